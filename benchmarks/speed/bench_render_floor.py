"""Rendering at the geometry floor: simplified render meshes, speed and fidelity.

Measures, for the render-only models with decimated visual meshes (``RENDER_SPEC`` of each
environment, :mod:`vp2.envs.meshes`):

* (a) RoboDesk: ``RoboDeskEnv.step`` with its 64x64 observation vs
  ``robodesk.RoboDesk(task='push_red', action_repeat=50, image_size=64).step``;
* (b) the render alone (64x64 observation of varied states): the new ``RENDER_SPEC`` vs the
  previous settings with the original meshes, for both environments;
* (c) tabletop: ``TabletopEnv.step`` with its 64x64 observation vs the robosuite environment
  (``TabletopWorld(camera_obs_size=64)``) stepped by robosuite with its own camera observation;
* (d) fidelity: mean absolute error (1/255) of the 64x64 observation against
  ``RENDER_SPEC.full_quality()`` with the ORIGINAL meshes (MuJoCo's defaults), over states of
  noisy scripted-policy trajectories (``make_task_policy`` + the data-collection noise) of
  each of the 11 tasks; mean and max per task and per environment.

Timings (a)-(c) are taken twice: side by side in one process (interleaved rounds, one call of
each variant per round, medians), and each variant alone in its own subprocess (same number
of rounds, medians).

Usage::

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.speed.bench_render_floor \\
        [--rounds 30] [--episodes 2] [--skip-subprocess]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks import common  # noqa: E402
from vp2.data.policies import ROBODESK_NOISE, TABLETOP_NOISE, make_task_policy  # noqa: E402
from vp2.data.policies.base import NoisyPolicy  # noqa: E402
from vp2.envs import ROBODESK_TASKS, TABLETOP_TASKS, make_env, robodesk, tabletop  # noqa: E402
from vp2.envs.rendering import Renderer, RenderSpec, mean_abs_error  # noqa: E402


def previous_spec(spec: RenderSpec) -> RenderSpec:
    """The settings before the simplified meshes: same knobs, original meshes and tessellation."""
    return dataclasses.replace(
        spec,
        mesh_reduction=0.0,
        plane_spacing=None,
        numslices=None,
        numstacks=None,
        numquads=None,
    )


# ---- timed variants: each a factory returning a zero-argument call ----------------------------
def _robodesk_states(count: int) -> list[np.ndarray]:
    env = robodesk.RoboDeskEnv("push_red", seed=0, observation_size=None)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    states = []
    for _ in range(count):
        env.step(rng.uniform(-0.5, 0.5, 5))
        states.append(env.get_state())
    return states


def _tabletop_states(count: int) -> list[np.ndarray]:
    env = tabletop.TabletopEnv("push_large_cube", seed=0, observation_size=None)
    env.reset(seed=7)
    rng = np.random.default_rng(0)
    states = []
    for _ in range(count):
        env.step(rng.uniform(-1, 1, 4))
        states.append(env.get_state())
    return states


def rd_ours() -> Callable[[], None]:
    env = robodesk.RoboDeskEnv("push_red", seed=0, observation_size=64)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    env.step(np.zeros(5))  # warm-up: GL context, render model
    return lambda: env.step(rng.uniform(-0.3, 0.3, 5))


def rd_package() -> Callable[[], None]:
    ours = robodesk.RoboDeskEnv("push_red", seed=0, observation_size=None)
    ours.reset(seed=0)
    package = common.robodesk_package("push_red")
    package.reset()
    common.load_package_state(package, ours.get_state())
    rng = np.random.default_rng(0)
    package.step(np.zeros(5))

    def call() -> None:
        common.rebind_package_gl(package)  # a no-op unless another GL context was made current
        package.step(rng.uniform(-0.3, 0.3, 5))

    return call


def _render_call(
    env, states: list[np.ndarray], renderer: Renderer | None, render: bool = True
) -> Callable[[], None]:
    """Loads the next state and renders it (``render=False``: only loads it)."""
    i = iter(range(10**9))
    data = env.data if isinstance(env, robodesk.RoboDeskEnv) else env._data
    model = env.model if isinstance(env, robodesk.RoboDeskEnv) else env._model

    def call() -> None:
        env.reset_to(states[next(i) % len(states)])
        mujoco.mj_kinematics(model, data)
        mujoco.mj_camlight(model, data)
        if not render:
            return
        if renderer is None:
            env.render(64)
        else:
            renderer.render(data, 64)

    call()
    return call


def rd_render_new() -> Callable[[], None]:
    env = robodesk.RoboDeskEnv("push_red", seed=0, observation_size=None)
    return _render_call(env, _robodesk_states(10), None)


def rd_render_old() -> Callable[[], None]:
    env = robodesk.RoboDeskEnv("push_red", seed=0, observation_size=None)
    renderer = Renderer(env.model, previous_spec(robodesk.RENDER_SPEC))
    return _render_call(env, _robodesk_states(10), renderer)


def rd_render_reset_only() -> Callable[[], None]:
    """The state loading that the render variants include (subtracted in the table)."""
    env = robodesk.RoboDeskEnv("push_red", seed=0, observation_size=None)
    return _render_call(env, _robodesk_states(10), None, render=False)


def tt_render_new() -> Callable[[], None]:
    env = tabletop.TabletopEnv("push_large_cube", seed=0, observation_size=None)
    return _render_call(env, _tabletop_states(10), None)


def tt_render_old() -> Callable[[], None]:
    env = tabletop.TabletopEnv("push_large_cube", seed=0, observation_size=None)
    renderer = Renderer(env._model, previous_spec(tabletop.DEFAULT_SCENE.render))
    return _render_call(env, _tabletop_states(10), renderer)


def tt_ours() -> Callable[[], None]:
    env = tabletop.TabletopEnv("push_large_cube", seed=0, observation_size=64)
    env.reset(seed=7)
    rng = np.random.default_rng(0)
    env.render(64)
    return lambda: env.step(rng.uniform(-1, 1, 4))


def tt_robosuite() -> Callable[[], None]:
    from vp2.envs._tabletop_stepper import LeanStepper
    from vp2.envs._tabletop_world import TabletopWorld

    ours = tabletop.TabletopEnv("push_large_cube", seed=0, observation_size=None)
    ours.reset(seed=7)
    world = TabletopWorld(camera_obs_size=64)
    common.load_into_world(ours, world, LeanStepper(world))
    rng = np.random.default_rng(0)
    gl = world.sim._render_context_offscreen.gl_ctx
    last: dict[str, np.ndarray] = {}

    def call() -> None:
        # robosuite renders into whichever GL context is current (it never makes its own
        # current again after creating it): another renderer in this process would make it
        # draw into the wrong context -- a wrong image, fast.
        gl.make_current()
        obs, *_ = world.step(rng.uniform(-1, 1, 4))
        last["image"] = obs[f"{world.camera_names[0]}_image"]

    def check() -> str:
        """robosuite's last image against a full-quality render of the same state."""
        model, data = world.sim.model._model, world.sim.data._data
        mujoco.mj_kinematics(model, data)
        mujoco.mj_camlight(model, data)
        full = Renderer(model, tabletop.DEFAULT_SCENE.render.full_quality()).render(data, 64)
        mae = mean_abs_error(np.flipud(last["image"]), full)
        return f"robosuite's camera image vs full quality, same state: MAE {mae:.2f}/255"

    call()
    call.check = check  # type: ignore[attr-defined]
    return call


