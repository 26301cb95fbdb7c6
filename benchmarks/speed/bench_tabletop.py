"""Tabletop environment: speed, hand response, render fidelity, object sizes, dynamics identity
and scripted-policy success.

Sections (``--section``, default ``all``):

* ``speed``: one control step + 64x64 observation of :class:`vp2.envs.tabletop.TabletopEnv`
  against the same robosuite environment stepped with robosuite's own ``env.step`` and its
  own camera observation at 64x64 (``use_camera_obs=True``, robosuite's rendering quality),
  interleaved step by step in one process so that machine load hits both alike; also our
  step without rendering, a reset with its 64x64 observation, and the floor: the raw
  ``mujoco.mj_step`` calls one control step needs (one control step is 1 s = 500 physics
  steps of 2 ms).
* ``hand``: from resets, how far the action (0, 1, 0, 0) moves the grip site in one step and
  how far it drifts under the next zero action.
* ``fidelity``: mean absolute pixel error at 64x64 against the original's way of rendering
  (``RENDER_SPEC.full_quality()`` at 256x256, then an anti-aliased bilinear resize to 64x64,
  :func:`vp2.envs.rendering.antialiased_bilinear`) over varied states (random initial states
  plus random actions), of the env's own render (``RENDER_SPEC`` at 64x64) and alternatives,
  and the render time of each.
* ``visibility``: visible pixels of each object at 64x64 (segmentation renders of the
  benchmark camera) at reset and after 12 policy steps, and the share of objects that are
  less than a quarter visible (under the hand).
* ``dynamics``: our lean step against robosuite's ``env.step`` from the same states with the
  same actions: the largest absolute difference of the full MuJoCo state (0 = bit-identical).
* ``policy``: over 35 steps of the scripted pushing policy, noise-free per task category and
  noisy (σ = 0.05, random object): how often the pushed object comes within 5 cm of its aim,
  and how often the trajectory passes the original's keep filter.

Usage::

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.speed.bench_tabletop [--section all] \\
        [--steps 30] [--states 50] [--episodes 50] [--workers 2] [--json out.json]

Prints Markdown tables; results are recorded in docs/tabletop.md.
"""

from __future__ import annotations

import dataclasses
import json
import os
import statistics
import time
from concurrent.futures import ProcessPoolExecutor

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks import common  # noqa: E402
from vp2.data.policies.base import NoisyPolicy  # noqa: E402
from vp2.data.policies.tabletop import FELL_OFF, keeps_push, make_tabletop_policy  # noqa: E402
from vp2.envs._tabletop_stepper import LeanStepper  # noqa: E402
from vp2.envs._tabletop_world import TabletopWorld  # noqa: E402
from vp2.envs.rendering import Renderer, antialiased_bilinear, mean_abs_error  # noqa: E402
from vp2.envs.tabletop import DEFAULT_SCENE, OBJECT_NAMES, TabletopEnv  # noqa: E402

#: The benchmark scene's render specification.
RENDER_SPEC = DEFAULT_SCENE.render

_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION


def _sim_state(world: TabletopWorld) -> np.ndarray:
    model, data = world.sim.model._model, world.sim.data._data
    out = np.empty(mujoco.mj_stateSize(model, _INTEGRATION))
    mujoco.mj_getState(model, data, out, _INTEGRATION)
    return out


def _varied_states(env: TabletopEnv, count: int, seed: int) -> list[np.ndarray]:
    """States from random resets followed by 0-8 random actions (biased down, so that the hand
    reaches the objects and pushes some)."""
    rng = np.random.default_rng(seed)
    states = []
    for i in range(count):
        env.reset(seed=seed + i)
        for _ in range(int(rng.integers(0, 9))):
            env.step(np.array([*rng.uniform(-1, 1, 2), rng.uniform(-1, 0.3), 0.0]))
        states.append(env.get_state())
    return states


