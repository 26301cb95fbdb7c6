"""Tests of the RoboDesk success classifiers; helpers that write a tiny labelled dataset."""

from __future__ import annotations

import numpy as np

from vp2.data import storage
from vp2.utils.io import write_json_atomic

SIDE = 16  # tiny frames keep training in the tests fast
STEPS = 6  # frames per trajectory


def make_frame(success: bool, rng: np.random.Generator) -> np.ndarray:
    """A noisy frame; success frames carry a bright square in the top-left corner."""
    image = rng.integers(0, 90, (SIDE, SIDE, 3), dtype=np.uint8)
    if success:
        image[2:7, 2:7] = 230
    return image


def write_dataset(root, num_per_task: int = 6, valid_every: int = 3, seed: int = 0):
    """A hand-made dataset in the vp2 layout: push_red and open_drawer trajectories whose
    success flags switch on at a per-trajectory step (never, for some)."""
    rng = np.random.default_rng(seed)
    streams = ("robodesk/push_red", "robodesk/open_drawer")
    trajectories = []
    for index in range(num_per_task * len(streams)):
        onset = int(rng.integers(1, STEPS + 2))  # > STEPS - 1: never successful
        success = np.arange(STEPS) >= onset
        trajectories.append(
            storage.Trajectory(
                task=streams[index % len(streams)],
                index=index,
                seed=index,
                actions=np.zeros((STEPS - 1, 5), np.float32),
                states=np.zeros((STEPS, 3)),
                images=np.stack([make_frame(s, rng) for s in success]),
                success=success,
                # the paper's label (summed dense reward >= 30) holds one step before success
                dense_reward=np.where(np.arange(STEPS) >= onset - 1, 40.0, 10.0),
                env_meta={"env": "robodesk"},
            )
        )
    chunks = []
    for c, start in enumerate(range(0, len(trajectories), 5)):
        part = trajectories[start : start + 5]
        storage.write_shard(storage.shard_path(root, c), part, {"env": "robodesk"}, valid_every)
        chunks.append({"chunk": c, "first": start, "count": len(part)})
    write_json_atomic(
        root / storage.MANIFEST,
        {
            "format": storage.FORMAT,
            "config": {"env": "robodesk", "image_size": SIDE, "valid_every": valid_every},
            "chunks": chunks,
            "complete": True,
        },
    )
    return root, trajectories
