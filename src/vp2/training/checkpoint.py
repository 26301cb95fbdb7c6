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

:func:`run_payload` makes one (the ``model`` entry, the layout and the format are
:mod:`vp2.models.checkpoint`'s), :meth:`vp2.training.setup.TrainingRun.save_checkpoint` writes
it; :mod:`vp2.training.export` keeps :data:`EXPORT_KEYS` for shipping.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import torch

from vp2.models.checkpoint import (
    CHECKPOINT_DIR,
    checkpoint_path,
    list_checkpoints,
    model_entry,
)

if TYPE_CHECKING:
    from vp2.models.base import VideoPredictor

__all__ = [
    "CHECKPOINT_DIR",
    "EXPORT_KEYS",
    "checkpoint_path",
    "list_checkpoints",
    "prune_checkpoints",
    "restore_rng_state",
    "rng_state",
    "run_payload",
]

#: The entries an inference-only (exported) checkpoint keeps, in the order written: all but
#: the optimizer, scaler and RNG states that only a resumed run needs.
EXPORT_KEYS = ("model", "step", "train_config", "dataset", "metrics", "train_seconds")


def run_payload(
    model: VideoPredictor,
    *,
    step: int,
    optimizer: torch.optim.Optimizer,
    scaler: torch.amp.GradScaler,
    noise: torch.Generator,
    train_config: dict[str, Any],
    dataset: dict[str, Any],
    metrics: dict[str, float],
    train_seconds: float,
) -> dict[str, Any]:
    """A training run's checkpoint of ``step`` (for
    :func:`~vp2.models.checkpoint.write_model_checkpoint`), its entries in the order above."""
    return {
        "model": model_entry(model),
        "step": step,
        "optimizer": optimizer.state_dict(),
        "scaler": scaler.state_dict() if scaler.is_enabled() else {},
        "rng": rng_state(noise),
        "train_config": train_config,
        "dataset": dataset,
        "metrics": metrics,
        "train_seconds": train_seconds,
    }


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