VARIANTS: dict[str, Callable[[], Callable[[], None]]] = {
    "robodesk: vp2 step + 64x64 obs": rd_ours,
    "robodesk: robodesk.RoboDesk.step": rd_package,
    "robodesk: render, new RENDER_SPEC": rd_render_new,
    "robodesk: render, previous settings, original meshes": rd_render_old,
    "robodesk: state loading only (subtracted)": rd_render_reset_only,
    "tabletop: vp2 step + 64x64 obs": tt_ours,
    "tabletop: robosuite step + 64x64 camera obs": tt_robosuite,
    "tabletop: render, new RENDER_SPEC": tt_render_new,
    "tabletop: render, previous settings, original meshes": tt_render_old,
}


def time_interleaved(names: list[str], rounds: int) -> dict[str, list[float]]:
    calls = {name: VARIANTS[name]() for name in names}
    times: dict[str, list[float]] = {name: [] for name in names}
    for _ in range(rounds):
        for name, call in calls.items():
            t = time.perf_counter()
            call()
            times[name].append(time.perf_counter() - t)
    for name, call in calls.items():
        if hasattr(call, "check"):
            print(
                f"# check ({name}, {len(names)} variant(s) in the process): {call.check()}",
                file=sys.stderr,
            )
    return times


def time_subprocesses(names: list[str], rounds: int) -> dict[str, list[float]]:
    out = {}
    for name in names:
        proc = subprocess.run(
            [sys.executable, "-m", __spec__.name, "--single", name, "--rounds", str(rounds)],
            check=True,
            capture_output=True,
            text=True,
        )
        out[name] = json.loads(proc.stdout.strip().splitlines()[-1])
        for line in proc.stderr.splitlines():
            if line.startswith("# check"):
                print(line, file=sys.stderr)
    return out


