"""A training run's checkpoints: where they are, pruning, and the random states they carry.

A run's checkpoint is a model checkpoint (:mod:`vp2.models.checkpoint`: written atomically,
loadable with ``torch.load(weights_only=True)``, plain data only) with the state a resumed run
needs on top::

    format         "vp2-checkpoint/1"
    model          {"name": str, "config": dict, "state_dict": {...}}   <- all load_model needs
    step           optimisation steps done
    optimizer      optimizer.state_dict()
    scaler         GradScaler.state_dict() (mixed precision on CUDA; {} otherwise)
    rng            {"noise": generator state, "torch": CPU state, "cuda": [per-device states]}
    train_config   the TrainConfig as a dict
    dataset        {"path", "config" (the dataset manifest's, with env metadata), ...}
    metrics        the latest validation metrics
    train_seconds  training wall time of all sessions up to this checkpoint (the time budget)

:meth:`vp2.training.setup.TrainingRun.save_checkpoint` writes one; :mod:`vp2.training.export`
strips the resume state for shipping.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

CHECKPOINT_DIR = "checkpoints"


def checkpoint_path(out_dir: str | os.PathLike[str], step: int) -> Path:
    """Where a run writes the checkpoint of ``step``."""
    return Path(out_dir) / CHECKPOINT_DIR / f"step_{step:08d}.pt"


def list_checkpoints(out_dir: str | os.PathLike[str]) -> list[Path]:
    """A run's checkpoints, oldest first (zero-padded step numbers sort in step order)."""
    directory = Path(out_dir) / CHECKPOINT_DIR
    return sorted(directory.glob("step_*.pt")) if directory.is_dir() else []


def prune_checkpoints(out_dir: str | os.PathLike[str], keep: int) -> None:
    """Deletes all but the newest ``keep`` (>= 1) checkpoints of a run."""
    for old in list_checkpoints(out_dir)[: -max(1, keep)]:
        old.unlink(missing_ok=True)


def rng_state(noise: torch.Generator) -> dict[str, Any]:
    """The random states a resumed run needs to continue bit-for-bit."""
    return {
        "noise": noise.get_state(),
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
    }


def restore_rng_state(state: dict[str, Any], noise: torch.Generator) -> None:
    """Sets the states :func:`rng_state` saved: ``noise``'s and torch's global generators."""
    noise.set_state(state["noise"])
    torch.set_rng_state(state["torch"])
    if state.get("cuda") and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])
