"""Success rates of the RoboDesk scripted policies (results in docs/robodesk.md).

Usage::

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.studies.robodesk_policies [--episodes 50] \\
        [--tasks all]

For every task: ``--episodes`` random initial states (``env.reset(seed=...)``), each rolled out
for 35 steps with the noise-free policy and with the data-collection noise σ = 0.1 and
σ = 0.2 (the same initial states for the three). An episode succeeds if ``env.is_success()``
holds after any of its steps. Nothing is rendered.
"""

from __future__ import annotations

import datetime
import os
import platform
import statistics
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from benchmarks import common  # noqa: E402
from vp2.data.policies.base import NoisyPolicy  # noqa: E402
from vp2.data.policies.robodesk import make_robodesk_policy  # noqa: E402
from vp2.envs.robodesk import TASKS, RoboDeskEnv  # noqa: E402

STEPS = 35
SEED_BASE = 10_000  # initial-state seeds SEED_BASE + i: disjoint from the tests' seeds


def episode(env: RoboDeskEnv, seed: int, sigma: float) -> int | None:
    """First step (0-based) at which the task succeeds, or ``None``."""
    env.reset(seed=seed)
    policy = make_robodesk_policy(env, np.random.default_rng([seed, 1]))
    if sigma > 0:
        policy = NoisyPolicy(policy, sigma, np.random.default_rng([seed, 2]))
    for t in range(STEPS):
        env.step(policy.act())
        if env.is_success():
            return t
    return None


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__, full_doc=True)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--tasks", default="all", help="comma-separated task names, or 'all'")
    parser.add_argument("--sigmas", default="0,0.1,0.2")
    args = parser.parse_args()
    tasks = TASKS if args.tasks == "all" else tuple(args.tasks.split(","))
    sigmas = [float(s) for s in args.sigmas.split(",")]
    print("# RoboDesk scripted policies: success within 35 steps (env.is_success at any step)")
    print(
        f"# {datetime.datetime.now().isoformat(timespec='seconds')}  {platform.node()}  "
        f"cpus={os.cpu_count()}  {args.episodes} initial states per task (seeds {SEED_BASE}+i)"
    )
    header = "".join(f"  {'σ=' + format(s, 'g'):>8s} {'steps':>5s}" for s in sigmas)
    print(f"{'task':26s}{header}")
    for task in tasks:
        env = RoboDeskEnv(task, seed=0, observation_size=None)
        start = time.time()
        cells = []
        for sigma in sigmas:
            firsts = [episode(env, SEED_BASE + i, sigma) for i in range(args.episodes)]
            solved = [f for f in firsts if f is not None]
            median = statistics.median(solved) + 1 if solved else float("nan")
            cells.append(f"  {len(solved) / len(firsts):8.0%} {median:5.0f}")
        env.close()
        print(f"{task:26s}{''.join(cells)}   ({time.time() - start:.0f} s)", flush=True)
    print("# steps: median number of env steps to the first success, over the successful episodes")


if __name__ == "__main__":
    main()
