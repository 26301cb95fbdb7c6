"""Executors: the local pool and Ray give the same results; Ray on a real two-node cluster.

The cluster tests start a head and a second node with ``ray start`` on loopback (``--num-cpus
1`` each), run ``vp2 run`` and ``vp2 collect`` on them as a user would, compare with
``--executor local``, and kill one node's worker processes mid-run. Every Ray process they
start is in one of two process groups, killed by id when the module's tests are done.
"""

from __future__ import annotations

import collections
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from tests.benchmark import tiny_suite_path
from vp2.benchmark.runner import run_benchmark
from vp2.data import storage
from vp2.data.collect import CollectionConfig, collect
from vp2.planning.config import PlannerConfig
from vp2.run.config import RunConfig
from vp2.run.results import trial_key
from vp2.run.run_dir import read_trials
from vp2.utils.executors import LiveQueue, LocalExecutor, RayExecutor, WorkerLost, make_executor

ray = pytest.importorskip("ray")

REPO = Path(__file__).resolve().parents[2]
PYTHON = sys.executable

# --------------------------------------------------------------------------- trivial work

_OFFSET: int | None = None


def _init(offset: int) -> None:
    global _OFFSET
    _OFFSET = offset


def _square_plus_offset(x: int) -> int:
    assert _OFFSET is not None, "the initialiser did not run in this worker"
    return x * x + _OFFSET


def _fail_on_three(x: int) -> int:
    if x == 3:
        raise ValueError("three is bad")
    return x


def _die_on_three(x: int) -> int:
    if x == 3:
        os._exit(1)
    return x


def _die_once(job: tuple[int, str]) -> int:
    x, marker = job
    if x == 3 and not os.path.exists(marker):
        Path(marker).touch()
        os._exit(1)
    return x


def test_local_executor_runs_the_initialiser_and_streams_every_item():
    with LocalExecutor(workers=1) as ex:
        out = dict(ex.imap_unordered(_square_plus_offset, range(6), _init, (10,)))
    assert out == {x: x * x + 10 for x in range(6)}


def test_local_executor_charges_a_dead_worker_to_its_item_and_reruns_the_others():
    """``on_lost="yield"``: the items in flight when a worker died are re-run alone; the one
    that kills its worker alone is yielded with WorkerLost, and runs alone again when the
    consumer puts it back into the live queue."""
    added: collections.deque[int] = collections.deque()
    lost, results = [], {}
    with LocalExecutor(workers=2) as ex:
        stream = ex.imap_unordered(_die_on_three, LiveQueue(range(6), added), on_lost="yield")
        for item, result in stream:
            if isinstance(result, WorkerLost):
                lost.append(item)
                if len(lost) == 1:
                    added.append(item)  # a retry, as the benchmark runner's
            else:
                results[item] = result
    assert lost == [3, 3] and results == {x: x for x in range(6) if x != 3}


def test_make_executor_validates():
    assert isinstance(make_executor("local", workers=2), LocalExecutor)
    with pytest.raises(ValueError, match="executor must be one of"):
        make_executor("dask")
    with pytest.raises(ValueError, match="--address is for"):
        make_executor("local", address="auto")
    with pytest.raises(ValueError, match="needs resources"):
        RayExecutor(num_cpus=0, num_gpus=0)


@pytest.fixture(scope="module")
def ray_executor():
    """A private two-actor Ray instance on this machine (as ``--executor ray`` starts it)."""
    ex = RayExecutor(workers=2, num_cpus=1)
    yield ex
    ex.close()


def test_ray_executor_gives_the_local_results_and_binds_to_loopback(ray_executor):
    items = list(range(12))
    out = list(ray_executor.imap_unordered(_square_plus_offset, items, _init, (7,)))
    with LocalExecutor(workers=1) as local:
        expected = dict(local.imap_unordered(_square_plus_offset, items, _init, (7,)))
    assert sorted(x for x, _ in out) == items  # every item exactly once
    assert dict(out) == expected
    assert {n["NodeManagerAddress"] for n in ray.nodes() if n["Alive"]} == {"127.0.0.1"}
    assert len({pid for pid in ray.get([a.ping.remote() for a in ray_executor._actors])}) == 2


def test_ray_executor_propagates_errors_of_the_function(ray_executor):
    with pytest.raises(ValueError, match="three is bad"):
        list(ray_executor.imap_unordered(_fail_on_three, range(5)))
    # The executor is still usable afterwards.
    assert sorted(x for x, _ in ray_executor.imap_unordered(_fail_on_three, [0, 1])) == [0, 1]


