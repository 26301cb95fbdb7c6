"""Simulator-oracle planning-step time with 1 and 2 workers, side by side, per environment.

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.speed.bench_oracle       # 200 samples
    MUJOCO_GL=egl .venv/bin/python -m benchmarks.speed.bench_oracle --num-samples 20 \\
        --tasks robodesk/push_red

One planning step = what the planning agent does once per control step with the oracle:
MPPI draws N candidate sequences of 10 actions, the oracle resets an environment to the
current state and simulates and renders every candidate (10 env steps + 10 renders at 64x64
each), the cost scores the frames, MPPI averages. Timed: ``PlanningAgent.act``, after a
warm-up step that starts the worker pool and builds each worker's environment and renderer
(reported separately). Repeats alternate 1, 2, 1, 2 workers so that machine noise hits both.

Each sample costs the same, so a step with N samples scales linearly: with ``--num-samples``
below 200 the table also shows the 200-sample step extrapolated (marked).

The floor (tabletop): the same physics steps (N x 10 control steps x 500) as plain ``mj_step``
calls on one core, in MuJoCo's own compiled loop (``mujoco.rollout``): the controls that the
stepping computed for a few random candidates from the planning state, replayed open-loop.
"x floor" is the planning step over that time, the floor timed again before every repeat and
the ratio taken within each repeat (median over repeats); the targets are <= 1.3x on one core
and <= 0.75x with both.

``--cull both`` times every worker count with the renderer's frustum culling off and on
(``VP2_RENDER_CULL``), alternating, in one run; ``--one-core`` pins this process and its
workers to the first CPU and keeps Mesa's rasteriser in the calling thread
(``LP_NUM_THREADS=0``), so that "one worker" uses one core and nothing else.
"""

from __future__ import annotations

import os
import platform
import statistics
import time

import mujoco
import numpy as np

from benchmarks import common
from vp2.envs import make_env
from vp2.envs.culling import CULL_ENV_VAR
from vp2.models import simulator
from vp2.models.simulator import SimulatorModel
from vp2.planning import Observation, PlannerConfig, PlanningAgent

SPEC_SAMPLES = 200


def observation(env, seed: int) -> tuple[Observation, np.ndarray]:
    """A mid-trial observation: reset, one zero step; the goal image is the reset frame."""
    env.reset(seed=seed)
    goal = env.render(64)
    zero = np.zeros(env.action_dim)
    env.step(zero)
    frames = np.stack([goal, env.render(64)])
    return Observation(1, frames, zero, env.serialize(), env.get_state()), goal


def _sim_breakdown(env, state: np.ndarray, steps: int = 10) -> tuple[float, float]:
    """Mean seconds of one env step and one 64x64 render, in this process."""
    rng = np.random.default_rng(0)
    env.reset_to(state)
    t_step = t_render = 0.0
    for _ in range(steps):
        t0 = time.perf_counter()
        env.step(rng.uniform(-1, 1, env.action_dim))
        t1 = time.perf_counter()
        env.render(64)
        t_render += time.perf_counter() - t1
        t_step += t1 - t0
    return t_step / steps, t_render / steps


