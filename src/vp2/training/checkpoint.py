"""Training checkpoints: written atomically, loadable with ``torch.load(weights_only=True)``.

A checkpoint is a dict of tensors and plain data only (no pickled classes)::

    format         "vp2-checkpoint/1"
    model          {"name": str, "config": dict, "state_dict": {...}}   <- all load_model needs
    step           optimisation steps done
    optimizer      optimizer.state_dict()
    scaler         GradScaler.state_dict() (mixed precision on CUDA; {} otherwise)
    rng            {"noise": generator state, "torch": CPU state, "cuda": [per-device states]}
    train_config   the TrainConfig as a dict
    dataset        {"path", "config" (the dataset manifest's, with env metadata), ...}
    metrics        the latest validation metrics
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from vp2.models.registry import CHECKPOINT_FORMAT
from vp2.utils.io import atomic_path

CHECKPOINT_DIR = "checkpoints"


def checkpoint_path(out_dir: str | os.PathLike[str], step: int) -> Path:
    return Path(out_dir) / CHECKPOINT_DIR / f"step_{step:08d}.pt"


def list_checkpoints(out_dir: str | os.PathLike[str]) -> list[Path]:
    """A run's checkpoints, oldest first (zero-padded step numbers sort in step order)."""
    directory = Path(out_dir) / CHECKPOINT_DIR
    return sorted(directory.glob("step_*.pt")) if directory.is_dir() else []


def save_checkpoint(path: str | os.PathLike[str], payload: dict[str, Any]) -> Path:
    """Writes a checkpoint atomically (temporary file, then ``os.replace``)."""
    payload = {"format": CHECKPOINT_FORMAT, **payload}
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return Path(path)


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
    noise.set_state(state["noise"])
    torch.set_rng_state(state["torch"])
    if state.get("cuda") and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


#: Entries an inference-only checkpoint keeps (no optimizer, scaler or RNG states).
EXPORT_KEYS = ("model", "step", "train_config", "dataset", "metrics")


def export_checkpoint(
    src: str | os.PathLike[str], dst: str | os.PathLike[str], half: bool = True
) -> Path:
    """Writes an inference-only copy of a training checkpoint (e.g. to ship in a package).

    Keeps what :func:`vp2.models.load_model` and a reader of the provenance need (model name,
    config and weights, step, training config, dataset, validation metrics) and drops the
    optimizer, scaler and RNG states, so it cannot resume training. With ``half`` the floating
    point weights are stored as float16 (half the size); ``load_model`` casts them back into
    the model's float32 parameters.

    Args:
        src: A checkpoint file or a run directory (its newest checkpoint).
        dst: Output file, written atomically.
    """
    from vp2.models.registry import read_checkpoint

    payload = read_checkpoint(src)
    out = {k: payload[k] for k in EXPORT_KEYS if k in payload}
    state = payload["model"]["state_dict"]
    if half:
        state = {k: v.half() if v.is_floating_point() else v for k, v in state.items()}
    out["model"] = {**payload["model"], "state_dict": state}
    out["exported"] = {"half": bool(half), "from_step": int(payload.get("step", -1))}
    out.pop("format", None)
    return save_checkpoint(dst, out)


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description="Export an inference-only checkpoint.")
    parser.add_argument("src", help="checkpoint file or training run directory")
    parser.add_argument("dst", help="output .pt file")
    parser.add_argument("--float32", action="store_true", help="keep float32 weights")
    args = parser.parse_args()
    print(export_checkpoint(args.src, args.dst, half=not args.float32))
