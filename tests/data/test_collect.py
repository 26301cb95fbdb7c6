import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from tests import child_pids, wait_until_gone
from tests.data.conftest import TINY
from vp2.data import storage
from vp2.data.collect import (
    ChunkProgress,
    CollectionConfig,
    chunk_plan,
    collect,
    rollout,
    trajectory_seed,
)
from vp2.data.policies import data_noise_sigma, make_data_env


def test_chunk_plan_covers_every_index_once():
    plan = chunk_plan(TINY)
    covered = [i for c in plan for i in range(c["first"], c["first"] + c["count"])]
    assert covered == list(range(TINY.total)) and TINY.total == 6
    assert [c["count"] for c in plan] == [2, 2, 2]


def test_tiny_dataset_layout_and_content(tiny_dataset):
    manifest = storage.load_manifest(tiny_dataset)
    assert manifest["complete"] is True
    records = storage.dataset_index(tiny_dataset)
    assert [r.name for r in records] == [f"demo_{i}" for i in range(6)]
    # Streams interleave: even indices push_red, odd open_drawer.
    assert [r.task for r in records] == ["robodesk/push_red", "robodesk/open_drawer"] * 3
    assert [r.split for r in records] == ["train", "train", "valid"] * 2
    traj = next(storage.read_trajectories(storage.shard_path(tiny_dataset, 0)))
    assert traj.actions.shape == (35, 5) and traj.actions.dtype == np.float32
    assert traj.images.shape == (36, 32, 32, 3) and traj.images.dtype == np.uint8
    assert traj.states.shape[0] == 36 and traj.success.shape == (36,)
    assert np.all(np.abs(traj.actions) <= 1)
    assert traj.env_meta["name"] == "robodesk/push_red"
    assert traj.noise_sigma == pytest.approx(0.1)  # even stream index: sigma 0.1


def test_stored_states_replay_exactly(tiny_dataset):
    traj = next(storage.read_trajectories(storage.shard_path(tiny_dataset, 1)))
    env = make_data_env(traj.task, observation_size=32)
    env.reset_to(traj.states[0])
    for t, action in enumerate(traj.actions):
        obs, _, _, _, info = env.step(action)
        np.testing.assert_array_equal(env.get_state(), traj.states[t + 1])
        np.testing.assert_array_equal(obs, traj.images[t + 1])
        assert info["success"] == traj.success[t + 1]


def test_trajectory_depends_only_on_its_seed(tiny_dataset):
    """Re-running one trajectory by itself reproduces what the collector stored."""
    stored = {t.index: t for t in storage.read_trajectories(storage.shard_path(tiny_dataset, 1))}
    index = 3  # stream 1 (open_drawer), stream index 1
    stream = TINY.resolved_streams()[index % 2]
    env = make_data_env(stream, observation_size=32)
    fresh = rollout(
        env,
        stream,
        index,
        trajectory_seed(TINY.seed, stream, 1),
        35,
        32,
        data_noise_sigma(stream, 1),
    )
    np.testing.assert_array_equal(fresh.states, stored[index].states)
    np.testing.assert_array_equal(fresh.images, stored[index].images)
    assert fresh.noise_sigma == pytest.approx(0.2)


def test_rerun_is_a_no_op_and_other_settings_are_refused(tiny_dataset):
    before = {p.name: p.stat().st_mtime_ns for p in (tiny_dataset / "shards").iterdir()}
    collect(TINY, tiny_dataset, workers=1, progress=False)
    after = {p.name: p.stat().st_mtime_ns for p in (tiny_dataset / "shards").iterdir()}
    assert before == after
    other = CollectionConfig(**{**TINY.__dict__, "image_size": 48})
    with pytest.raises(FileExistsError, match="image_size: existing 32 vs requested 48"):
        collect(other, tiny_dataset, workers=1, progress=False)


