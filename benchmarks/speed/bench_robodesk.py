"""RoboDesk speed and rendering-fidelity benchmarks (results in docs/robodesk.md).

Usage::

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.speed.bench_robodesk speed   [--steps 30]
    MUJOCO_GL=egl .venv/bin/python -m benchmarks.speed.bench_robodesk render  [--episodes 2]

``speed`` times, side by side (interleaved, one call of each per round, median over rounds):

* (a) ``RoboDeskEnv.step`` with its 64x64 observation vs ``robodesk.RoboDesk.step`` with its
  own observation (the package renders with a fresh dm_control camera per frame);
* (b) both without rendering (``observation_size=None`` / the package's ``_get_obs`` replaced);
* (c) the floor: 500 raw ``mujoco.mj_step`` calls (one env step is 50 x 10 physics steps);
* (d) our step without rendering through MuJoCo's Python bindings, one call per physics step
  and IK iteration (``RoboDeskEnv._simulate_python``), against (b), the compiled step.

``oracle`` times one simulator-oracle planning step on push_red's instance #0 (``--samples``
candidates, in this process), the compiled step against the Python-bindings step, alternating,
and checks that both choose the same action to the last bit.

``render`` draws varied states (every task, the noisy scripted policies) and renders each with
MuJoCo's full quality (:meth:`RenderSpec.full_quality`) and with candidate quality settings,
reporting the mean absolute error of the 64x64 observation (in 1/255) and the time per frame.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import statistics
import time

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks import common  # noqa: E402
from vp2.data.policies.robodesk import make_noisy_robodesk_policy  # noqa: E402
from vp2.envs.rendering import Renderer, RenderSpec, mean_abs_error  # noqa: E402
from vp2.envs.robodesk import RENDER_SPEC, TASKS, RoboDeskEnv  # noqa: E402

_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION


def _header(title: str) -> None:
    print(f"# {title}")
    print(
        f"# {common.timestamp()}  {platform.node()}  "
        f"{platform.processor() or platform.machine()}  cpus={os.cpu_count()}  "
        f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}  mujoco={mujoco.__version__}"
    )


def _blind_package(task: str):
    """The package's environment with rendering replaced by a no-op."""
    package = common.robodesk_package(task)
    package.render = lambda *args, **kwargs: None
    return package


def speed(args: argparse.Namespace) -> None:
    _header("RoboDesk step speed: vp2 RoboDeskEnv vs robodesk.RoboDesk(action_repeat=50)")
    task = "push_red"
    ours = RoboDeskEnv(task, seed=0, observation_size=64)
    ours_blind = RoboDeskEnv(task, seed=0, observation_size=None)
    ours_python = RoboDeskEnv(task, seed=0, observation_size=None)
    package = common.robodesk_package(task)
    package_blind = _blind_package(task)
    rng = np.random.default_rng(0)
    ours.reset(seed=0)
    start = ours.get_state()
    for env in (ours_blind, ours_python):
        env.reset_to(start)
    for p in (package, package_blind):
        p.reset()
        common.load_package_state(p, ours.get_state())
    model, data = ours.model, mujoco.MjData(ours.model)
    mujoco.mj_setState(model, data, start[: mujoco.mj_stateSize(model, _INTEGRATION)], _INTEGRATION)

    def raw() -> None:
        mujoco.mj_step(model, data, 500)

    timers: dict[str, list[float]] = {
        k: [] for k in ("a_ours", "a_package", "b_ours", "b_package", "c_raw", "d_python")
    }
    ours.step(np.zeros(5))  # warm up GL contexts and caches
    package.step(np.zeros(5))
    for _ in range(args.steps):
        # Small actions keep the arm in its workspace over the whole run.
        action = rng.uniform(-0.3, 0.3, size=5)
        calls = {
            "a_ours": ours.step,
            "a_package": lambda a: (common.rebind_package_gl(package), package.step(a)),
            "b_ours": ours_blind.step,
            "b_package": package_blind.step,
            "c_raw": lambda a: raw(),
            "d_python": lambda a: ours_python._simulate_python(ours_python.check_action(a), None),
        }
        for name, call in calls.items():
            t = time.perf_counter()
            call(action)
            timers[name].append(time.perf_counter() - t)
    # The package's image must be the real one (see rebind_package_gl): compare it with ours
    # at full quality on the package's current state.
    full = Renderer(ours.model, RENDER_SPEC.full_quality())
    probe = RoboDeskEnv(task, observation_size=None)
    n = mujoco.mj_stateSize(ours.model, _INTEGRATION)
    probe.reset_to(np.concatenate([package.physics.get_state(_INTEGRATION), start[n:]]))
    common.rebind_package_gl(package)
    check = mean_abs_error(package.render(), full.render(probe.data, 64))
    med = {k: statistics.median(v) * 1e3 for k, v in timers.items()}
    q = {k: np.percentile(np.array(v) * 1e3, [25, 75]) for k, v in timers.items()}
    print(f"# median over {args.steps} interleaved steps (interquartile range), ms per env step")
    for k in timers:
        print(f"{k:10s} {med[k]:8.1f}   [{q[k][0]:.1f}, {q[k][1]:.1f}]")
    print(f"(a) with 64x64 observation: package / ours = {med['a_package'] / med['a_ours']:.2f}x")
    print(f"(b) without rendering:      package / ours = {med['b_package'] / med['b_ours']:.2f}x")
    print(f"(c) ours without rendering / 500 raw mj_step = {med['b_ours'] / med['c_raw']:.2f}x")
    print(
        f"(d) ours through the Python bindings / compiled = {med['d_python'] / med['b_ours']:.2f}x"
    )
    d = ours_python.get_state() - ours_blind.get_state()
    print(f"# check: the two paths' states after {args.steps} steps differ by {np.abs(d).max()}")
    print(f"# check: package image vs ours at full quality, same state: MAE {check:.2f}/255")