def test_ray_executor_reruns_an_item_whose_worker_died(ray_executor, tmp_path):
    marker = str(tmp_path / "died")
    jobs = [(x, marker) for x in range(6)]
    out = list(ray_executor.imap_unordered(_die_once, jobs))
    assert os.path.exists(marker)  # a worker did die
    assert sorted(r for _, r in out) == list(range(6))


def test_ray_executor_gives_up_on_an_item_that_always_kills_its_worker(ray_executor):
    ray_executor.max_lost_retries = 1
    try:
        out = dict(ray_executor.imap_unordered(_die_on_three, range(5), on_lost="yield"))
        assert isinstance(out.pop(3), WorkerLost) and out == {0: 0, 1: 1, 2: 2, 4: 4}
        with pytest.raises(WorkerLost):
            list(ray_executor.imap_unordered(_die_on_three, range(5)))
    finally:
        ray_executor.max_lost_retries = 2


def test_ray_executor_refuses_actors_the_cluster_cannot_fit(ray_executor):
    with RayExecutor(num_gpus=1) as ex:  # the private instance has no GPU
        with pytest.raises(ValueError, match="no Ray actor with num_cpus=1, num_gpus=1 fits"):
            list(ex.imap_unordered(_fail_on_three, [0]))


# --------------------------------------------------------------------------- a real cluster