def _ms(values: list[float]) -> float:
    return statistics.median(values) * 1e3


# ---- fidelity ---------------------------------------------------------------------------------
def fidelity(episodes: int) -> dict[str, dict[str, list[float]]]:
    """MAE of the observation (and of the previous settings) vs full quality, per task."""
    errors: dict[str, dict[str, list[float]]] = {}
    for env_name, tasks in (("robodesk", ROBODESK_TASKS), ("tabletop", TABLETOP_TASKS)):
        spec = robodesk.RENDER_SPEC if env_name == "robodesk" else tabletop.DEFAULT_SCENE.render
        for t, task in enumerate(tasks):
            env = make_env(f"{env_name}/{task}", seed=t, observation_size=None)
            model = env.model if env_name == "robodesk" else env._model
            data = env.data if env_name == "robodesk" else env._data
            full = Renderer(model, spec.full_quality())
            old = Renderer(model, previous_spec(spec))
            rows = errors[f"{env_name}/{task}"] = {"new": [], "previous": []}
            for episode in range(episodes):
                env.reset(seed=10_000 + 100 * t + episode)
                sigma = TABLETOP_NOISE if env_name == "tabletop" else ROBODESK_NOISE[episode % 2]
                policy = NoisyPolicy(
                    make_task_policy(env, np.random.default_rng([t, episode])),
                    sigma,
                    np.random.default_rng([t, episode, 1]),
                )
                for step in range(35):
                    env.step(policy.act())
                    if step % 5:
                        continue
                    new = env.render(64)  # the observation, through the render model
                    mujoco.mj_kinematics(model, data)
                    mujoco.mj_camlight(model, data)
                    ref = full.render(data, 64)
                    rows["new"].append(mean_abs_error(new, ref))
                    rows["previous"].append(mean_abs_error(old.render(data, 64), ref))
            full.close()
            old.close()
            env.close()
    return errors


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__, full_doc=True)
    parser.add_argument("--rounds", type=int, default=30, help="timed calls per variant")
    parser.add_argument("--episodes", type=int, default=2, help="noisy episodes per task (d)")
    parser.add_argument("--skip-subprocess", action="store_true")
    parser.add_argument("--single", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.single:  # one variant alone, in this (sub)process: print its times as JSON
        times = time_interleaved([args.single], args.rounds)[args.single]
        print(json.dumps(times))
        return

    load = os.getloadavg()
    print("# Rendering at the geometry floor")
    print(
        f"# {common.timestamp()}  {common.cpu_name()}  "
        f"cpus={os.cpu_count()}  MUJOCO_GL={os.environ.get('MUJOCO_GL')}  "
        f"mujoco={mujoco.__version__}  load={load[0]:.1f}  rounds={args.rounds}"
    )
    print(f"# robodesk.RENDER_SPEC = {robodesk.RENDER_SPEC}")
    print(f"# tabletop DEFAULT_SCENE.render = {tabletop.DEFAULT_SCENE.render}")
    names = list(VARIANTS)
    together = time_interleaved(names, args.rounds)
    alone = time_subprocesses(names, args.rounds) if not args.skip_subprocess else None
    print("\n## Speed (median ms per call)\n")
    print("| variant | one process, interleaved | own subprocess |")
    print("|---|---|---|")
    for name in names:
        sub = f"{_ms(alone[name]):.1f}" if alone else "-"
        print(f"| {name} | {_ms(together[name]):.1f} | {sub} |")

    def ratios(t: dict[str, list[float]]) -> dict[str, float]:
        reset = _ms(t["robodesk: state loading only (subtracted)"])
        rd_new = _ms(t["robodesk: render, new RENDER_SPEC"]) - reset
        rd_old = _ms(t["robodesk: render, previous settings, original meshes"]) - reset
        return {
            "(a) robodesk step: package / vp2": _ms(t["robodesk: robodesk.RoboDesk.step"])
            / _ms(t["robodesk: vp2 step + 64x64 obs"]),
            "(b) robodesk render ms (state loading subtracted): new": rd_new,
            "(b) robodesk render ms (state loading subtracted): previous": rd_old,
            "(b) robodesk render: previous / new": rd_old / rd_new,
            "(b) tabletop render: previous / new": _ms(
                t["tabletop: render, previous settings, original meshes"]
            )
            / _ms(t["tabletop: render, new RENDER_SPEC"]),
            "(c) tabletop step: robosuite / vp2": _ms(
                t["tabletop: robosuite step + 64x64 camera obs"]
            )
            / _ms(t["tabletop: vp2 step + 64x64 obs"]),
        }

    print("\n| ratio | one process, interleaved | own subprocesses |")
    print("|---|---|---|")
    r1 = ratios(together)
    r2 = ratios(alone) if alone else None
    for key in r1:
        print(f"| {key} | {r1[key]:.2f} | {f'{r2[key]:.2f}' if r2 else '-'} |")

    errors = fidelity(args.episodes)
    print(
        f"\n## Fidelity: MAE (1/255) of the 64x64 observation vs full quality with the original "
        f"meshes ({args.episodes} noisy scripted episodes per task, every 5th of 35 steps)\n"
    )
    print("| task | states | new mean | new max | previous mean | previous max |")
    print("|---|---|---|---|---|---|")
    per_env: dict[str, dict[str, list[float]]] = {}
    for task, rows in errors.items():
        env_rows = per_env.setdefault(task.split("/")[0], {"new": [], "previous": []})
        for k in rows:
            env_rows[k] += rows[k]
        print(
            f"| {task} | {len(rows['new'])} | {np.mean(rows['new']):.2f} | "
            f"{np.max(rows['new']):.2f} | {np.mean(rows['previous']):.2f} | "
            f"{np.max(rows['previous']):.2f} |"
        )
    for env_name, rows in per_env.items():
        print(
            f"| **{env_name} (all)** | {len(rows['new'])} | **{np.mean(rows['new']):.2f}** | "
            f"**{np.max(rows['new']):.2f}** | {np.mean(rows['previous']):.2f} | "
            f"{np.max(rows['previous']):.2f} |"
        )
    # Everything is printed. The robodesk package's (dm_control) and robosuite's GL contexts
    # free themselves in exit hooks that may run after EGL is terminated and print EGL
    # tracebacks; skip the interpreter's teardown.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


if __name__ == "__main__":
    main()
