"""PyTorch training clips from a collected dataset.

A clip is ``context + future`` consecutive frames (2 + 10 by default) and the
``context + future - 1`` actions between them, aligned as the benchmark calls models
(SPEC §4): ``actions[k]`` is the action executed in ``frames[k]`` that produced
``frames[k + 1]``, so ``actions[context - 1]`` is the last executed action (it produced the
last context frame) and the remaining ones are the actions of the predicted frames.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import torch
from torch.utils.data import Dataset

from vp2.data.storage import DatasetError, DemoRecord, dataset_index, require_images
from vp2.utils.tensors import images_to_float


class ClipDataset(Dataset):
    """Clips of a vp2 dataset for training or evaluating video prediction models.

    Args:
        root: dataset directory (from ``vp2 collect``).
        split: ``"train"`` or ``"valid"``.
        tasks: keep only these data streams (e.g. ``["robodesk/push_red"]``); ``None`` = all.
        max_trajectories: keep only the dataset's first N trajectories (before the split is
            applied, so train and valid stay disjoint; trajectories interleave tasks, so the
            first N are balanced across them). For data-quantity studies.
        context: context frames per clip.
        future: predicted frames per clip.
        stride: step between clip start frames within a trajectory.
        uint8: return frames as ``uint8`` (convert on the accelerator) instead of float.

    Items are dicts: ``frames`` ``(T, 3, H, W)`` float32 in [0, 1] (or uint8),
    ``actions`` ``(T - 1, A)`` float32, ``index`` (trajectory index) and ``start`` (frame).
    """

    def __init__(
        self,
        root: str | os.PathLike[str],
        split: str = "train",
        tasks: Sequence[str] | None = None,
        max_trajectories: int | None = None,
        context: int = 2,
        future: int = 10,
        stride: int = 1,
        uint8: bool = False,
    ):
        if split not in ("train", "valid"):
            raise ValueError(f"split must be 'train' or 'valid', got {split!r}")
        if context < 1 or future < 1 or stride < 1:
            raise ValueError("context, future and stride must be >= 1")
        records = dataset_index(root)
        require_images(root, records)
        if max_trajectories is not None:
            if max_trajectories <= 0:
                raise ValueError(f"max_trajectories must be > 0, got {max_trajectories}")
            if max_trajectories > len(records):
                raise ValueError(
                    f"{root} holds {len(records)} trajectories, fewer than max_trajectories="
                    f"{max_trajectories}; collect more with a larger -n"
                )
            records = records[:max_trajectories]
        if tasks is not None:
            known = sorted({r.task for r in records})
            missing = set(tasks) - set(known)
            if missing:
                raise ValueError(f"tasks {sorted(missing)} not in {root}; it holds {known}")
            records = [r for r in records if r.task in set(tasks)]
        self.records: list[DemoRecord] = [r for r in records if r.split == split]
        self.clip_length = context + future
        self.context, self.future, self.uint8 = context, future, uint8
        starts = []
        for rid, rec in enumerate(self.records):
            last = rec.num_frames - self.clip_length
            starts.extend((rid, s) for s in range(0, last + 1, stride))
        if not starts:
            raise DatasetError(
                f"{root}: no {split} clips of {self.clip_length} frames"
                f"{' for ' + ', '.join(tasks) if tasks else ''}"
            )
        self._starts = np.asarray(starts, dtype=np.int64)  # (num_clips, 2)
        self._files: dict[Path, h5py.File] = {}

    def __len__(self) -> int:
        return len(self._starts)

    @property
    def action_dim(self) -> int:
        return self.records[0].action_dim

    @property
    def image_shape(self) -> tuple[int, int, int]:
        return self.records[0].image_shape

    def _file(self, path: Path) -> h5py.File:
        # Opened lazily, so each DataLoader worker process gets its own handles.
        f = self._files.get(path)
        if f is None:
            f = self._files[path] = h5py.File(path, "r")
        return f

    def trajectory(self, i: int) -> int:
        """The trajectory clip ``i`` is cut from, as its position in :attr:`records` (clips of
        one trajectory share it; reads no frames)."""
        return int(self._starts[i][0])

    def __getitem__(self, i: int) -> dict[str, Any]:
        rid, start = (int(v) for v in self._starts[i])
        rec = self.records[rid]
        g = self._file(rec.path)["data"][rec.name]
        end = start + self.clip_length
        # Contiguous: a permuted view is channels-last, which changes conv rounding (and trips a
        # oneDNN bug in torch 2.13 on CPU).
        frames = torch.from_numpy(g["obs/rgb"][start:end]).permute(0, 3, 1, 2).contiguous()  # (T, 3, H, W)
        if not self.uint8:
            frames = images_to_float(frames)
        actions = torch.from_numpy(g["actions"][start : end - 1])  # (T - 1, A)
        return {"frames": frames, "actions": actions, "index": int(rec.name[5:]), "start": start}

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_files"] = {}
        return state

    def close(self) -> None:
        for f in self._files.values():
            f.close()
        self._files.clear()


def select_clips(num_available: int, num_clips: int, seed: int) -> list[int]:
    """The held-out clips a model is measured on: ``min(num_clips, num_available)`` distinct
    indices of a :class:`ClipDataset` drawn with ``seed``, in increasing order. The same seed
    picks the same clips for every model and every measure (``vp2 metrics``, ``vp2
    diagnose``'s action conditioning)."""
    if num_clips < 1:
        raise ValueError(f"num_clips must be >= 1, got {num_clips}")
    gen = torch.Generator().manual_seed(seed)
    chosen = torch.randperm(num_available, generator=gen)[: min(num_clips, num_available)]
    return sorted(chosen.tolist())