def _varied_states(per_task: int, seed: int) -> list[tuple[str, np.ndarray]]:
    """States along noisy scripted trajectories of every task (every 5th step)."""
    states = []
    for t, task in enumerate(TASKS):
        env = RoboDeskEnv(task, seed=seed, observation_size=None)
        for episode in range(per_task):
            env.reset(seed=seed + 100 * t + episode)
            rng = np.random.default_rng([seed, t, episode])
            policy = make_noisy_robodesk_policy(
                env, rng, np.random.default_rng([seed, t, episode, 1]), episode
            )
            for step in range(35):
                env.step(policy.act())
                if step % 5 == 0:
                    states.append((task, env.get_state()))
        env.close()
    return states


CANDIDATES: dict[str, dict] = {
    "no shadows, msaa 4": dict(shadow_lights=(), multisamples=4, reflection=False),
    "no shadows, no msaa": dict(shadow_lights=(), multisamples=0, reflection=False),
    "light 2 shadows, 512, no msaa": dict(
        shadow_lights=(2,), shadow_size=512, multisamples=0, reflection=False
    ),
    "3 shadows 4096, msaa 4, no reflection": dict(
        shadow_size=4096, multisamples=4, reflection=False
    ),
    "3 shadows 512, msaa 4, no reflection": dict(shadow_size=512, multisamples=4, reflection=False),
    "3 shadows 256, no msaa, no reflection": dict(
        shadow_size=256, multisamples=0, reflection=False
    ),
    "3 shadows 512, no msaa, no reflection": dict(
        shadow_size=512, multisamples=0, reflection=False
    ),
    "3 shadows 1024, no msaa, no reflection": dict(
        shadow_size=1024, multisamples=0, reflection=False
    ),
    "3 shadows 512, no msaa, reflection": dict(shadow_size=512, multisamples=0, reflection=True),
}


