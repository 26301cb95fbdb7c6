"""Is it the planner or the pixel cost? The tabletop oracle with a cost on the simulator state.

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python benchmarks/oracle_state_cost.py \
        --instances 1 [--cost objects|shaped] [--tasks tabletop/push_large_cube ...] [--json out.json]

The same control trial as ``vp2 run --model simulator`` (SPEC §4: 15 steps, the first the zero
action, success at any step judged from the state) and the same planner (SPEC §5: MPPI, 200
samples, γ = 0.05, correlated noise, warm start), but each candidate is scored on the simulator
*state* its 10 actions reach instead of on rendered frames: the score is minus the sum over
the 10 predicted steps of the squared distances (in cm²) of every object to its goal position
(the quantity the success criterion thresholds); ``--cost shaped`` adds the squared distance
from the hand (grip site) to the pushed object, the textbook shaping that tells a planner to go
to the object first. Nothing is rendered, so a trial costs
seconds of physics per step. If the planner succeeds with this cost where the pixel-cost
oracle fails on the same instances, the failure is the pixel cost's, not MPPI's, the 10-step
horizon's or the instances'. The cost is in cm² so that score differences between candidates
are of the size of the pixel cost's (tens to hundreds): MPPI's γ keeps its SPEC value.
"""

from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from vp2.benchmark.agent import PlannerConfig, build_optimizer  # noqa: E402
from vp2.data.suite import TaskSuite  # noqa: E402
from vp2.envs.tabletop import TabletopEnv  # noqa: E402
from vp2.planning.optimizers import shift_plan  # noqa: E402

HORIZON = 10
NUM_STEPS = 15


def run_trial(inst, seed: int, cost_name: str = "objects") -> dict:
    env = inst.make_env(observation_size=None)
    sim = inst.make_env(observation_size=None)  # the "model": a second copy of the simulator
    goal = TabletopEnv.object_positions_from_state(inst.goal_state)
    start_positions = TabletopEnv.object_positions_from_state(inst.init_state)
    pushed = int(np.argmax(np.linalg.norm(goal - start_positions, axis=1)))
    optimizer = build_optimizer(inst.task, PlannerConfig())
    generator = torch.Generator().manual_seed(seed)
    plan = torch.zeros(HORIZON, env.action_dim, dtype=torch.float64)

    def objective(candidates: torch.Tensor) -> torch.Tensor:
        start = env.get_state()
        scores = np.empty(len(candidates))
        for i, actions in enumerate(candidates.numpy()):
            sim.reset_to(start)
            cost = 0.0
            for a in actions:
                sim.step(a)
                positions = sim.object_positions()
                cost += float(np.sum((positions - goal) ** 2)) * 1e4
                if cost_name == "shaped":
                    reach = sim.end_effector_position() - positions[pushed]
                    cost += float(np.sum(reach**2)) * 1e4
            scores[i] = -cost
        return torch.from_numpy(scores)

    success_step, best_scores, t0 = None, [], time.perf_counter()
    env.step(np.zeros(env.action_dim))  # SPEC §4: the first step executes the zero action
    if env.is_success(inst.goal_state):
        success_step = 0
    for step in range(1, NUM_STEPS):
        if success_step is not None:
            break
        plan, info = optimizer.optimize(objective, plan, generator)
        best_scores.append(info.best_score)
        env.step(env.check_action(plan[0].numpy()))
        if env.is_success(inst.goal_state):
            success_step = step
        plan = shift_plan(plan)
    distance = float(np.max(np.linalg.norm(env.object_positions() - goal, axis=1)))
    env.close()
    sim.close()
    return {
        "task": inst.task,
        "instance": inst.index,
        "seed": seed,
        "cost": cost_name,
        "success": success_step is not None,
        "success_step": success_step,
        "final_max_distance_m": distance,
        "best_score_first_last": [best_scores[0], best_scores[-1]] if best_scores else None,
        "seconds": time.perf_counter() - t0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=None, help="default: the 4 tabletop tasks")
    parser.add_argument("--instances", type=int, default=1, help="k instances per task")
    parser.add_argument("--first", type=int, default=0, help="index of the first instance")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cost", choices=("objects", "shaped"), default="objects")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    suite = TaskSuite.load()
    tasks = args.tasks or [t for t in suite.tasks if t.startswith("tabletop/")]
    results = []
    print("| task | instance | success (step) | final max object distance (cm) | s |")
    print("|---|---|---|---|---|")
    for task in tasks:
        for inst in suite.for_task(task)[args.first : args.first + args.instances]:
            r = run_trial(inst, args.seed, args.cost)
            results.append(r)
            step = f"yes ({r['success_step']})" if r["success"] else "no"
            print(f"| {task} | {inst.index} | {step} | {100 * r['final_max_distance_m']:.1f} | "
                  f"{r['seconds']:.0f} |", flush=True)
    print(f"success: {sum(r['success'] for r in results)} / {len(results)}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
