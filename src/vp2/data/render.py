"""Re-render a dataset's observations at another resolution from its stored states."""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from vp2.data import storage
from vp2.envs.base import Env
from vp2.envs.cache import EnvCache
from vp2.utils.executors import Executor, LocalExecutor
from vp2.utils.io import remove_stale_temporaries, write_json_atomic

# The environments of this process (closed at the end of a rerender).
_ENVS = EnvCache(4)


def render_states(env: Env, states: np.ndarray, size: int) -> np.ndarray:
    """Renders each state of a trajectory: ``(T, S)`` -> ``(T, size, size, 3)`` uint8."""
    frames = []
    for state in states:
        env.reset_to(state)
        frames.append(env.render(size))
    return np.asarray(frames, np.uint8)


def _render_shard(job: tuple[str, int]) -> list[storage.Trajectory]:
    path, size = job
    out = []
    for traj in storage.read_trajectories(path):
        env = _ENVS.get(traj.env_meta, observation_size=None)
        out.append(dataclasses.replace(traj, images=render_states(env, traj.states, size)))
    return out


def rerender(
    src: str | Path,
    out: str | Path,
    size: int,
    workers: int | None = None,
    progress: bool = True,
    executor: Executor | None = None,
) -> Path:
    """Writes a copy of dataset ``src`` with observations rendered at ``size``×``size``.

    Resumable like collection: shards already rendered into ``out`` are kept. ``executor``
    runs the shards (default: local worker processes, ``workers`` of them); the source
    dataset must be readable at the same path on every worker's machine.
    """
    if size <= 0:
        raise ValueError(f"size must be positive, got {size}")
    src, root = Path(src), Path(out)
    if src.resolve() == root.resolve():
        raise ValueError("--out must differ from the source dataset")
    manifest = storage.load_manifest(src)
    storage.dataset_index(src)  # the source must be complete and valid
    new_manifest: dict[str, Any] = {
        **manifest,
        "config": {**manifest["config"], "image_size": size, "render": True},
        "rendered_from": str(src.resolve()),
        "complete": False,
    }
    if (root / storage.MANIFEST).exists():
        existing = storage.load_manifest(root)
        if existing["config"] != new_manifest["config"]:
            raise FileExistsError(f"{root} holds a different dataset; choose another --out")
    root.mkdir(parents=True, exist_ok=True)
    if (root / storage.SHARD_DIR).exists():
        remove_stale_temporaries(root / storage.SHARD_DIR)
    write_json_atomic(root / storage.MANIFEST, new_manifest)
    todo = []
    for chunk in manifest["chunks"]:
        dst = storage.shard_path(root, chunk["chunk"])
        if dst.exists():
            try:
                storage.read_shard_index(dst)
                continue
            except storage.DatasetError:
                dst.unlink()
        todo.append(chunk)
    executor = LocalExecutor(workers) if executor is None else executor
    valid_every = manifest["config"]["valid_every"]
    env_meta = {"env": manifest["config"]["env"], "collection": new_manifest["config"]}
    total = sum(c["count"] for c in manifest["chunks"])
    with tqdm(total=total, initial=total - sum(c["count"] for c in todo), unit="traj",
              desc=f"render {size}px", disable=not progress) as bar, contextlib.closing(_ENVS):
        jobs = [(str(storage.shard_path(src, c["chunk"])), size) for c in todo]
        for (path, _), trajectories in executor.imap_unordered(_render_shard, jobs):
            chunk = int(Path(path).stem)
            storage.write_shard(storage.shard_path(root, chunk), trajectories, env_meta, valid_every)
            bar.update(len(trajectories))
    new_manifest["complete"] = True
    write_json_atomic(root / storage.MANIFEST, new_manifest)
    return root