def render(args: argparse.Namespace) -> None:
    _header("RoboDesk rendering: fidelity of 64x64 observations vs MuJoCo full quality, and cost")
    states = _varied_states(args.episodes, seed=0)
    env = RoboDeskEnv("push_red", seed=0, observation_size=None)
    reference = Renderer(env.model, RENDER_SPEC.full_quality())
    specs: dict[str, RenderSpec] = {"chosen (RENDER_SPEC)": RENDER_SPEC}
    for name, knobs in CANDIDATES.items():
        specs[name] = dataclasses.replace(
            RENDER_SPEC.full_quality(), skybox=RENDER_SPEC.skybox, **knobs
        )
    renderers = {name: Renderer(env.model, spec) for name, spec in specs.items()}
    errors: dict[str, list[float]] = {name: [] for name in specs}
    times: dict[str, list[float]] = {name: [] for name in ["full quality", *specs]}
    cpu: dict[str, list[float]] = {name: [] for name in ["full quality", *specs]}
    env.reset_to(states[0][1])
    reference.render(env.data, 64)
    for r in renderers.values():
        r.render(env.data, 64)
    for _, state in states:
        env.reset_to(state)
        t, c = time.perf_counter(), time.process_time()
        ref = reference.render(env.data, 64)
        times["full quality"].append(time.perf_counter() - t)
        cpu["full quality"].append(time.process_time() - c)
        for name, r in renderers.items():
            t, c = time.perf_counter(), time.process_time()
            img = r.render(env.data, 64)
            times[name].append(time.perf_counter() - t)
            cpu[name].append(time.process_time() - c)
            errors[name].append(mean_abs_error(img, ref))
    print(
        f"# {len(states)} states (7 tasks x {args.episodes} noisy scripted episodes, every 5th step)"
    )
    print("# median wall-clock and process-CPU ms per 64x64 frame; MAE vs full quality (mean, max)")
    print(f"# {'settings':44s} {'wall ms':>8s} {'cpu ms':>7s} {'MAE/255':>8s} {'max':>6s}")
    for name in ["full quality", *specs]:
        e = np.array(errors.get(name, [0.0]))
        label = "full quality (MuJoCo defaults)" if name == "full quality" else name
        print(
            f"  {label:44s} {statistics.median(times[name]) * 1e3:8.1f} "
            f"{statistics.median(cpu[name]) * 1e3:7.1f} {e.mean():8.2f} {e.max():6.2f}"
        )
    print(f"# chosen spec: {RENDER_SPEC}")


def oracle(args: argparse.Namespace) -> None:
    from vp2.models.simulator import SimulatorModel

    _header("RoboDesk oracle planning step: compiled env step vs the Python-bindings step")
    step = common.suite_planning_step("robodesk/push_red", SimulatorModel, args.samples)
    compiled = RoboDeskEnv._simulate

    def python_path(self, action):  # the oracle never tracks the dense reward
        return self._simulate_python(action, None)

    times: dict[str, list[float]] = {"compiled": [], "python": []}
    actions: dict[str, np.ndarray] = {}
    step()  # warm up (environments, renderer, classifier)
    for _ in range(args.repeats):
        for name, impl in (("compiled", compiled), ("python", python_path)):
            RoboDeskEnv._simulate = impl
            try:
                t = time.perf_counter()
                action, _ = step()
                times[name].append(time.perf_counter() - t)
            finally:
                RoboDeskEnv._simulate = compiled
            actions[name] = np.asarray(action)
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"# {args.samples} samples, {args.repeats} alternating pairs, seconds per planning step")
    for k, v in times.items():
        print(f"{k:9s} median {med[k]:7.2f}   runs {', '.join(f'{x:.2f}' for x in v)}")
    ratios = [c / p for c, p in zip(times["compiled"], times["python"], strict=True)]
    print(f"compiled / python: {statistics.median(ratios):.2f}x (median of the pairs' ratios)")
    print(f"# same action: {np.array_equal(actions['compiled'], actions['python'])}")


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__, full_doc=True)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("speed", help="step time: vp2 vs the robodesk package vs raw MuJoCo")
    p.add_argument("--steps", type=int, default=30)
    p.set_defaults(func=speed)
    p = sub.add_parser("render", help="fidelity and cost of render quality settings")
    p.add_argument("--episodes", type=int, default=2, help="noisy scripted episodes per task")
    p.set_defaults(func=render)
    p = sub.add_parser("oracle", help="an oracle planning step: compiled vs Python-bindings step")
    p.add_argument("--samples", type=int, default=20)
    p.add_argument("--repeats", type=int, default=3)
    p.set_defaults(func=oracle)
    args = parser.parse_args()
    args.func(args)


if __name__ == "__main__":
    main()