# ---- sections --------------------------------------------------------------------------------
def bench_speed(steps: int) -> dict:
    ours = TabletopEnv("push_large_cube", seed=0, observation_size=64)
    ours_blind = TabletopEnv("push_large_cube", seed=0, observation_size=None)
    robo = TabletopWorld(camera_obs_size=64)
    robo_stepper = LeanStepper(robo)  # only to load states into robosuite's controllers
    for e in (ours, ours_blind):
        e.reset(seed=7)
    common.load_into_world(ours, robo, robo_stepper)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(steps + 3, 4))
    model = ours._model
    n_substeps = ours._stepper.n_substeps
    times: dict[str, list[float]] = {"ours": [], "ours_blind": [], "robosuite": [], "floor": []}
    probe = mujoco.MjData(model)
    from mujoco import rollout

    from benchmarks.speed.bench_oracle import controlled_rollout

    for i, action in enumerate(actions):
        before = ours_blind.get_state()
        t0 = time.perf_counter()
        ours.step(action)
        t1 = time.perf_counter()
        ours_blind.step(action)
        t2 = time.perf_counter()
        obs, *_ = robo.step(action)
        t3 = time.perf_counter()
        after = ours_blind.get_state()
        # The floor: this step's physics steps as plain mj_step calls in MuJoCo's compiled loop,
        # with the controls the controller computed (recorded), replayed open-loop.
        controls, _ = controlled_rollout(ours_blind, before, action[None])
        ours_blind.reset_to(after)
        start = np.empty(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
        mujoco.mj_setState(model, probe, before[: ours._n_integration], _INTEGRATION)
        mujoco.mj_getState(model, probe, start, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        t4 = time.perf_counter()
        rollout.rollout(model, probe, start[None], controls[None])
        t5 = time.perf_counter()
        if i >= 3:  # warm-up: first renders create GL contexts
            times["ours"].append(t1 - t0)
            times["ours_blind"].append(t2 - t1)
            times["robosuite"].append(t3 - t2)
            times["floor"].append(t5 - t4)
    assert obs[f"{robo.camera_names[0]}_image"].shape == (64, 64, 3)
    med = {k: statistics.median(v) * 1e3 for k, v in times.items()}
    q = {k: np.percentile(np.array(v) * 1e3, [25, 75]).tolist() for k, v in times.items()}
    ours.close()
    robo.close()
    return {
        "median_ms": med,
        "quartiles_ms": q,
        "steps": steps,
        "physics_steps_per_control_step": n_substeps,
        "speedup_vs_robosuite_with_render": med["robosuite"] / med["ours"],
        "blind_step_over_floor": med["ours_blind"] / med["floor"],
        "reset_ms": _reset_ms(steps),
    }


def _reset_ms(count: int) -> float:
    """Median time of ``reset`` with its 64x64 observation (after a warm-up reset)."""
    env = TabletopEnv("push_large_cube", seed=0, observation_size=64)
    env.reset(seed=0)
    times = []
    for i in range(count):
        t0 = time.perf_counter()
        env.reset(seed=i + 1)
        times.append(time.perf_counter() - t0)
    env.close()
    return statistics.median(times) * 1e3


def bench_hand(resets: int) -> dict:
    """Grip-site motion (m) of the action (0, 1, 0, 0) from a reset, and its drift under the
    next zero action."""
    env = TabletopEnv("push_large_cube", seed=0, observation_size=None)
    moved, drift = [], []
    for i in range(resets):
        env.reset(seed=i)
        start = env.end_effector_position()
        env.step(np.array([0.0, 1.0, 0.0, 0.0]))
        after = env.end_effector_position()
        env.step(np.zeros(4))
        moved.append(float(np.linalg.norm(after - start)))
        drift.append(float(np.linalg.norm(env.end_effector_position() - after)))
    env.close()
    return {
        "resets": resets,
        "move_m": {"median": statistics.median(moved), "min": min(moved), "max": max(moved)},
        "drift_m": {"median": statistics.median(drift), "min": min(drift), "max": max(drift)},
    }


def bench_fidelity(count: int) -> dict:
    env = TabletopEnv("push_large_cube", seed=0, observation_size=None)
    states = _varied_states(env, count, seed=1000)
    render_model = env._world.render_model(RENDER_SPEC.mesh_reduction)
    full = RENDER_SPEC.full_quality()
    # name: (renderer, render size before the anti-aliased resize to 64x64)
    candidates = {
        "original way": (Renderer(env._model, full), 256),
        "full quality at 64": (Renderer(env._model, full), 64),
        "RENDER_SPEC at 256 + resize": (Renderer(env._model, RENDER_SPEC, render_model), 256),
        "RENDER_SPEC + 4x MSAA": (
            Renderer(env._model, dataclasses.replace(RENDER_SPEC, multisamples=4), render_model),
            64,
        ),
        "RENDER_SPEC (the env's)": (Renderer(env._model, RENDER_SPEC, render_model), 64),
    }
    images: dict[str, list[np.ndarray]] = {name: [] for name in candidates}
    times: dict[str, list[float]] = {name: [] for name in candidates}
    for state in states:
        env.reset_to(state)
        mujoco.mj_kinematics(env._model, env._data)
        mujoco.mj_camlight(env._model, env._data)
        for name, (renderer, size) in candidates.items():
            t0 = time.perf_counter()
            image = renderer.render(env._data, size)
            if size != 64:
                image = antialiased_bilinear(image, 64, 64)
            times[name].append(time.perf_counter() - t0)
            images[name].append(image)
    for renderer, _ in candidates.values():
        renderer.close()
    rows = {}
    for name in candidates:
        errors = [
            mean_abs_error(a, b) for a, b in zip(images[name], images["original way"], strict=True)
        ]
        rows[name] = {
            "mae_mean": float(np.mean(errors)),
            "mae_max": float(np.max(errors)),
            "render_ms": statistics.median(times[name][1:]) * 1e3,
        }
    return {"states": count, "candidates": rows, "spec": dataclasses.asdict(RENDER_SPEC)}


def bench_visibility(states: int) -> dict:
    """Visible pixels of each object at 64x64, from segmentation renders of the benchmark camera.

    States ``reset(seed=100000 + i)`` and the same after 12 steps of the scripted policy;
    visual geoms only. ``hidden_share``: objects with less than a quarter of their median
    visible pixels (mostly under the hand).
    """
    from benchmarks.studies.tabletop_goal_pixels import object_pixels

    env = TabletopEnv("push_large_cube", seed=0, observation_size=None)
    counts: dict[str, list[list[int]]] = {"reset": [], "after_12_policy_steps": []}
    for i in range(states):
        env.reset(seed=100_000 + i)
        policy = make_tabletop_policy(env, np.random.default_rng(i))
        for phase, steps in (("reset", 0), ("after_12_policy_steps", 12)):
            for _ in range(steps):
                env.step(policy.act())
            counts[phase].append(object_pixels(env, env.get_state()))
    env.close()
    out: dict = {"states": states}
    for phase, c in counts.items():
        c = np.array(c)
        median = np.median(c, axis=0)
        out[phase] = {
            "median_pixels": dict(zip(OBJECT_NAMES, median.tolist(), strict=True)),
            "median_width_px": dict(
                zip(OBJECT_NAMES, np.sqrt(median).round(2).tolist(), strict=True)
            ),
            "hidden_share": float(np.mean(c < 0.25 * median)),
        }
    return out


def bench_dynamics(episodes: int, steps: int) -> dict:
    env = TabletopEnv("push_large_cube", seed=0, observation_size=None)
    world = TabletopWorld()
    stepper = LeanStepper(world)
    worst = worst_qpos = 0.0
    qpos = slice(1, 1 + env._model.nq)  # the integration state starts with the time
    for ep in range(episodes):
        env.reset(seed=ep)
        common.load_into_world(env, world, stepper)
        rng = np.random.default_rng(ep)
        policy = make_tabletop_policy(env, np.random.default_rng(ep))
        for t in range(steps):
            # Mix scripted pushes (contacts) with random actions (gripper toggling, fast moves).
            action = policy.act() if t % 3 else rng.uniform(-1, 1, 4)
            env.step(action)
            world.step(env.check_action(action))
            diff = np.abs(_sim_state(world) - env.get_state()[: env._n_integration])
            worst = max(worst, float(diff.max()))
            worst_qpos = max(worst_qpos, float(diff[qpos].max()))
    return {
        "episodes": episodes,
        "steps": steps,
        "max_abs_state_difference": worst,
        "max_abs_qpos_difference": worst_qpos,
    }


def _policy_episode(args: tuple[int | None, int, float]) -> dict:
    """One 35-step episode: whether the pushed object came within 5 cm of its aim, and whether
    the trajectory passes the original's keep filter (``keeps_push``: some object other than the
    ball -- unless the ball is pushed -- moved > 0.08 m in xy, none |dz| > 0.5 m)."""
    obj, episode, sigma = args
    env = TabletopEnv("push_large_cube", seed=0, observation_size=None)
    env.reset(seed=100_000 + episode)
    policy = make_tabletop_policy(env, np.random.default_rng(episode), target_object=obj)
    actor = policy
    if sigma > 0:
        actor = NoisyPolicy(
            policy, (sigma, sigma, sigma, 0.0), np.random.default_rng(10**6 + episode)
        )
    k = policy.object_index
    start = env.object_positions()
    first = None
    for t in range(35):
        env.step(actor.act())
        if (
            first is None
            and np.linalg.norm(env.object_positions()[k, :2] - policy.target_xy) < 0.05
        ):
            first = t + 1
    end = env.object_positions()
    env.close()
    moved = np.linalg.norm(end[:, :2] - start[:, :2], axis=1)
    fell = bool(np.abs(end[:, 2] - start[:, 2]).max() > FELL_OFF)
    return {
        "object": k,
        "reached": first is not None,
        "first": first,
        "fell": fell,
        "kept": keeps_push(start, end, k),
        "moved": float(moved[k]),
    }


def _rates(rows: list[dict]) -> dict:
    steps = [r["first"] for r in rows if r["reached"]]
    return {
        "episodes": len(rows),
        "reached_5cm": sum(r["reached"] for r in rows) / len(rows),
        "median_first_reach_step": statistics.median(steps) if steps else None,
        "kept_by_filter": sum(r["kept"] for r in rows) / len(rows),
        "fell_off": sum(r["fell"] for r in rows) / len(rows),
        "median_moved_m": float(np.median([r["moved"] for r in rows])),
    }


def bench_policy(episodes: int, workers: int) -> dict:
    """Noise-free per category (``episodes`` each) and noisy (σ = 0.05) with a random object
    (``episodes`` in all), as the data stream runs it."""
    with ProcessPoolExecutor(max_workers=workers) as pool:
        clean = list(
            pool.map(
                _policy_episode,
                [(o, e, 0.0) for o in range(len(OBJECT_NAMES)) for e in range(episodes)],
                chunksize=2,
            )
        )
        noisy = list(
            pool.map(_policy_episode, [(None, e, 0.05) for e in range(episodes)], chunksize=2)
        )
    out: dict = {"episodes": episodes, "noise_free": {}, "noisy_0.05": {}}
    for o, name in enumerate(OBJECT_NAMES):
        out["noise_free"][f"push_{name}"] = _rates([r for r in clean if r["object"] == o])
        out["noisy_0.05"][f"push_{name}"] = _rates([r for r in noisy if r["object"] == o])
    out["noise_free"]["all"] = _rates(clean)
    out["noisy_0.05"]["all"] = _rates(noisy)
    return out


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument(
        "--section",
        choices=["all", "speed", "hand", "fidelity", "visibility", "dynamics", "policy"],
        default="all",
    )
    parser.add_argument("--steps", type=int, default=30, help="timed control steps (speed)")
    parser.add_argument("--states", type=int, default=50, help="varied states (fidelity)")
    parser.add_argument("--episodes", type=int, default=50, help="episodes per category (policy)")
    parser.add_argument("--workers", type=int, default=2, help="processes (policy)")
    parser.add_argument("--json", help="also write the results to this file")
    args = parser.parse_args()

    report: dict = {
        "date": common.timestamp(),
        "machine": f"{common.cpu_name()}, {os.cpu_count()} CPUs",
        "mujoco_gl": os.environ.get("MUJOCO_GL"),
    }
    sections = (
        ["speed", "hand", "fidelity", "visibility", "dynamics", "policy"]
        if args.section == "all"
        else [args.section]
    )
    print(
        f"# bench_tabletop  {report['date']}  {report['machine']}  MUJOCO_GL={report['mujoco_gl']}"
    )
    if "speed" in sections:
        r = report["speed"] = bench_speed(args.steps)
        m = r["median_ms"]
        print(
            f"\n## Speed (median of {r['steps']} control steps, ms; {r['physics_steps_per_control_step']} physics steps each)\n"
        )
        print("| what | median ms | quartiles |\n|---|---|---|")
        labels = {
            "ours": "TabletopEnv step + 64x64 render",
            "robosuite": "robosuite env.step with 64x64 camera obs",
            "ours_blind": "TabletopEnv step, no render",
            "floor": "raw mj_step calls of one step",
        }
        for k, label in labels.items():
            q = r["quartiles_ms"][k]
            print(f"| {label} | {m[k]:.2f} | {q[0]:.2f}-{q[1]:.2f} |")
        print(
            f"\nspeed-up vs robosuite (with rendering): {r['speedup_vs_robosuite_with_render']:.2f}x;"
            f" blind step / floor: {r['blind_step_over_floor']:.2f}x;"
            f" reset + 64x64 observation: {r['reset_ms']:.2f} ms"
        )
    if "hand" in sections:
        r = report["hand"] = bench_hand(min(args.states, 20))
        mv, dr = r["move_m"], r["drift_m"]
        print(f"\n## Hand response to (0, 1, 0, 0) from {r['resets']} resets (cm)\n")
        print("| | median | min | max |\n|---|---|---|---|")
        for label, c in (("moved in the step", mv), ("drift under the next zero action", dr)):
            print(
                f"| {label} | {c['median'] * 100:.3f} | {c['min'] * 100:.3f} | {c['max'] * 100:.3f} |"
            )
    if "fidelity" in sections:
        r = report["fidelity"] = bench_fidelity(args.states)
        print(
            f"\n## Render fidelity over {r['states']} states (64x64), RENDER_SPEC = {r['spec']}\n"
        )
        print(
            "| render | MAE vs the original way (/255) | max over states | render ms |\n|---|---|---|---|"
        )
        for name, c in r["candidates"].items():
            print(f"| {name} | {c['mae_mean']:.2f} | {c['mae_max']:.2f} | {c['render_ms']:.2f} |")
    if "visibility" in sections:
        r = report["visibility"] = bench_visibility(min(args.states, 40))
        print(f"\n## Visible object pixels at 64x64 ({r['states']} states)\n")
        print(
            "| when | " + " | ".join(OBJECT_NAMES) + " | < 25% visible |\n|---|---|---|---|---|---|"
        )
        for phase in ("reset", "after_12_policy_steps"):
            c = r[phase]
            cells = [
                f"{c['median_pixels'][o]:g} px ({c['median_width_px'][o]:.1f} across)"
                for o in OBJECT_NAMES
            ]
            print(f"| {phase} | " + " | ".join(cells) + f" | {c['hidden_share']:.1%} |")
    if "dynamics" in sections:
        r = report["dynamics"] = bench_dynamics(episodes=4, steps=12)
        print(f"\n## Dynamics vs robosuite env.step ({r['episodes']} x {r['steps']} steps)\n")
        print(
            f"max |qpos difference| = {r['max_abs_qpos_difference']:.3g}; "
            f"max |state difference| = {r['max_abs_state_difference']:.3g}"
        )
    if "policy" in sections:
        r = report["policy"] = bench_policy(args.episodes, args.workers)
        print(
            f"\n## Scripted policy over 35 steps ({r['episodes']} episodes per category "
            "noise-free, in all noisy)\n"
        )
        print(
            "| run | category | episodes | object within 5 cm of its aim | kept by the filter "
            "| an object fell off | median distance pushed |\n|---|---|---|---|---|---|---|"
        )
        for run in ("noise_free", "noisy_0.05"):
            for cat, c in r[run].items():
                print(
                    f"| {run} | {cat} | {c['episodes']} | {c['reached_5cm']:.0%} | "
                    f"{c['kept_by_filter']:.0%} | {c['fell_off']:.0%} | {c['median_moved_m']:.3f} m |"
                )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=2, default=str)


if __name__ == "__main__":
    main()
