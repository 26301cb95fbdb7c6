"""The renderer's frustum culling on the tabletop: time per frame off and on, and the frames.

    MUJOCO_GL=egl LP_NUM_THREADS=0 OMP_NUM_THREADS=1 .venv/bin/python -m \\
        benchmarks.speed.bench_culling [--states 300] [--rounds 2] [--tasks push_large_cube ...]

Per task: ``--states`` varied states (resets every 30 steps, uniform random full actions), each
rendered at 64x64 by the environment's renderer with culling off and on, in alternating rounds
over all the states (one process; the median round reported per setting). Prints whether the
frames are equal bit for bit (also at 128x128) and how many geoms culling left out per frame.
``LP_NUM_THREADS=0`` keeps Mesa's rasteriser in the calling thread, i.e. one core.
"""

from __future__ import annotations

import os
import platform
import statistics
import time

import mujoco
import numpy as np

from benchmarks import common
from vp2.envs import TABLETOP_TASKS
from vp2.envs.tabletop import TabletopEnv


def varied_states(env: TabletopEnv, count: int, seed: int = 1) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    states = []
    for k in range(count):
        if k % 30 == 0:
            env.reset(seed=k)
        env.step(rng.uniform(-1, 1, env.action_dim))
        states.append(env.get_state())
    return states


def render_all(env: TabletopEnv, states: list[np.ndarray], cull: bool,
               size: int = 64) -> tuple[np.ndarray, list[int], float]:
    """Frames, geoms culled per frame and seconds per frame."""
    renderer = env._renderer
    renderer.cull = cull
    frames, culled = [], []
    t0 = time.perf_counter()
    for state in states:
        env.reset_to(state)
        mujoco.mj_kinematics(env._model, env._data)
        mujoco.mj_camlight(env._model, env._data)
        frames.append(env.render(size))
        culled.append(renderer._culling[(size, size)].culled)
    seconds = (time.perf_counter() - t0) / len(states)
    renderer.cull = True
    return np.stack(frames), culled, seconds


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--tasks", nargs="+", default=["push_large_cube", "push_sphere"],
                        choices=TABLETOP_TASKS)
    parser.add_argument("--states", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    print(f"machine: {platform.machine()} {os.cpu_count()} cores, LP_NUM_THREADS="
          f"{os.environ.get('LP_NUM_THREADS', 'unset')}, {args.states} states, "
          f"{args.rounds} alternating round(s) per setting")
    print("| task | off ms | on ms | on / off | geoms culled (mean of 96) | same frames 64, 128 |")
    print("|---|---|---|---|---|---|")
    for task in args.tasks:
        env = TabletopEnv(task, seed=0, observation_size=None)
        states = varied_states(env, args.states)
        env.render(64)
        same = []
        for size in (64, 128):
            a, _, _ = render_all(env, states, cull=False, size=size)
            b, _, _ = render_all(env, states, cull=True, size=size)
            same.append(bool(np.array_equal(a, b)))
        times: dict[bool, list[float]] = {False: [], True: []}
        counts: dict[bool, list[int]] = {}
        for _ in range(args.rounds):
            for cull in (False, True):
                _, counts[cull], seconds = render_all(env, states, cull)
                times[cull].append(seconds)
        off, on = (statistics.median(times[c]) * 1e3 for c in (False, True))
        print(f"| {task} | {', '.join(f'{1e3 * t:.2f}' for t in times[False])} | "
              f"{', '.join(f'{1e3 * t:.2f}' for t in times[True])} | {on / off:.2f} | "
              f"{np.mean(counts[True]):.1f} | {same[0]}, {same[1]} |")
        env.close()


if __name__ == "__main__":
    main()
