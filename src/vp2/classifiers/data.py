"""Labelled frames of a collected RoboDesk dataset, to train and evaluate classifiers on.

:func:`load_frames` gives every frame of a task's trajectories labelled with the simulator's
success flag of that frame (or the paper's dense-reward label), split by trajectory with the
dataset's own ``mask/train`` / ``mask/valid``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import h5py
import numpy as np
import torch
from torch import Tensor

from vp2.classifiers.registry import short_task
from vp2.data.storage import DatasetError, dataset_index, require_images
from vp2.envs.robodesk import DENSE_LABEL_THRESHOLD
from vp2.utils.tensors import images_to_float


@dataclasses.dataclass
class FrameSet:
    """Frames of one task and split with their success labels.

    Attributes:
        images: ``(N, H, W, 3)`` uint8.
        labels: ``(N,)`` bool, the simulator's success flag of each frame.
        trajectories: ``(N,)`` int64, the dataset index of each frame's trajectory.
        steps: ``(N,)`` int64, the frame's index in its trajectory (0 = the reset frame).
        targets: ``(N,)`` float32 training targets in [0, 1] where the label is soft
            (``"progress"``), else ``None`` (the targets are ``labels``).
        threshold: The logit above which a frame counts as predicted positive when it is
            scored against ``labels`` (0 for the hard labels).
    """

    images: np.ndarray
    labels: np.ndarray
    trajectories: np.ndarray
    steps: np.ndarray
    targets: np.ndarray | None = None
    threshold: float = 0.0

    def training_targets(self) -> np.ndarray:
        """``(N,)`` float32: what the loss fits (the soft targets, else the labels)."""
        return (self.labels if self.targets is None else self.targets).astype(np.float32)

    def __len__(self) -> int:
        return len(self.labels)

    @property
    def positives(self) -> int:
        return int(self.labels.sum())

    @property
    def num_trajectories(self) -> int:
        return len(np.unique(self.trajectories))

    def describe(self) -> dict[str, int]:
        return {
            "trajectories": self.num_trajectories,
            "frames": len(self),
            "positives": self.positives,
            "positive_trajectories": len(np.unique(self.trajectories[self.labels])),
        }


#: Frame labels a classifier can be trained on (SPEC §6): the simulator's strict success flag,
#: or the paper's label, the dense reward summed over the step's 50 action repeats >= 30.
LABELS = {
    "success": "simulator success flag of each frame (success[k] of obs/rgb[k])",
    "dense": "paper: dense reward summed over the step's 50 action repeats >= 30 "
    "(dense_reward[k] of obs/rgb[k])",
    "progress": "soft: PROGRESS_DECAY ** (steps until the paper's label first holds in the "
    "frame's trajectory), 1 from then on, 0 in a trajectory where it never holds; scored "
    "against the paper's label at sigmoid(logit) >= (1 + PROGRESS_DECAY) / 2",
}

#: Decay per step of the ``"progress"`` label: its target is 1 where the paper's label first
#: holds, 0.7 one step before, 0.49 two steps before, ... (0.014 twelve steps before).
PROGRESS_DECAY = 0.7


def progress_targets(positive: np.ndarray, decay: float = PROGRESS_DECAY) -> np.ndarray:
    """Soft targets of one trajectory's frames from its per-frame paper labels.

    ``decay ** (k* - k)`` for frame ``k`` before the first positive frame ``k*``, 1 from ``k*``
    on, and 0 everywhere in a trajectory with no positive frame.

    Args:
        positive: ``(T + 1,)`` bool, the paper's label of each frame.
        decay: Factor per step before ``k*``, in (0, 1).

    Returns:
        ``(T + 1,)`` float32.
    """
    positive = np.asarray(positive, bool)
    if not 0.0 < decay < 1.0:
        raise ValueError(f"decay must be in (0, 1), got {decay}")
    if not positive.any():
        return np.zeros(len(positive), np.float32)
    first = int(np.argmax(positive))
    k = np.arange(len(positive))
    return np.where(k >= first, 1.0, decay ** (first - k)).astype(np.float32)


def load_frames(root: str | Path, task: str, split: str, label: str = "success") -> FrameSet:
    """Every frame of every ``task`` trajectory of one split of a collected dataset.

    Frame ``k`` of a trajectory is ``obs/rgb[k]``, rendered from ``states[k]``. With
    ``label="success"`` its label is ``success[k]``, the simulator's success flag of that state
    (``k = 0`` is the reset frame); with ``label="dense"`` the paper's: ``dense_reward[k] >=
    30`` (:data:`vp2.envs.robodesk.DENSE_LABEL_THRESHOLD`).
    The split is the dataset's own ``mask/train`` / ``mask/valid`` (by trajectory), so no
    trajectory contributes frames to both.

    Args:
        root: Dataset directory (from ``vp2 collect``).
        task: ``"robodesk/<task>"`` or ``"<task>"``.
        split: ``"train"`` or ``"valid"``.

    Raises:
        DatasetError: if the dataset holds no ``split`` trajectory of the task.
    """
    if split not in ("train", "valid"):
        raise ValueError(f"split must be 'train' or 'valid', got {split!r}")
    if label not in LABELS:
        raise ValueError(f"label must be one of {', '.join(LABELS)}, got {label!r}")
    full = f"robodesk/{short_task(task)}"
    records = [r for r in dataset_index(root) if r.task == full and r.split == split]
    if not records:
        raise DatasetError(f"{root}: no {split} trajectories of {full}")
    require_images(root, records)
    images, labels, trajectories, steps, targets = [], [], [], [], []
    by_file: dict[Path, list[str]] = {}
    for r in records:
        by_file.setdefault(r.path, []).append(r.name)
    for path, names in by_file.items():
        with h5py.File(path, "r") as f:
            for name in names:
                g = f["data"][name]
                rgb = g["obs/rgb"][()]  # (T + 1, H, W, 3)
                if label in ("dense", "progress"):
                    if "dense_reward" not in g:
                        raise DatasetError(
                            f"{path}:{name}: no dense_reward (collected before it was "
                            "recorded); re-collect with `vp2 collect robodesk`, or use "
                            "--label success"
                        )
                    success = g["dense_reward"][()] >= DENSE_LABEL_THRESHOLD
                    if label == "progress":
                        targets.append(progress_targets(success))
                else:
                    success = g["success"][()].astype(bool)  # (T + 1,)
                if len(rgb) != len(success):
                    raise DatasetError(
                        f"{path}:{name}: {len(rgb)} frames but {len(success)} success flags"
                    )
                images.append(rgb)
                labels.append(success)
                trajectories.append(np.full(len(rgb), int(name.split("_")[1]), np.int64))
                steps.append(np.arange(len(rgb), dtype=np.int64))
    order = np.argsort(np.concatenate(trajectories) * 10_000 + np.concatenate(steps), kind="stable")
    soft = label == "progress"
    return FrameSet(
        images=np.concatenate(images)[order],
        labels=np.concatenate(labels)[order],
        trajectories=np.concatenate(trajectories)[order],
        steps=np.concatenate(steps)[order],
        targets=np.concatenate(targets)[order] if soft else None,
        threshold=progress_threshold() if soft else 0.0,
    )


def progress_threshold(decay: float = PROGRESS_DECAY) -> float:
    """The logit at which a ``"progress"`` classifier's probability is halfway between the
    targets of the first positive frame (1) and the frame before it (``decay``)."""
    p = (1.0 + decay) / 2.0
    return float(np.log(p / (1.0 - p)))


def to_tensor(images: np.ndarray, device: torch.device | str = "cpu") -> Tensor:
    """``(N, H, W, 3)`` uint8 -> contiguous ``(N, 3, H, W)`` float32 in [0, 1]."""
    return images_to_float(np.ascontiguousarray(images), device, channels_first=True)
