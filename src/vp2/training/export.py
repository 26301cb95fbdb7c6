"""Shipping a trained model: an inference-only copy of a training checkpoint.

::

    python -m vp2.training.export runs/svg_prime_tiny_robodesk model.pt   # float16 weights
"""

from __future__ import annotations

import os
from pathlib import Path

from vp2.models.checkpoint import read_model_checkpoint, write_model_checkpoint
from vp2.training.checkpoint import EXPORT_KEYS

__all__ = ["EXPORT_KEYS", "export_checkpoint"]


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
    payload = read_model_checkpoint(src)
    out = {k: payload[k] for k in EXPORT_KEYS if k in payload}
    state = payload["model"]["state_dict"]
    if half:
        state = {k: v.half() if v.is_floating_point() else v for k, v in state.items()}
    out["model"] = {**payload["model"], "state_dict": state}
    out["exported"] = {"half": bool(half), "from_step": int(payload.get("step", -1))}
    out.pop("format", None)
    return write_model_checkpoint(dst, out)


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description="Export an inference-only checkpoint.")
    parser.add_argument("src", help="checkpoint file or training run directory")
    parser.add_argument("dst", help="output .pt file")
    parser.add_argument("--float32", action="store_true", help="keep float32 weights")
    args = parser.parse_args()
    print(export_checkpoint(args.src, args.dst, half=not args.float32))