def controlled_rollout(
    env, state: np.ndarray, actions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Steps ``actions`` (T, A) from ``state`` as ``env.step`` does, one physics step per call
    of the compiled loop, and returns every physics step's ``ctrl`` (T * 500, nu) and the final
    full-physics state."""
    model, data, st = env._model, env._data, env._stepper
    env.reset_to(state)
    controls = []
    for action in actions:
        goals = st.begin_step(action)
        for i in range(st.n_substeps):
            if i:
                mujoco.mj_step1(model, data)
            st.physics_steps(goals, 1)
            controls.append(data.ctrl.copy())
        st.end_step()
    final = np.empty(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(model, data, final, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    return np.array(controls), final


class PhysicsFloor:
    """Seconds of ``num_samples`` x 10 control steps of plain ``mj_step`` on one core: the
    physics steps of ``batch`` random candidates (their controls recorded from the controlled
    stepping) replayed open-loop by MuJoCo's compiled ``mujoco.rollout``, scaled linearly.
    Checks once that the replay reaches the controlled rollouts' states (the same physics
    steps); :meth:`time` replays them again, so that every repeat of a run has its own floor."""

    def __init__(self, env, state: np.ndarray, num_samples: int, batch: int = 4):
        from mujoco import rollout

        self._rollout = rollout.rollout
        self.model, self.data = env._model, env._data
        self.scale = num_samples / batch
        rng = np.random.default_rng(0)
        recorded = [controlled_rollout(env, state, rng.uniform(-1, 1, (10, env.action_dim)))
                    for _ in range(batch)]  # fmt: skip
        env.reset_to(state)
        mujoco.mj_forward(self.model, self.data)
        size = mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        initial = np.empty(size)
        mujoco.mj_getState(self.model, self.data, initial, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        self.controls = np.stack([c for c, _ in recorded])
        self.initial = np.tile(initial, (batch, 1))
        self._rollout(self.model, self.data, self.initial[:1], self.controls[:1, :10])  # warm-up
        states, _ = self._rollout(self.model, self.data, self.initial, self.controls)
        gap = max(float(np.abs(states[i, -1] - final).max())
                  for i, (_, final) in enumerate(recorded))  # fmt: skip
        print(f"floor: {batch} replayed candidates end {gap:.1e} from the controlled ones")

    def time(self) -> float:
        """Seconds of the scaled replay."""
        t0 = time.perf_counter()
        self._rollout(self.model, self.data, self.initial, self.controls)
        return (time.perf_counter() - t0) * self.scale


def set_culling(cull: str) -> None:
    """Frustum culling on ("1") or off ("0") for the pools started after and for the
    environments one-worker models keep in this process."""
    os.environ[CULL_ENV_VAR] = cull
    for env in simulator._PROCESS_ENVS._envs.values():
        if getattr(env, "_renderer", None) is not None:
            env._renderer.cull = cull == "1"


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--tasks", nargs="+", default=["tabletop/push_sphere", "robodesk/push_red"])
    parser.add_argument("--num-samples", type=int, default=SPEC_SAMPLES)
    parser.add_argument("--repeats", type=int, default=1, help="timed steps per worker count")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cull", choices=["on", "off", "both"], default="on",
                        help="the renderer's frustum culling (both: off and on, alternating)")
    parser.add_argument("--one-core", action="store_true",
                        help="pin everything to CPU 0, Mesa's rasteriser in the calling thread")
    args = parser.parse_args()
    if args.one_core:
        os.environ["LP_NUM_THREADS"] = "0"  # before the first GL context
        os.sched_setaffinity(0, {0})
    culls = {"on": ["1"], "off": ["0"], "both": ["0", "1"]}[args.cull]

    rows = []
    for task in args.tasks:
        env = make_env(task, seed=args.seed, observation_size=None)
        obs, goal = observation(env, args.seed)
        step_s, render_s = _sim_breakdown(env, obs.state)
        floor = (
            PhysicsFloor(env, obs.state, args.num_samples) if task.startswith("tabletop") else None
        )
        models = {(w, cull): SimulatorModel(action_dim=env.action_dim, num_workers=w)
                  for cull in culls for w in args.workers}  # fmt: skip
        times: dict[tuple[int, str], list[float]] = {key: [] for key in models}
        floors: list[float] = []
        startup: dict[tuple[int, str], float] = {}
        try:
            for key, model in models.items():
                set_culling(key[1])  # a pool starts here: its workers read the switch
                warm = PlanningAgent(model, PlannerConfig(num_samples=key[0]))
                warm.reset(task, goal, seed=0)
                t0 = time.perf_counter()
                warm.act(obs)
                startup[key] = time.perf_counter() - t0
            for r in range(args.repeats):
                if floor is not None:
                    floors.append(floor.time())
                for key, model in models.items():
                    agent = PlanningAgent(model, PlannerConfig(num_samples=args.num_samples))
                    agent.reset(task, goal, seed=r)
                    set_culling(key[1])
                    t0 = time.perf_counter()
                    agent.act(obs)
                    times[key].append(time.perf_counter() - t0)
        finally:
            for model in models.values():
                model.close()
            env.close()
        base = statistics.median(times[next(iter(models))])
        for key in models:
            t = statistics.median(times[key])
            # Each repeat's step over that repeat's floor: the ratio within a repeat.
            ratio = (statistics.median(a / b for a, b in zip(times[key], floors, strict=True))
                     if floors else None)  # fmt: skip
            rows.append((task, key, t, startup[key], base / t, step_s, render_s, times[key],
                         floors, ratio))

    print(
        f"machine: {platform.machine()} {os.cpu_count()} cores (load {os.getloadavg()[0]:.1f} at "
        f"the end), {args.num_samples} samples x 10 steps, {args.repeats} timed step(s) per row"
        f"{', pinned to one core, LP_NUM_THREADS=0' if args.one_core else ''}"
    )
    extrapolate = args.num_samples != SPEC_SAMPLES
    head = ("| task | workers | culling | planning step s (median) | per sample ms | speed-up |"
            " pool start s |")
    rule = "|---|---|---|---|---|---|---|"
    if extrapolate:
        head += f" {SPEC_SAMPLES}-sample step s (extrapolated) |"
        rule += "---|"
    head += " env step ms | render ms | floor s | x floor | runs s |"
    rule += "---|---|---|---|---|"
    print(head)
    print(rule)
    for task, (w, cull), t, start, speedup, step_s, render_s, runs, floors, ratio in rows:
        line = (
            f"| {task} | {w} | {'on' if cull == '1' else 'off'} | {t:.1f} | "
            f"{1000 * t / args.num_samples:.0f} | {speedup:.2f}x | {start:.1f} |"
        )
        if extrapolate:
            line += f" {t * SPEC_SAMPLES / args.num_samples:.0f} |"
        line += f" {1000 * step_s:.0f} | {1000 * render_s:.1f} |"
        line += (" - | - |" if ratio is None else
                 f" {', '.join(f'{x:.1f}' for x in floors)} | {ratio:.2f}x |")  # fmt: skip
        line += f" {', '.join(f'{x:.1f}' for x in runs)} |"
        print(line)


if __name__ == "__main__":
    main()
