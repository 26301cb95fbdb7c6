"""The oracle's planning step before and after rendering at the geometry floor, in one run.

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.speed.bench_oracle_render \\
        [--cases robodesk/push_red:50 robodesk/push_red:200 tabletop/push_large_cube:200]

"Before" is the render path of 2026-11-23 (commit 131e30f): the original meshes and
tessellation with that day's quality settings (``bench_render_floor.previous_spec``: RoboDesk 3
shadow lights at 512², no MSAA, no reflection; tabletop no shadows, no MSAA, no reflection). "After" is today's ``RENDER_SPEC`` with its simplified
render-only model. Both run in this process with one oracle worker on the same environment
(only its renderer is swapped), the same MPPI seed and the same observation, alternating
before/after per case so that machine load hits both; physics is identical.

It also prints the per-sample breakdown of the "after" oracle: ``reset_to``, the 10 env steps
(physics), the 10 renders, and the transfer a worker pool adds (pickling the frames a worker
sends back).
"""

from __future__ import annotations

import os
import pickle
import time

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import numpy as np  # noqa: E402

from benchmarks import common  # noqa: E402
from benchmarks.speed.bench_oracle import observation  # noqa: E402
from benchmarks.speed.bench_render_floor import previous_spec  # noqa: E402
from vp2.envs import make_env  # noqa: E402
from vp2.envs.rendering import Renderer, RenderSpec  # noqa: E402
from vp2.models.simulator import _PROCESS_ENVS, SimulatorModel  # noqa: E402
from vp2.planning import PlannerConfig, PlanningAgent  # noqa: E402


def before_renderer(env) -> Renderer:
    """A renderer of ``env``'s physics model with the settings of 2026-11-23 (original meshes)."""
    return Renderer(physics_model(env), previous_spec(env_render_spec(env)))


def env_render_spec(env) -> RenderSpec:
    from vp2.envs import robodesk, tabletop

    return (
        robodesk.RENDER_SPEC if env.name.startswith("robodesk") else tabletop.DEFAULT_SCENE.render
    )


def physics_model(env):
    return env.model if hasattr(env, "model") else env._model


def breakdown(env, state: np.ndarray, samples: int = 5) -> dict[str, float]:
    """Milliseconds per oracle sample: reset_to, 10 steps, 10 renders, pickling 10 frames."""
    rng = np.random.default_rng(0)
    t = dict.fromkeys(("reset_to", "physics", "render", "transfer"), 0.0)
    for _ in range(samples):
        t0 = time.perf_counter()
        env.reset_to(state)
        t["reset_to"] += time.perf_counter() - t0
        frames = []
        for _ in range(10):
            t0 = time.perf_counter()
            env.step(rng.uniform(-1, 1, env.action_dim))
            t1 = time.perf_counter()
            frames.append(env.render(64))
            t["render"] += time.perf_counter() - t1
            t["physics"] += t1 - t0
        t0 = time.perf_counter()
        pickle.loads(pickle.dumps(np.stack(frames), protocol=pickle.HIGHEST_PROTOCOL))
        t["transfer"] += time.perf_counter() - t0
    return {k: 1000 * v / samples for k, v in t.items()}


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument(
        "--cases",
        nargs="+",
        default=["robodesk/push_red:50", "robodesk/push_red:200", "tabletop/push_large_cube:200"],
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rows, parts = [], []
    for case in args.cases:
        task, n = case.rsplit(":", 1)
        probe = make_env(task, seed=args.seed, observation_size=None)
        obs, goal = observation(probe, args.seed)
        probe.close()
        model = SimulatorModel(action_dim=probe.action_dim, num_workers=1)
        # The oracle's own environment in this process.
        env = _PROCESS_ENVS.get(obs.env_meta, observation_size=None)
        env.render(64)
        after, before = env._renderer, before_renderer(env)
        times = {}
        for label, renderer in (("before", before), ("after", after)):
            env._renderer = renderer
            renderer.render(env.data if hasattr(env, "data") else env._data, 64)  # warm up
            agent = PlanningAgent(model, PlannerConfig(num_samples=int(n)))
            agent.reset(task, goal, seed=args.seed)
            t0 = time.perf_counter()
            agent.act(obs)
            times[label] = time.perf_counter() - t0
            print(f"{case} {label}: {times[label]:.1f} s", flush=True)
        env._renderer = after
        before.close()
        rows.append((task, int(n), times["before"], times["after"]))
        parts.append((task, breakdown(env, obs.state)))
    print(
        f"\n{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end; one "
        "oracle worker; one planning step per row\n"
    )
    print("| task | samples | before s | after s | speed-up |")
    print("|---|---|---|---|---|")
    for task, n, b, a in rows:
        print(f"| {task} | {n} | {b:.1f} | {a:.1f} | **{b / a:.1f}x** |")
    print("\nPer sample, after (ms): reset_to, 10 env steps, 10 renders, pickling its frames\n")
    print("| task | reset_to | physics | render | transfer | total |")
    print("|---|---|---|---|---|---|")
    for task, p in dict(parts).items():
        print(
            f"| {task} | {p['reset_to']:.2f} | {p['physics']:.0f} | {p['render']:.0f} | "
            f"{p['transfer']:.2f} | {sum(p.values()):.0f} |"
        )


if __name__ == "__main__":
    main()
