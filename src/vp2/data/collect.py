"""Scripted data collection: N trajectories per task, in parallel, resumable.

Trajectory ``i`` of a dataset is fully determined by ``(seed, its data stream, its index
in that stream)``: which worker ran it, how many workers there were, or whether the run was
interrupted and resumed never changes a trajectory. Indices interleave the streams (index
``i`` belongs to stream ``i % num_streams``), so a dataset's first N trajectories are
balanced across tasks, and a larger collection with the same seed starts with a smaller one's
trajectories.

The work is cut into chunks of ``chunk_size`` trajectories; each chunk becomes one shard,
written once and atomically by the collecting process. Re-running the same command skips
the shards that exist and are valid, so a killed collection resumes where it stopped.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import math
import threading
import time
import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from vp2.data import storage
from vp2.data.datasets import DEFAULT_TRAJECTORIES  # noqa: F401 - re-exported
from vp2.data.policies import data_noise_sigma, make_data_env, make_policy, stream_names
from vp2.envs.base import Env
from vp2.envs.cache import EnvCache
from vp2.envs.robodesk import ACTION_REPEAT
from vp2.utils.executors import Executor, LocalExecutor, spawn_manager
from vp2.utils.io import remove_stale_temporaries, write_json_atomic
from vp2.utils.seeds import check_seed

log = logging.getLogger(__name__)

#: Control steps per trajectory (36 frames: the initial one and one per action).
HORIZON = 35


@dataclasses.dataclass(frozen=True)
class CollectionConfig:
    """Everything that determines a dataset's content.

    Attributes:
        env: ``"robodesk"`` or ``"tabletop"``.
        streams: data streams to collect (``None``: the environment's default streams:
            every RoboDesk task, or the tabletop random-object pushing stream).
        trajectories_per_stream: trajectories collected for each stream.
        image_size: side of the stored observations.
        seed: base seed of the whole dataset.
        horizon: actions per trajectory.
        chunk_size: trajectories per shard (the unit of work and of resumption).
        valid_every: every ``valid_every``-th trajectory goes to the validation split.
        render: store observations; ``False`` stores states only (physics alone, several
            times faster on a CPU), to be rendered later with ``vp2 render``.
    """

    env: str
    trajectories_per_stream: int
    streams: tuple[str, ...] | None = None
    image_size: int = 64
    seed: int = 0
    horizon: int = HORIZON
    chunk_size: int = 10
    valid_every: int = 10
    render: bool = True

    def resolved_streams(self) -> tuple[str, ...]:
        return tuple(self.streams) if self.streams else stream_names(self.env)

    def validate(self) -> None:
        if self.trajectories_per_stream <= 0:
            raise ValueError(f"trajectories per stream must be > 0, got {self.trajectories_per_stream}")
        if self.image_size <= 0 or self.horizon <= 0 or self.chunk_size <= 0:
            raise ValueError("image_size, horizon and chunk_size must be positive")
        check_seed(self.seed)
        known = stream_names(self.env)
        for s in self.resolved_streams():
            if s not in known:
                raise ValueError(f"unknown data stream {s!r} for env {self.env!r}; known: {', '.join(known)}")
        if self.valid_every < 0:
            raise ValueError(f"valid_every must be >= 0 (0: no validation split), got {self.valid_every}")
        streams = len(self.resolved_streams())
        if self.valid_every > 0 and math.gcd(streams, self.valid_every) > 1:
            # Index i belongs to stream i % streams and is held out when i % valid_every ==
            # valid_every - 1: with a common factor, some streams never reach a held-out index.
            fits = next(v for v in range(self.valid_every, 10 * self.valid_every) if math.gcd(streams, v) == 1)
            raise ValueError(
                f"{streams} data streams with a validation split of every {self.valid_every}th "
                "trajectory would hold out no trajectory of some streams (the dataset's indices "
                f"interleave the streams); choose --valid-every coprime with {streams}, e.g. {fits}"
            )

    @property
    def total(self) -> int:
        return self.trajectories_per_stream * len(self.resolved_streams())

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["streams"] = list(self.resolved_streams())
        return d


def trajectory_seed(seed: int, stream: str, stream_index: int) -> int:
    """The seed of one trajectory: depends only on the dataset seed, its stream and index."""
    ss = np.random.SeedSequence([seed, zlib.crc32(stream.encode()), stream_index])
    return int(ss.generate_state(1, np.uint32)[0])


#: Episodes drawn for one trajectory before the collection gives up (the tabletop's filter keeps
#: about half of the pushes, so 50 failures in a row mean a broken policy).
MAX_ATTEMPTS = 50


def retry_seed(seed: int, attempt: int) -> int:
    """The seed of a trajectory's ``attempt``-th redraw (attempt >= 1) after the collection
    filter dropped the earlier episodes; the trajectory records the seed it was made from."""
    return int(np.random.SeedSequence([seed, attempt]).generate_state(1, np.uint32)[0])


def chunk_plan(config: CollectionConfig, indices: Sequence[int] | None = None) -> list[dict[str, Any]]:
    """The shards of a collection: ``[{"chunk": c, "first": i0, "count": n}, ...]``; with
    ``indices``, one shard per listed trajectory, numbered by its index (shard ``i`` holds
    trajectory ``i``)."""
    total = config.total
    if indices is not None:
        return [{"chunk": i, "first": i, "count": 1} for i in indices]
    return [
        {"chunk": c, "first": start, "count": min(config.chunk_size, total - start)}
        for c, start in enumerate(range(0, total, config.chunk_size))
    ]


def rollout(
    env: Env,
    stream: str,
    index: int,
    seed: int,
    horizon: int,
    image_size: int,
    noise_sigma: float | Sequence[float],
    render: bool = True,
) -> storage.Trajectory | None:
    """Runs one noisy scripted trajectory from a seeded initial state and records it.

    RoboDesk trajectories also record the package's dense reward of every step (the
    classifiers' paper label, SPEC §6); ``render=False`` records no images. ``None`` when the
    policy's collection filter drops the episode (``ScriptedPolicy.keeps``: the tabletop keeps
    only the pushes the original kept).
    """
    reset_seed, policy_seed, noise_seed = np.random.SeedSequence(seed).generate_state(3)
    env.reset(seed=int(reset_seed))
    policy = make_policy(env, stream, np.random.default_rng(policy_seed), np.random.default_rng(noise_seed), noise_sigma)
    policy.reset()
    goal = policy.goal_state()
    env.set_goal(goal)

    dense_reward = getattr(env, "dense_reward", None)  # RoboDesk envs only
    if dense_reward is not None:
        env.track_dense_reward = True
    states = [env.get_state()]
    images = [env.render(image_size)] if render else None
    success = [env.is_success(goal)]
    dense = [ACTION_REPEAT * dense_reward()] if dense_reward is not None else None
    actions = []
    for _ in range(horizon):
        # Executed as stored: float32 (what datasets hold), so replays are exact.
        action = env.check_action(policy.act()).astype(np.float32)
        obs, _, _, _, info = env.step(action)
        actions.append(action)
        states.append(env.get_state())
        if images is not None:
            images.append(obs if obs is not None and obs.shape[0] == image_size else env.render(image_size))
        success.append(bool(info["success"]))
        if dense is not None:
            dense.append(info["dense_reward"])
    if not policy.keeps(np.asarray(states)):
        return None
    sigma = np.asarray(noise_sigma, np.float64)
    return storage.Trajectory(
        task=stream,
        index=index,
        seed=seed,
        actions=np.asarray(actions, np.float32),
        states=np.asarray(states, np.float64),
        images=None if images is None else np.asarray(images, np.uint8),
        success=np.asarray(success, bool),
        env_meta=env.serialize(),
        noise_sigma=float(sigma.max()),
        dense_reward=None if dense is None else np.asarray(dense, np.float64),
    )


# One environment per data stream per worker process, built on first use (closed at the end of
# a collection, for the collections that run in this process).
_WORKER_ENVS = EnvCache(64)


def _collect_chunk(job: tuple[dict[str, Any], dict[str, Any], Any]) -> list[storage.Trajectory]:
    config_json, chunk, progress_queue = job
    config = CollectionConfig(**{**config_json, "streams": tuple(config_json["streams"])})
    streams = config.resolved_streams()
    trajectories = []
    for index in range(chunk["first"], chunk["first"] + chunk["count"]):
        stream = streams[index % len(streams)]
        stream_index = index // len(streams)
        size = config.image_size if config.render else None
        env = _WORKER_ENVS.get_or_make(
            (stream, size), functools.partial(make_data_env, stream, observation_size=size)
        )
        seed = trajectory_seed(config.seed, stream, stream_index)
        for attempt in range(MAX_ATTEMPTS):
            trajectory = rollout(
                env,
                stream,
                index,
                seed if attempt == 0 else retry_seed(seed, attempt),
                config.horizon,
                config.image_size,
                data_noise_sigma(stream, stream_index),
                render=config.render,
            )
            if trajectory is not None:
                break
        else:
            raise RuntimeError(
                f"{stream}: trajectory {index} was dropped by the collection filter "
                f"{MAX_ATTEMPTS} times in a row; the scripted policy no longer moves objects"
            )
        trajectories.append(trajectory)
        if progress_queue is not None:
            progress_queue.put(chunk["chunk"])
    return trajectories


class ChunkProgress:
    """A progress bar that moves per trajectory although work comes back per chunk.

    Workers put their chunk's number on a queue after every trajectory; a thread here drains it.
    A chunk counts at most its size (a chunk re-run after a lost worker reports again), and a
    finished chunk counts exactly its size, whatever arrived.
    """

    def __init__(self, bar: Any, sizes: dict[int, int]) -> None:
        self.bar = bar
        self._sizes = sizes
        self._seen: dict[int, int] = {}
        self._done: set[int] = set()
        self._lock = threading.Lock()

    def trajectory(self, chunk: int) -> None:
        """One trajectory of ``chunk`` finished (a worker said so)."""
        with self._lock:
            if chunk in self._done or self._seen.get(chunk, 0) >= self._sizes[chunk]:
                return
            self._seen[chunk] = self._seen.get(chunk, 0) + 1
            self.bar.update(1)

    def chunk(self, chunk: int) -> None:
        """``chunk`` is written: it counts its full size from now on."""
        with self._lock:
            if chunk not in self._done:
                self._done.add(chunk)
                self.bar.update(self._sizes[chunk] - self._seen.get(chunk, 0))

    @contextlib.contextmanager
    def listening(self, enabled: bool) -> Iterator[Any]:
        """Yields a queue for the workers (``None`` when ``enabled`` is false: Ray workers on
        other machines cannot reach it) and drains it until the block ends."""
        if not enabled:
            yield None
            return
        with spawn_manager() as manager:
            queue = manager.Queue()

            def drain() -> None:
                while (item := queue.get()) is not None:
                    self.trajectory(item)

            thread = threading.Thread(target=drain, daemon=True)
            thread.start()
            try:
                yield queue
            finally:
                queue.put(None)
                thread.join()


def _check_existing(
    root: Path, config: CollectionConfig, indices: list[int] | None = None
) -> dict[str, Any] | None:
    path = root / storage.MANIFEST
    if not path.exists():
        if root.exists() and any(root.iterdir()):
            raise FileExistsError(
                f"{root} exists, is not empty and is not a vp2 dataset; choose another --out"
            )
        return None
    manifest = storage.load_manifest(root)
    # Datasets collected before `render` existed stored images.
    manifest["config"] = {"render": True, **manifest["config"]}
    if manifest["config"] != config.to_json():
        diffs = {
            k: (manifest["config"].get(k), v)
            for k, v in config.to_json().items()
            if manifest["config"].get(k) != v
        }
        detail = ", ".join(f"{k}: existing {a!r} vs requested {b!r}" for k, (a, b) in diffs.items())
        raise FileExistsError(
            f"{root} holds a dataset collected with different settings ({detail}). "
            "Use another --out, or delete it to start over."
        )
    if manifest.get("indices") != indices:
        held = "all trajectories" if manifest.get("indices") is None else "a subset of trajectories"
        raise FileExistsError(
            f"{root} holds {held} of this collection, not the ones requested. Use another "
            "--out, or delete it to start over."
        )
    return manifest


def collect(
    config: CollectionConfig,
    out: str | Path,
    workers: int | None = None,
    progress: bool = True,
    executor: Executor | None = None,
    indices: Sequence[int] | None = None,
) -> Path:
    """Collects (or completes) a dataset; returns its directory.

    Args:
        config: what to collect.
        out: dataset directory. If it holds a dataset with the same config, only the missing
            shards are collected (resume); with another config, ``FileExistsError``.
        workers: worker processes (default: one per core; ``1`` runs in this process).
        progress: show a progress bar with trajectories/s.
        executor: where chunks run (:mod:`vp2.utils.executors`; default: a
            :class:`~vp2.utils.executors.LocalExecutor` with ``workers``). This process
            alone writes the shards, whichever executor ran them.
        indices: collect only these trajectories of the dataset ``config`` describes (each
            the very trajectory the whole collection holds at that index, in its split), one
            shard each; the manifest lists them under ``indices``. ``vp2 diagnose`` collects
            a default dataset's validation trajectories this way
            (:mod:`vp2.data.held_out`).
    """
    config.validate()
    root = Path(out)
    if indices is not None:
        indices = sorted({int(i) for i in indices})
        if not indices or indices[0] < 0 or indices[-1] >= config.total:
            raise ValueError(
                f"indices must name trajectories 0..{config.total - 1} of the collection, "
                f"got {indices[:1] + indices[-1:] if indices else 'none'}"
            )
    _check_existing(root, config, indices)
    root.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(root / storage.SHARD_DIR) if (root / storage.SHARD_DIR).exists() else None
    plan = chunk_plan(config, indices)
    manifest = {
        "format": storage.FORMAT,
        "config": config.to_json(),
        **({} if indices is None else {"indices": indices}),
        "chunks": plan,
        "complete": False,
    }
    write_json_atomic(root / storage.MANIFEST, manifest)

    todo = []
    for chunk in plan:
        path = storage.shard_path(root, chunk["chunk"])
        if path.exists():
            try:
                if len(storage.read_shard_index(path)) == chunk["count"]:
                    continue
            except storage.DatasetError as exc:
                log.warning("regenerating %s", exc)
            path.unlink()
        todo.append(chunk)

    executor = LocalExecutor(workers) if executor is None else executor
    total = sum(c["count"] for c in plan)
    done_before = total - sum(c["count"] for c in todo)
    config_json = config.to_json()
    start = time.perf_counter()
    with tqdm(
        total=total, initial=done_before, unit="traj", desc=f"collect {config.env}",
        disable=not progress, smoothing=0.1,
    ) as bar:
        env_meta = {"env": config.env, "collection": config_json}
        counter = ChunkProgress(bar, {c["chunk"]: c["count"] for c in todo})
        # Per-trajectory updates where the workers can reach this process (local pools).
        with (
            counter.listening(progress and isinstance(executor, LocalExecutor)) as queue,
            contextlib.closing(_WORKER_ENVS),
        ):
            jobs = [(config_json, chunk, queue) for chunk in todo]
            for (_, chunk, _), trajectories in executor.imap_unordered(_collect_chunk, jobs):
                storage.write_shard(
                    storage.shard_path(root, chunk["chunk"]), trajectories, env_meta,
                    config.valid_every,
                )
                counter.chunk(chunk["chunk"])
    manifest["complete"] = True
    manifest["collected_seconds"] = round(time.perf_counter() - start, 3)
    write_json_atomic(root / storage.MANIFEST, manifest)
    return root
