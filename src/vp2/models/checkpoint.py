"""The checkpoint format of trained models: where a checkpoint is, reading and writing it.

A checkpoint is a dict of tensors and plain data only (no pickled classes), loadable with
``torch.load(weights_only=True)``::

    format   "vp2-checkpoint/1"
    model    {"name": str, "config": dict, "state_dict": {...}}   <- all load_model needs
    ...      whatever else the writer keeps (a training run: step, optimizer, RNG states,
             train_config, dataset, metrics; see :mod:`vp2.training.checkpoint`)

:func:`vp2.models.registry.load_model` turns one into a ready model.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from vp2.utils.io import atomic_path

#: Format tag of checkpoints written by :mod:`vp2.training` (and read by ``load_model``).
CHECKPOINT_FORMAT = "vp2-checkpoint/1"


def latest_checkpoint(path: str | os.PathLike[str]) -> Path:
    """The checkpoint a path designates: a file itself, else the newest ``step_*.pt`` in the
    directory or in its ``checkpoints/`` subdirectory (a training run's output directory).

    Raises:
        FileNotFoundError: if there is none.
    """
    path = Path(path)
    if path.is_file():
        return path
    for directory in (path, path / "checkpoints"):
        found = sorted(directory.glob("step_*.pt")) if directory.is_dir() else []
        if found:
            return found[-1]  # zero-padded step numbers sort in step order
    raise FileNotFoundError(f"{path}: no checkpoint (expected a .pt file or a run directory)")


def read_model_checkpoint(
    path: str | os.PathLike[str], map_location: Any = "cpu"
) -> dict[str, Any]:
    """Loads a vp2 model checkpoint (a file or a run directory's newest, see
    :func:`latest_checkpoint`) with ``torch.load(weights_only=True)`` and checks its format.

    Raises:
        FileNotFoundError: no checkpoint at ``path``.
        ValueError: not a vp2 checkpoint.
    """
    path = latest_checkpoint(path)
    payload = torch.load(path, map_location=map_location, weights_only=True)
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path}: not a {CHECKPOINT_FORMAT} checkpoint")
    return payload


def write_model_checkpoint(path: str | os.PathLike[str], payload: dict[str, Any]) -> Path:
    """Writes ``payload`` tagged with :data:`CHECKPOINT_FORMAT`, atomically (temporary file,
    then ``os.replace``)."""
    payload = {"format": CHECKPOINT_FORMAT, **payload}
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return Path(path)
