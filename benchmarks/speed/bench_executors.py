"""Executors: Ray's throughput with 1 vs 2 worker CPUs, and its per-task overhead vs local.

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.speed.bench_executors    # all three parts
    MUJOCO_GL=egl .venv/bin/python -m benchmarks.speed.bench_executors --parts overhead

Needs an otherwise idle machine with at least 2 cores (3 is better: the driver also works).
One private Ray instance with 2 CPUs (loopback, no dashboard) serves every part.

* ``collect``: ``collect(tabletop)`` on a Ray executor with 1 and 2 actors (1 CPU each);
  trajectories/min, including actor start-up and environment construction.
* ``oracle``: ``run_benchmark`` with the simulator oracle (``--executor ray``, workers 1
  and 2) on the first shipped tabletop instances; trials/min.
* ``overhead``: a trivial task (returns its item) through the local pool (2 spawned
  processes) and through Ray (2 actors). Each executor runs N1 and N2 items; the marginal
  cost (t(N2) - t(N1)) / (N2 - N1) is the per-task overhead in ms, t(N1) minus N1 times
  that is the start-up.

Configurations alternate (1, 2, 1, 2 ...; local, ray, local, ray ...) so that machine noise
hits both alike; medians over ``--repeats`` are reported.
"""

from __future__ import annotations

import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

from benchmarks import common

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_NUM_THREADS", "1")


def _identity(x: int) -> int:
    return x


def _start_ray(cpus: int):
    from vp2.utils import executors

    executors._keep_ray_on_loopback()
    import ray

    ray.init(num_cpus=cpus, include_dashboard=False, logging_level="WARNING")
    return ray


def bench_collect(n: int, repeats: int) -> dict[int, float]:
    from vp2.data.collect import CollectionConfig, collect
    from vp2.utils.executors import RayExecutor

    config = CollectionConfig(env="tabletop", trajectories_per_stream=n, chunk_size=2)
    rates: dict[int, list[float]] = {1: [], 2: []}
    for _ in range(repeats):
        for workers in (1, 2):
            with tempfile.TemporaryDirectory() as tmp, RayExecutor(workers=workers) as ex:
                t0 = time.perf_counter()
                collect(config, Path(tmp) / "ds", progress=False, executor=ex)
                rates[workers].append(60 * config.total / (time.perf_counter() - t0))
    return {k: statistics.median(v) for k, v in rates.items()}


def bench_oracle(instances: int, seeds: int, samples: int, repeats: int) -> dict[int, float]:
    from vp2.benchmark import RunConfig, run_benchmark
    from vp2.planning.config import PlannerConfig

    rates: dict[int, list[float]] = {1: [], 2: []}
    for _ in range(repeats):
        for workers in (1, 2):
            with tempfile.TemporaryDirectory() as tmp:
                config = RunConfig(
                    model="simulator",
                    out=str(Path(tmp) / "run"),
                    tasks=("tabletop",),
                    num_instances=instances,
                    seeds=tuple(range(seeds)),
                    planner=PlannerConfig(num_samples=samples),
                    num_steps=5,
                    save_gifs=False,
                    progress=False,
                    executor="ray",
                    workers=workers,
                )
                t0 = time.perf_counter()
                result = run_benchmark(config)
                rates[workers].append(60 * result.num_run / (time.perf_counter() - t0))
    return {k: statistics.median(v) for k, v in rates.items()}


def bench_overhead(n1: int, n2: int, repeats: int) -> dict[str, tuple[float, float]]:
    from vp2.utils.executors import LocalExecutor, RayExecutor

    times: dict[str, dict[int, list[float]]] = {"local": {n1: [], n2: []}, "ray": {n1: [], n2: []}}
    for _ in range(repeats):
        for name in ("local", "ray"):
            for n in (n1, n2):
                ex = LocalExecutor(workers=2) if name == "local" else RayExecutor(workers=2)
                with ex:
                    t0 = time.perf_counter()
                    assert len(list(ex.imap_unordered(_identity, list(range(n))))) == n
                    times[name][n].append(time.perf_counter() - t0)
    out = {}
    for name, by_n in times.items():
        t1, t2 = statistics.median(by_n[n1]), statistics.median(by_n[n2])
        per_task = (t2 - t1) / (n2 - n1)
        out[name] = (1000 * per_task, t1 - n1 * per_task)
    return out


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument(
        "--parts",
        nargs="+",
        default=["collect", "oracle", "overhead"],
        choices=["collect", "oracle", "overhead"],
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("-n", type=int, default=16, help="tabletop trajectories to collect")
    parser.add_argument(
        "--instances", type=int, default=2, help="oracle: tabletop instances per category"
    )
    parser.add_argument("--seeds", type=int, default=1, help="oracle: seeds")
    parser.add_argument("--num-samples", type=int, default=20, help="oracle: planner samples")
    parser.add_argument("--n1", type=int, default=50)
    parser.add_argument("--n2", type=int, default=550)
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    ray = _start_ray(2)
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"ray {ray.__version__}\n"
    )
    try:
        if "collect" in args.parts:
            r = bench_collect(args.n, args.repeats)
            print(f"collect tabletop ({args.n} trajectories), Ray actors:")
            print("| worker CPUs | trajectories/min |\n|---|---|")
            print(f"| 1 | {r[1]:.1f} |\n| 2 | {r[2]:.1f} |")
            print(f"speed-up 2 vs 1: {r[2] / r[1]:.2f}x\n")
        if "oracle" in args.parts:
            r = bench_oracle(args.instances, args.seeds, args.num_samples, args.repeats)
            print(f"oracle run (simulator, {args.num_samples} samples, 5 steps), Ray actors:")
            print("| worker CPUs | trials/min |\n|---|---|")
            print(f"| 1 | {r[1]:.1f} |\n| 2 | {r[2]:.1f} |")
            print(f"speed-up 2 vs 1: {r[2] / r[1]:.2f}x\n")
        if "overhead" in args.parts:
            r = bench_overhead(args.n1, args.n2, args.repeats)
            print(f"trivial task, 2 workers ({args.n1} vs {args.n2} items):")
            print("| executor | ms per task | start-up s |\n|---|---|---|")
            for name, (ms, startup) in r.items():
                print(f"| {name} | {ms:.2f} | {startup:.2f} |")
    finally:
        ray.shutdown()


if __name__ == "__main__":
    main()
