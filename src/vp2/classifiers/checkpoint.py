"""Classifier checkpoints: small files (state dict + plain metadata) that load with
``torch.load(weights_only=True)``."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import torch
from torch import nn

from vp2.classifiers.networks import FrameClassifierModule, build_classifier
from vp2.utils.io import atomic_path

#: Checkpoint format tag.
FORMAT = "vp2-classifier/1"


def save_classifier(path: str | Path, model: nn.Module, meta: dict[str, Any]) -> Path:
    """Writes ``{"format", "state_dict", "meta"}`` atomically; ``meta`` must be plain data.

    ``meta`` must hold ``arch``, ``task`` and ``image_size``; the rest (metrics, data
    description, training command) is kept for readers.
    """
    for key in ("arch", "task", "image_size"):
        if key not in meta:
            raise ValueError(f"classifier metadata needs {key!r}")
    json.dumps(meta)  # plain data only: what weights_only loading accepts
    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save({"format": FORMAT, "state_dict": state, "meta": meta}, tmp)
    return path


def read_classifier_checkpoint(path: str | Path) -> dict[str, Any]:
    """The checkpoint dict of a classifier file (``weights_only`` loading), checked."""
    path = Path(path)
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise
    except Exception as exc:  # a truncated or foreign file
        raise ValueError(f"{path}: not a readable classifier checkpoint ({exc})") from exc
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise ValueError(f"{path}: not a {FORMAT} checkpoint")
    return ckpt


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes (hex): which classifier a trial planned with."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def load_classifier(path: str | Path, device: str | torch.device = "cpu") -> FrameClassifierModule:
    """A saved classifier, ready for the planning cost: eval mode, parameters frozen.

    Returns:
        ``images (M, 3, H, W) in [0, 1] -> logits (M,)`` on ``device``; its ``meta`` is the
        file's metadata plus ``sha256``, the file's hash.
    """
    ckpt = read_classifier_checkpoint(path)
    meta = {**ckpt["meta"], "sha256": file_sha256(path)}
    network = build_classifier(meta["arch"], int(meta["image_size"]), int(meta.get("width", 1)))
    network.load_state_dict(ckpt["state_dict"])
    module = FrameClassifierModule(network, meta["task"], meta).to(device).eval()
    module.requires_grad_(False)
    return module
