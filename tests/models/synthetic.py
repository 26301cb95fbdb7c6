"""Synthetic action-conditioned videos for model and trainer tests: moving squares.

A coloured square on a dark background moves by ``action[:2] * speed`` pixels per step
(clamped to the image), so the future depends on the actions and on nothing else: a model
that ignores actions cannot predict it. ``actions[k]`` is executed in frame ``k`` and
produces frame ``k + 1``, as in vp2 datasets.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from vp2.data import storage
from vp2.utils.io import write_json_atomic


def moving_square_video(
    rng: np.random.Generator,
    num_frames: int,
    size: int,
    action_dim: int,
    speed: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One video: ``(num_frames, size, size, 3)`` uint8 frames and ``(num_frames - 1, A)``
    float32 actions in [-1, 1]."""
    speed = size / 8 if speed is None else speed
    side = max(2, size // 5)
    color = rng.uniform(0.5, 1.0, 3)
    pos = rng.uniform(0, size - side, 2)
    actions = rng.uniform(-1, 1, (num_frames - 1, action_dim)).astype(np.float32)
    frames = np.zeros((num_frames, size, size, 3), np.float64)
    frames[:] = 0.1
    for t in range(num_frames):
        if t > 0:
            pos = np.clip(pos + actions[t - 1, :2] * speed, 0, size - side)
        x, y = np.round(pos).astype(int)
        frames[t, y : y + side, x : x + side] = color
    return (frames * 255).round().astype(np.uint8), actions


def moving_square_batch(
    batch: int, size: int = 32, action_dim: int = 4, num_frames: int = 12, seed: int = 0
) -> tuple[torch.Tensor, torch.Tensor]:
    """``frames (B, T, 3, H, W)`` float in [0, 1] and ``actions (B, T - 1, A)``."""
    rng = np.random.default_rng(seed)
    videos = [moving_square_video(rng, num_frames, size, action_dim) for _ in range(batch)]
    frames = torch.from_numpy(np.stack([v[0] for v in videos])).permute(0, 1, 4, 2, 3)
    actions = torch.from_numpy(np.stack([v[1] for v in videos]))
    return frames.contiguous().float() / 255, actions


def write_moving_square_dataset(
    root: str | Path,
    num_trajectories: int = 6,
    size: int = 32,
    action_dim: int = 4,
    num_frames: int = 16,
    valid_every: int = 3,
    chunk_size: int = 3,
    seed: int = 0,
) -> Path:
    """A complete vp2 dataset directory (manifest + shards) that ``ClipDataset`` reads."""
    root = Path(root)
    rng = np.random.default_rng(seed)
    env_meta = {"env": "synthetic/moving_square", "size": size}
    chunks = []
    for c, first in enumerate(range(0, num_trajectories, chunk_size)):
        count = min(chunk_size, num_trajectories - first)
        trajectories = []
        for index in range(first, first + count):
            images, actions = moving_square_video(rng, num_frames, size, action_dim)
            trajectories.append(
                storage.Trajectory(
                    task="synthetic/moving_square",
                    index=index,
                    seed=seed + index,
                    actions=actions,
                    states=np.zeros((num_frames, 1)),
                    images=images,
                    success=np.zeros(num_frames, bool),
                    env_meta=env_meta,
                )
            )
        storage.write_shard(storage.shard_path(root, c), trajectories, env_meta, valid_every)
        chunks.append({"chunk": c, "first": first, "count": count})
    write_json_atomic(
        root / storage.MANIFEST,
        {
            "format": storage.FORMAT,
            "config": {
                "env": "synthetic",
                "image_size": size,
                "seed": seed,
                "trajectories": num_trajectories,
                "valid_every": valid_every,
            },
            "chunks": chunks,
            "complete": True,
        },
    )
    return root
