"""On-disk dataset format: HDF5 shards in the robomimic layout, tied together by a manifest.

A dataset is a directory::

    manifest.json          # settings, the chunk plan, completion state (written atomically)
    shards/00000.hdf5      # one chunk of trajectories, written once, atomically
    shards/00001.hdf5
    ...

Each shard follows robomimic's layout::

    data/                       attrs: env_meta (JSON, environment-level), total
    data/demo_<i>/              attrs: task, seed, noise_sigma, num_samples, env_meta (JSON)
        actions   (T, A)        float32, T = 35
        states    (T+1, S)      float64  (re-render any resolution from these)
        success   (T+1,)        bool     success flag of each state
        dense_reward (T+1,)     float64  RoboDesk: the package's dense reward summed over the
                                         50 repeats that led to each state (50x the reset
                                         state's for state 0); absent on the tabletop
        obs/rgb   (T+1, H, W, 3) uint8   absent in a states-only collection (`vp2 collect
                                         --states-only`) until `vp2 render` adds it
    mask/train, mask/valid      demo names (bytes)
    attrs: vp2_format, complete

``<i>`` is the trajectory's index in the whole dataset, so demo names are unique across
shards. A shard is only ever renamed into place after it is fully written and marked
``complete``; a truncated or corrupted file is reported by :func:`read_shard_index` with
its path.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from vp2.utils.io import atomic_path

FORMAT = "vp2-dataset/1"
MANIFEST = "manifest.json"
SHARD_DIR = "shards"


class DatasetError(RuntimeError):
    """A dataset file is missing, truncated, corrupted, or inconsistent with its manifest."""


@dataclasses.dataclass
class Trajectory:
    """One recorded trajectory: ``T`` actions and the ``T + 1`` states/frames around them."""

    task: str  # registered name, e.g. "robodesk/push_red"
    index: int  # index in the whole dataset
    seed: int
    actions: np.ndarray  # (T, A) float32
    states: np.ndarray  # (T+1, S) float64
    images: np.ndarray | None  # (T+1, H, W, 3) uint8; None: states only (render later)
    success: np.ndarray  # (T+1,) bool
    env_meta: dict[str, Any]
    noise_sigma: float = 0.0
    dense_reward: np.ndarray | None = None  # (T+1,) float64, RoboDesk only

    @property
    def name(self) -> str:
        return f"demo_{self.index}"


def shard_path(root: str | Path, chunk: int) -> Path:
    return Path(root) / SHARD_DIR / f"{chunk:05d}.hdf5"


def is_valid_index(index: int, valid_every: int) -> bool:
    """The train/validation split: every ``valid_every``-th trajectory is held out."""
    return valid_every > 0 and index % valid_every == valid_every - 1


def write_shard(
    path: str | Path,
    trajectories: Sequence[Trajectory],
    env_meta: dict[str, Any],
    valid_every: int,
) -> None:
    """Writes one shard atomically (temporary file, then rename)."""
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        data = f.create_group("data")
        data.attrs["env_meta"] = json.dumps(env_meta, sort_keys=True)
        data.attrs["total"] = int(sum(len(t.actions) for t in trajectories))
        train, valid = [], []
        for traj in trajectories:
            g = data.create_group(traj.name)
            g.attrs["task"] = traj.task
            g.attrs["seed"] = int(traj.seed)
            g.attrs["noise_sigma"] = float(traj.noise_sigma)
            g.attrs["num_samples"] = len(traj.actions)
            g.attrs["env_meta"] = json.dumps(traj.env_meta, sort_keys=True)
            g.create_dataset("actions", data=np.asarray(traj.actions, np.float32))
            g.create_dataset("states", data=np.asarray(traj.states, np.float64))
            g.create_dataset("success", data=np.asarray(traj.success, bool))
            if traj.dense_reward is not None:
                g.create_dataset("dense_reward", data=np.asarray(traj.dense_reward, np.float64))
            if traj.images is not None:
                g.create_dataset("obs/rgb", data=np.asarray(traj.images, np.uint8))
            (valid if is_valid_index(traj.index, valid_every) else train).append(traj.name)
        f.create_dataset("mask/train", data=np.array(train, dtype="S"), shape=(len(train),))
        f.create_dataset("mask/valid", data=np.array(valid, dtype="S"), shape=(len(valid),))
        f.attrs["vp2_format"] = FORMAT
        f.attrs["complete"] = True


@dataclasses.dataclass(frozen=True)
class DemoRecord:
    """Where one trajectory lives, and what it is (read from a shard without its arrays)."""

    path: Path
    name: str
    task: str
    split: str  # "train" or "valid"
    num_frames: int
    image_shape: tuple[int, ...]  # () in a states-only collection
    action_dim: int


def read_shard_index(path: str | Path) -> list[DemoRecord]:
    """Lists a shard's trajectories, checking that the file is complete and readable.

    Raises:
        DatasetError: naming the file, if it is truncated, corrupted or incomplete.
    """
    path = Path(path)
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("vp2_format") != FORMAT or not f.attrs.get("complete", False):
                raise DatasetError(
                    f"{path}: not a complete vp2 shard (interrupted write?). Delete it and "
                    "re-run the same `vp2 collect` command to regenerate it."
                )
            split = {n.decode(): "train" for n in f["mask/train"][()]}
            split.update({n.decode(): "valid" for n in f["mask/valid"][()]})
            records = []
            for name, g in f["data"].items():
                rgb = g.get("obs/rgb")
                records.append(
                    DemoRecord(
                        path=path,
                        name=name,
                        task=str(g.attrs["task"]),
                        split=split[name],
                        num_frames=int(g["states"].shape[0]),
                        image_shape=() if rgb is None else tuple(int(s) for s in rgb.shape[1:]),
                        action_dim=int(g["actions"].shape[1]),
                    )
                )
            return records
    except DatasetError:
        raise
    except (OSError, KeyError, ValueError) as exc:
        raise DatasetError(
            f"{path}: corrupted or truncated shard ({exc}). Delete it and re-run the same "
            "`vp2 collect` command to regenerate it."
        ) from exc


def read_trajectories(path: str | Path) -> Iterator[Trajectory]:
    """Reads every trajectory of a shard (arrays included)."""
    read_shard_index(path)  # validates
    with h5py.File(path, "r") as f:
        for name, g in f["data"].items():
            yield Trajectory(
                task=str(g.attrs["task"]),
                index=int(name.split("_")[1]),
                seed=int(g.attrs["seed"]),
                actions=g["actions"][()],
                states=g["states"][()],
                images=g["obs/rgb"][()] if "obs/rgb" in g else None,
                success=g["success"][()],
                env_meta=json.loads(g.attrs["env_meta"]),
                noise_sigma=float(g.attrs["noise_sigma"]),
                dense_reward=g["dense_reward"][()] if "dense_reward" in g else None,
            )


def load_manifest(root: str | Path) -> dict[str, Any]:
    """Reads a dataset's manifest, with a clear error when the path is not a dataset."""
    path = Path(root) / MANIFEST
    if not path.exists():
        raise DatasetError(
            f"{root}: no {MANIFEST}; not a vp2 dataset. Create one with `vp2 collect`."
        )
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: corrupted manifest ({exc})") from exc
    if manifest.get("format") != FORMAT:
        raise DatasetError(f"{path}: format {manifest.get('format')!r}, expected {FORMAT!r}")
    return manifest


def dataset_index(root: str | Path, require_complete: bool = True) -> list[DemoRecord]:
    """Every trajectory of a dataset, in dataset order, validating every shard.

    Raises:
        DatasetError: if the collection is incomplete (and ``require_complete``), or a shard
            is missing or corrupted (naming the file).
    """
    manifest = load_manifest(root)
    if require_complete and not manifest.get("complete", False):
        raise DatasetError(
            f"{root}: collection incomplete; re-run the `vp2 collect` command that created it "
            "to finish it (it resumes)."
        )
    records: list[DemoRecord] = []
    for chunk in manifest["chunks"]:
        path = shard_path(root, chunk["chunk"])
        if not path.exists():
            if require_complete:
                raise DatasetError(f"{path}: shard listed in the manifest is missing")
            continue
        records.extend(read_shard_index(path))
    records.sort(key=lambda r: int(r.name.split("_")[1]))
    return records


def require_images(root: str | Path, records: Sequence[DemoRecord]) -> None:
    """Raises a clear error if a dataset was collected without images."""
    if any(not r.image_shape for r in records):
        raise DatasetError(
            f"{root}: a states-only collection has no images yet; render them with "
            f"`vp2 render {root} --size 64`"
        )