# `ray start` swaps 127.0.0.1 for the machine's routable address (and then listens on every
# interface); a second node can only join with that switch on. This keeps the nodes on
# loopback: the test cluster is reachable from this machine only.
_RAY_CLI_ON_LOOPBACK = (
    "import sys, ray._private.services as s; s.resolve_ip_for_localhost = lambda h: h; "
    "from ray.scripts.scripts import main; sys.argv[0] = 'ray'; main()"
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Cluster:
    def __init__(self, root: Path) -> None:
        token = root / "auth_token"
        token.write_text(secrets.token_hex(32))
        self.env = {
            k: v for k, v in os.environ.items() if k != "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
        }
        # Token authentication, with a token of this test's own.
        self.env.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN_PATH=str(token),
                        MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), OMP_NUM_THREADS="1")
        self.root = root
        # Ray's socket paths must stay short (AF_UNIX: 107 bytes): not under pytest's tmp.
        self.ray_dir = tempfile.mkdtemp(prefix="vp2ray-")
        self.port = _free_port()
        self.address = f"127.0.0.1:{self.port}"
        self.groups: list[int] = []

    def start_node(self, *args: str) -> int:
        proc = subprocess.Popen(
            [PYTHON, "-c", _RAY_CLI_ON_LOOPBACK, "start", "--num-cpus", "1",
             "--node-ip-address", "127.0.0.1", "--object-store-memory", str(200 * 2**20),
             "--disable-usage-stats", *args],
            env=self.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            start_new_session=True,  # its daemons keep this process group: killed by id below
        )
        self.groups.append(proc.pid)
        output, _ = proc.communicate(timeout=120)
        assert proc.returncode == 0, output
        return proc.pid

    def start(self) -> None:
        self.start_node("--head", "--port", str(self.port), "--include-dashboard=false",
                        "--temp-dir", self.ray_dir)
        self.start_node("--address", self.address)

    def stop(self) -> None:
        for pgid in self.groups:
            try:
                os.killpg(pgid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        shutil.rmtree(self.ray_dir, ignore_errors=True)

    def raylet_pid(self, group: int) -> int:
        out = subprocess.run(["ps", "-eo", "pid=,pgid=,comm="], capture_output=True,
                             text=True).stdout
        for line in out.splitlines():
            pid, pgid, comm = line.split(None, 2)
            if int(pgid) == group and comm.strip() == "raylet":
                return int(pid)
        raise AssertionError(f"no raylet in process group {group}")

    def worker_pids(self, group: int) -> list[int]:
        """The node's worker processes (the raylet's children other than its agents)."""
        out = subprocess.run(["ps", "-o", "pid=,args=", "--ppid", str(self.raylet_pid(group))],
                             capture_output=True, text=True).stdout
        return [int(line.split(None, 1)[0]) for line in out.splitlines()
                if "Agent" not in line and line.strip()]

    def vp2(self, *args: str, wait: bool = True):
        cmd = [PYTHON, "-m", "vp2.cli", *args]
        if not wait:
            return subprocess.Popen(cmd, env=self.env, cwd=REPO, stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True)
        proc = subprocess.run(cmd, env=self.env, cwd=REPO, capture_output=True, text=True,
                              timeout=600)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        return proc


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    c = _Cluster(tmp_path_factory.mktemp("ray-cluster"))
    try:
        c.start()
        yield c
    finally:
        c.stop()


def _run_args(out: Path, seeds: tuple[int, ...], steps: int = 3) -> list[str]:
    return ["run", "--model", "repeat_last_frame", "--suite", str(tiny_suite_path()),
            "--seeds", *map(str, seeds), "--num-steps", str(steps), "--num-samples", "8",
            "--no-gifs", "--no-progress", "--out", str(out)]


def _outcomes(records):
    return {
        trial_key(r): (r["success"], tuple(r["success_steps"]), json.dumps(r["actions"]))
        for r in records
    }


def _local_reference(out: Path, seeds: tuple[int, ...], steps: int = 3):
    return run_benchmark(RunConfig(
        model="repeat_last_frame", out=str(out), suite=str(tiny_suite_path()), seeds=seeds,
        num_steps=steps, planner=PlannerConfig(num_samples=8), save_gifs=False, progress=False,
    ))


def test_vp2_run_on_a_two_node_cluster_matches_the_local_executor(cluster, tmp_path):
    seeds = (0, 1, 2)
    cluster.vp2(*_run_args(tmp_path / "ray", seeds), "--executor", "ray",
                "--address", cluster.address, "--workers", "2")
    on_ray = read_trials(tmp_path / "ray")
    local = _local_reference(tmp_path / "local", seeds).records
    assert sorted(trial_key(r) for r in on_ray) == sorted(trial_key(r) for r in local)
    assert len(on_ray) == 6 and all(r["error"] is None for r in on_ray)
    assert _outcomes(on_ray) == _outcomes(local)
    # Resume under the other executor: nothing is left to run, nothing is written twice.
    cluster.vp2(*_run_args(tmp_path / "ray", seeds), "--resume")
    assert len(read_trials(tmp_path / "ray")) == 6


def test_vp2_collect_on_a_two_node_cluster_matches_the_local_executor(cluster, tmp_path):
    cluster.vp2("collect", "tabletop", "-n", "4", "--chunk-size", "2", "--image-size", "32",
                "--executor", "ray", "--address", cluster.address, "--out",
                str(tmp_path / "ray"))
    config = CollectionConfig(env="tabletop", trajectories_per_stream=4, image_size=32,
                              chunk_size=2)
    collect(config, tmp_path / "local", workers=1, progress=False)
    for root in ("ray", "local"):
        assert storage.load_manifest(tmp_path / root)["complete"] is True
    ray_manifest = storage.load_manifest(tmp_path / "ray")
    local_manifest = storage.load_manifest(tmp_path / "local")
    assert ray_manifest["config"] == local_manifest["config"]
    assert ray_manifest["chunks"] == local_manifest["chunks"]
    for chunk in local_manifest["chunks"]:
        a = list(storage.read_trajectories(storage.shard_path(tmp_path / "ray", chunk["chunk"])))
        b = list(storage.read_trajectories(storage.shard_path(tmp_path / "local", chunk["chunk"])))
        assert [t.index for t in a] == [t.index for t in b] and len(a) == chunk["count"]
        for ta, tb in zip(a, b, strict=True):
            assert (ta.task, ta.seed, ta.noise_sigma) == (tb.task, tb.seed, tb.noise_sigma)
            for field in ("actions", "states", "images", "success"):
                np.testing.assert_array_equal(getattr(ta, field), getattr(tb, field))


@pytest.mark.slow  # ~1 min; the fast set keeps the Ray executor's rerun of a dead worker's item
def test_killing_a_nodes_workers_mid_run_runs_every_trial_exactly_once(cluster, tmp_path):
    seeds, steps = (0, 1, 2, 3, 4, 5), 6
    out = tmp_path / "ray"
    proc = cluster.vp2(*_run_args(out, seeds, steps), "--executor", "ray", "--address",
                       cluster.address, "--workers", "2", wait=False)
    second_node = cluster.groups[1]
    killed: list[int] = []
    try:
        deadline = time.monotonic() + 300
        # Mid-run: some trials written, and the second node's actor at work.
        while time.monotonic() < deadline and proc.poll() is None:
            done = len(read_trials(out)) if (out / "trials.jsonl").exists() else 0
            workers = cluster.worker_pids(second_node)
            if done >= 1 and workers:
                for pid in workers:
                    os.kill(pid, signal.SIGKILL)
                killed += workers
                break
            time.sleep(0.2)
        output, _ = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert killed, "the run ended before a worker could be killed"
    assert proc.returncode == 0, output
    records = read_trials(out)
    keys = [trial_key(r) for r in records]
    assert len(keys) == len(set(keys)) == 12  # every trial exactly once
    assert all(r["error"] is None for r in records)
    assert "a Ray worker died" in output  # the lost trial was re-run, not charged
    reference = _local_reference(tmp_path / "local", seeds, steps).records
    assert _outcomes(records) == _outcomes(reference)
