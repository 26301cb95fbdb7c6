"""Env step time of this tree against another checkout of vp2, side by side in one run.

Usage::

    git worktree add /tmp/vp2-before <commit>
    MUJOCO_GL=egl .venv/bin/python -m benchmarks.speed.bench_stepping --against /tmp/vp2-before/src

Each round times, in a fresh subprocess per tree and alternating between the trees, ``--steps``
env steps without rendering (``observation_size=None``) of a RoboDesk and a tabletop env after a
warm-up step (the tabletop's first step compiles its numba kernel, cached on disk); random
actions, the same in both trees. Reports the median ms per env step of each tree over
``--rounds`` and their ratio. Both trees run with the same interpreter and packages.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

from benchmarks import common

CHILD = """
import json, sys, time
import numpy as np
from vp2.envs import make_env
out = {}
for task in ("robodesk/push_red", "tabletop/push_large_cube"):
    env = make_env(task, seed=0, observation_size=None)
    env.reset(seed=0)
    dim = env.action_space.shape[0]
    actions = np.random.default_rng(0).uniform(-1, 1, size=(STEPS + 1, dim))
    env.step(actions[0])
    t0 = time.perf_counter()
    for a in actions[1:]:
        env.step(a)
    out[task.split("/")[0]] = (time.perf_counter() - t0) / STEPS * 1e3
print(json.dumps(out))
"""


def time_tree(src: str, steps: int) -> dict[str, float]:
    env = {
        **os.environ,
        "PYTHONPATH": src,
        "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"),
        "OMP_NUM_THREADS": "1",
    }
    code = CHILD.replace("STEPS", str(steps))
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__, full_doc=True)
    parser.add_argument("--against", required=True, help="the other tree's src/ folder")
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    this = str(Path(__file__).resolve().parents[2] / "src")
    import mujoco

    common.print_header(__spec__.name, f"mujoco {mujoco.__version__}, other tree {args.against}")
    times: dict[str, dict[str, list[float]]] = {"this": {}, "other": {}}
    for _ in range(args.rounds):
        for label, src in (("other", args.against), ("this", this)):
            for env, ms in time_tree(src, args.steps).items():
                times[label].setdefault(env, []).append(ms)
    print(f"# {args.rounds} rounds x {args.steps} env steps, no rendering; median ms per step")
    print(f"{'env':10s} {'other':>9s} {'this':>9s} {'this/other':>11s}")
    for env in times["this"]:
        other, this_ = (statistics.median(times[k][env]) for k in ("other", "this"))
        print(f"{env:10s} {other:9.2f} {this_:9.2f} {this_ / other:11.2f}")


if __name__ == "__main__":
    main()
