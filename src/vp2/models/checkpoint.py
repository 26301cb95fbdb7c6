"""The checkpoint format of trained models: its layout, where a checkpoint is, reading, writing.

The one definition of a vp2 checkpoint. A checkpoint is a dict of tensors and plain data only
(no pickled classes), loadable with ``torch.load(weights_only=True)``::

    format   "vp2-checkpoint/1"
    model    {"name": str, "config": dict, "state_dict": {...}}   <- all load_model needs
    ...      whatever else the writer keeps (a training run: step, optimizer, RNG states,
             train_config, dataset, metrics; see :mod:`vp2.training.checkpoint`)

A training run keeps its checkpoints as ``OUT/checkpoints/step_00000123.pt``
(:func:`checkpoint_path`); a checkpoint is named by that file or by the run directory (its
newest, :func:`latest_checkpoint`). :func:`model_entry` makes the ``model`` entry,
:func:`write_model_checkpoint` writes a checkpoint and :func:`read_model_checkpoint` reads one
back, refusing anything else with a one-line :class:`CheckpointError`.
:func:`vp2.models.registry.load_model` turns one into a ready model.
"""

from __future__ import annotations

import os
import pickle
import re
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from vp2.utils.io import atomic_path

if TYPE_CHECKING:
    from vp2.models.base import VideoPredictor

#: Format tag of checkpoints written by :mod:`vp2.training` (and read by ``load_model``).
CHECKPOINT_FORMAT = "vp2-checkpoint/1"
#: The subdirectory of a training run that holds its checkpoints.
CHECKPOINT_DIR = "checkpoints"
#: The file names of a run's checkpoints (:func:`checkpoint_path`).
CHECKPOINT_GLOB = "step_*.pt"
#: The entries of a checkpoint's ``model`` entry: all that ``load_model`` needs.
MODEL_KEYS = ("name", "config", "state_dict")


class CheckpointError(ValueError):
    """A file that is not a readable vp2 checkpoint (of the expected model), with the reason."""


def checkpoint_path(out_dir: str | os.PathLike[str], step: int) -> Path:
    """Where a training run in ``out_dir`` keeps the checkpoint of ``step``."""
    return Path(out_dir) / CHECKPOINT_DIR / f"step_{step:08d}.pt"


def list_checkpoints(out_dir: str | os.PathLike[str]) -> list[Path]:
    """A run's checkpoints, oldest first (zero-padded step numbers sort in step order)."""
    directory = Path(out_dir) / CHECKPOINT_DIR
    return sorted(directory.glob(CHECKPOINT_GLOB)) if directory.is_dir() else []


def latest_checkpoint(path: str | os.PathLike[str]) -> Path:
    """The checkpoint a path designates: a file itself, else the newest ``step_*.pt`` in the
    directory or in its ``checkpoints/`` subdirectory (a training run's output directory).

    Raises:
        FileNotFoundError: if there is none.
    """
    path = Path(path)
    if path.is_file():
        return path
    if not path.exists():
        raise FileNotFoundError(f"no checkpoint at {path}: no such file or directory")
    found = sorted(path.glob(CHECKPOINT_GLOB)) or list_checkpoints(path)
    if found:
        return found[-1]
    raise FileNotFoundError(
        f"no checkpoint at {path}: expected a .pt file or a run directory "
        f"(with {CHECKPOINT_GLOB} files in it or in its {CHECKPOINT_DIR}/)"
    )


def model_entry(model: VideoPredictor) -> dict[str, Any]:
    """The ``model`` entry of a checkpoint of ``model``: its name, config and weights."""
    return {"name": model.name, "config": model.config_dict(), "state_dict": model.state_dict()}


def read_model_checkpoint(
    path: str | os.PathLike[str], map_location: Any = "cpu", expected_name: str | None = None
) -> dict[str, Any]:
    """Loads a vp2 model checkpoint (a file or a run directory's newest, see
    :func:`latest_checkpoint`) with ``torch.load(weights_only=True)`` and checks it: its format
    tag, its ``model`` entry and, if given, the model it holds.

    Raises:
        FileNotFoundError: no checkpoint at ``path``.
        CheckpointError: (a ``ValueError``) not a vp2 checkpoint, or not of ``expected_name``;
            one line naming the file and the reason.
    """
    path = latest_checkpoint(path)
    payload = _load(path, map_location)
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        found = payload.get("format") if isinstance(payload, dict) else None
        what = f"format {found!r}" if found is not None else f"no {CHECKPOINT_FORMAT!r} tag"
        raise CheckpointError(f"{path} is not a vp2 checkpoint (a PyTorch file with {what})")
    entry = payload.get("model")
    if not isinstance(entry, dict) or not all(k in entry for k in MODEL_KEYS):
        raise CheckpointError(
            f"{path} is not a vp2 checkpoint (no 'model' entry with {', '.join(MODEL_KEYS)})"
        )
    if expected_name is not None and entry["name"] != expected_name:
        raise CheckpointError(f"{path} holds a {entry['name']!r} model, not {expected_name!r}")
    return payload


def write_model_checkpoint(path: str | os.PathLike[str], payload: dict[str, Any]) -> Path:
    """Writes ``payload`` tagged with :data:`CHECKPOINT_FORMAT`, atomically (temporary file,
    then ``os.replace``). The same payload gives the same bytes: torch names the archive's
    records after the file it is given, so it is given an open file (records named
    ``archive/``), not the temporary file's random name."""
    payload = {"format": CHECKPOINT_FORMAT, **payload}
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        torch.save(payload, f)
    return Path(path)


def _load(path: Path, map_location: Any) -> Any:
    """``torch.load(weights_only=True)`` of a file; what it cannot read is a CheckpointError."""
    try:
        with warnings.catch_warnings():
            # Raised by any file pickled with protocol > 2 (e.g. by plain ``pickle``).
            warnings.filterwarnings("ignore", "Detected pickle protocol", UserWarning)
            return torch.load(path, map_location=map_location, weights_only=True)
    except OSError as exc:
        raise CheckpointError(f"cannot read the checkpoint {path}: {exc.strerror or exc}") from None
    except Exception as exc:  # torch raises what its readers raise: RuntimeError, EOFError, ...
        raise CheckpointError(f"{path} is not a vp2 checkpoint ({_unreadable(exc)})") from None


def _unreadable(exc: Exception) -> str:
    """Why ``torch.load(weights_only=True)`` failed, in a few words. The load is never retried
    unsafely, so torch's advice to do so (its message's first lines) is left out."""
    detail: BaseException = exc
    if isinstance(exc, pickle.UnpicklingError) and exc.__context__ is not None:
        detail = exc.__context__  # the weights-only unpickler's own error
    text = str(detail).strip()
    found = re.search(r"GLOBAL ([\w.]+)", text)
    if isinstance(exc, pickle.UnpicklingError) and found:
        return (
            f"it holds a pickled Python object, {found[1]}, which vp2 does not load: "
            "a vp2 checkpoint is tensors and plain data only"
        )
    text = re.sub(r"^\[enforce fail at [^\]]*\]\s*\.?\s*", "", text)
    text = (text.splitlines() or [""])[0].split(". ")[0].rstrip(".")
    text = text.removeprefix("PytorchStreamReader ")
    if "weights_only" in text or "Weights only" in text:
        text = ""
    if not isinstance(detail, RuntimeError) or not text:
        text = f"{type(detail).__name__}: {text}" if text else type(detail).__name__
    return f"not a readable PyTorch file: {text}"