def test_corrupted_shard_is_named(tiny_dataset, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(tiny_dataset, copy)
    shard = storage.shard_path(copy, 1)
    data = shard.read_bytes()
    shard.write_bytes(data[: len(data) // 2])
    with pytest.raises(storage.DatasetError, match=str(shard)):
        storage.dataset_index(copy)
    # Re-running the collection repairs it.
    collect(TINY, copy, workers=1, progress=False)
    assert len(storage.dataset_index(copy)) == 6


def test_sigkill_half_way_then_resume(tmp_path):
    """Kill a collection with SIGKILL after its first shard: its helper processes end with it,
    and re-running completes it exactly."""
    out = tmp_path / "killed"
    cmd = [
        sys.executable,
        "-m",
        "vp2.cli",
        "collect",
        "robodesk",
        "--streams",
        "robodesk/push_blue",
        "-n",
        "6",
        "--chunk-size",
        "2",
        "--image-size",
        "32",
        "--workers",
        "1",
        "--out",
        str(out),
    ]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=os.environ
    )
    deadline = time.time() + 300
    while not storage.shard_path(out, 0).exists():
        assert proc.poll() is None and time.time() < deadline, (
            "collection ended before its first shard"
        )
        time.sleep(0.2)
    helpers = child_pids(proc.pid)  # the progress queue's manager (and multiprocessing's tracker)
    assert helpers
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert wait_until_gone(helpers, timeout=15) == [], "orphaned processes of the killed collection"
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] is False
    with pytest.raises(storage.DatasetError, match="incomplete"):
        storage.dataset_index(out)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    records = storage.dataset_index(out)
    assert sorted(int(r.name[5:]) for r in records) == list(range(6))
    assert not list((out / "shards").glob(".*.tmp"))
    for shard in sorted((out / "shards").glob("*.hdf5")):
        for traj in storage.read_trajectories(shard):
            assert traj.images.shape == (36, 32, 32, 3) and np.all(np.isfinite(traj.states))


def test_states_only_collection_then_render_equals_a_rendered_collection(tiny_dataset, tmp_path):
    from vp2.classifiers.data import load_frames
    from vp2.data.loader import ClipDataset
    from vp2.data.render import rerender

    config = CollectionConfig(**{**TINY.__dict__, "render": False})
    states_only = collect(config, tmp_path / "states", workers=1, progress=False)
    records = storage.dataset_index(states_only)
    assert all(r.image_shape == () and r.num_frames == 36 for r in records)
    with pytest.raises(storage.DatasetError, match="vp2 render"):
        ClipDataset(states_only, split="train")
    rendered = rerender(states_only, tmp_path / "rendered", 32, workers=1, progress=False)
    for chunk in range(3):
        a = list(storage.read_trajectories(storage.shard_path(tiny_dataset, chunk)))
        b = list(storage.read_trajectories(storage.shard_path(rendered, chunk)))
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x.states, y.states)
            np.testing.assert_array_equal(x.images, y.images)
            np.testing.assert_array_equal(x.dense_reward, y.dense_reward)
    # RoboDesk trajectories carry the package's dense reward summed over each step's repeats;
    # the paper's classifier label is dense >= 30 (a wider region than strict success).
    traj = next(storage.read_trajectories(storage.shard_path(tiny_dataset, 0)))
    assert traj.dense_reward.shape == (36,) and np.all(
        (traj.dense_reward > 0) & (traj.dense_reward <= 50)
    )
    dense = load_frames(tiny_dataset, "push_red", "train", label="dense")
    strict = load_frames(tiny_dataset, "push_red", "train", label="success")
    assert np.all(dense.labels[strict.labels])  # success implies the dense label here
    assert dense.positives > strict.positives


def test_a_dataset_from_before_the_render_setting_still_resumes(tiny_dataset, tmp_path):
    import json
    import shutil

    old = tmp_path / "old"
    shutil.copytree(tiny_dataset, old)
    manifest = json.loads((old / storage.MANIFEST).read_text())
    del manifest["config"]["render"]  # written before states-only collection existed
    (old / storage.MANIFEST).write_text(json.dumps(manifest))
    assert collect(TINY, old, workers=1, progress=False) == old
    with pytest.raises(FileExistsError, match="render: existing True vs requested False"):
        collect(
            CollectionConfig(**{**TINY.__dict__, "render": False}), old, workers=1, progress=False
        )


class _Bar:
    """Records the bar's position after every update."""

    def __init__(self) -> None:
        self.n = 0
        self.positions: list[int] = []

    def update(self, k: int) -> None:
        self.n += k
        self.positions.append(self.n)


def test_progress_counts_trajectories_and_each_chunk_once():
    bar = _Bar()
    counter = ChunkProgress(bar, {0: 2, 1: 2, 2: 1})
    counter.trajectory(0)
    counter.trajectory(1)
    counter.trajectory(0)
    counter.trajectory(0)  # a re-run chunk reports again: capped at its size
    counter.chunk(0)  # already counted in full: no jump
    counter.chunk(2)  # a chunk whose reports never arrived counts its size when written
    counter.chunk(1)
    counter.trajectory(1)  # a straggler after the chunk was written: ignored
    assert bar.positions == [1, 2, 3, 3, 4, 5] and bar.n == 5


def test_local_collection_reports_every_trajectory(tmp_path, monkeypatch):
    """A pooled collection moves its bar once per trajectory and writes the same data."""
    import vp2.data.collect as collect_module

    bars = []

    class RecordingProgress(ChunkProgress):
        def __init__(self, bar, sizes):
            super().__init__(bar, sizes)
            bars.append(self)
            self.calls: list[str] = []

        def trajectory(self, chunk):
            self.calls.append("t")
            super().trajectory(chunk)

        def chunk(self, chunk):
            self.calls.append("c")
            super().chunk(chunk)

    monkeypatch.setattr(collect_module, "ChunkProgress", RecordingProgress)
    config = CollectionConfig(**{**TINY.__dict__, "trajectories_per_stream": 2})
    root = collect(config, tmp_path / "pooled", workers=2, progress=True)
    (counter,) = bars
    assert counter.calls.count("t") == 4 and counter.calls.count("c") == 2
    assert counter.bar.n == 4
    assert len(list((root / storage.SHARD_DIR).glob("*.hdf5"))) == 2


def test_a_split_that_leaves_a_stream_without_held_out_trajectories_is_refused():
    # Index i belongs to stream i % 2 and is held out when i % 10 == 9: every held-out index
    # is odd, so the first stream would have none.
    two = ("robodesk/flat_block_off_table", "robodesk/upright_block_off_table")
    config = CollectionConfig(env="robodesk", trajectories_per_stream=20, streams=two)
    with pytest.raises(ValueError, match=r"coprime with 2, e\.g\. 11"):
        config.validate()
    CollectionConfig(
        env="robodesk", trajectories_per_stream=20, streams=two, valid_every=11
    ).validate()
    CollectionConfig(
        env="robodesk", trajectories_per_stream=20, streams=two, valid_every=0
    ).validate()
    CollectionConfig(env="robodesk", trajectories_per_stream=20).validate()  # 7 streams, 10
    with pytest.raises(ValueError, match="seed must be a non-negative integer, got -1"):
        CollectionConfig(env="robodesk", trajectories_per_stream=20, seed=-1).validate()
    with pytest.raises(ValueError, match="valid_every must be >= 0"):
        CollectionConfig(env="robodesk", trajectories_per_stream=20, valid_every=-1).validate()


def test_zero_trajectories_is_an_error_not_the_default(tmp_path, capsys):
    from vp2 import cli

    # `-n 0` once fell back to the default count and collected 100 trajectories.
    assert cli.main(["collect", "tabletop", "-n", "0", "--out", str(tmp_path / "d")]) == 2
    assert "trajectories per stream must be > 0, got 0" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_tabletop_collection_keeps_only_the_pushes_the_original_kept(tmp_path):
    """Every stored tabletop trajectory passes the keep filter; a dropped draw is redrawn with
    the next retry seed, and the stored seed replays the stored trajectory."""
    from vp2.data.collect import retry_seed
    from vp2.data.policies.tabletop import keeps_push
    from vp2.envs.tabletop import TabletopEnv

    config = CollectionConfig(
        env="tabletop", trajectories_per_stream=6, image_size=16, chunk_size=6, valid_every=0,
        render=False,
    )  # fmt: skip
    out = collect(config, tmp_path / "tt", workers=1, progress=False)
    stream = config.resolved_streams()[0]
    positions = TabletopEnv.object_positions_from_state
    redrawn = 0
    for traj in storage.read_trajectories(storage.shard_path(out, 0)):
        first = trajectory_seed(config.seed, stream, traj.index)
        retries = [retry_seed(first, a) for a in range(1, 50)]
        assert traj.seed == first or traj.seed in retries
        redrawn += traj.seed != first
        moved = np.linalg.norm(
            positions(traj.states[-1])[:, :2] - positions(traj.states[0])[:, :2], axis=1
        )
        assert moved[:3].max() > 0.08 or moved[3] > 0.08
        env = make_data_env(stream, observation_size=None)
        fresh = rollout(
            env,
            stream,
            traj.index,
            traj.seed,
            35,
            16,
            data_noise_sigma(stream, traj.index),
            render=False,
        )
        np.testing.assert_array_equal(fresh.states, traj.states)
        if traj.seed != first:  # the first draw was dropped
            dropped = rollout(
                env,
                stream,
                traj.index,
                first,
                35,
                16,
                data_noise_sigma(stream, traj.index),
                render=False,
            )
            assert dropped is None
    # About half the scripted pushes move nothing far enough: #4 and #5 were redrawn.
    assert redrawn == 2
    start = np.zeros((4, 3))
    end = start.copy()
    end[3, 0] = 0.2  # only the sphere moved: counts only when it is the pushed object
    assert not keeps_push(start, end, pushed=0) and keeps_push(start, end, pushed=3)
    end[0, 2] = -0.6  # an object fell off the table
    assert not keeps_push(start, end, pushed=3)
