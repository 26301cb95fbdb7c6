"""How much of the tabletop pixel cost is the pushed object, how much the arm (oracle diagnosis).

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.studies.tabletop_cost_share --instances 5

For each instance of the shipped suite: the pixel SSE (64x64, [0, 1]) between the goal image
and (a) the initial frame, (b) the goal state with the objects put back where they started
(only the arm differs from the goal... and the objects: this is the object term), and (c) the
initial state with the objects moved to their goal positions (the arm term: arm pose only).
If (b) is small next to (c), a pixel-cost planner is paid mostly for matching the arm pose.
"""

from __future__ import annotations

import statistics

import numpy as np

from benchmarks import common
from vp2.data.suite import TaskSuite
from vp2.envs import ENV_TASKS


def _sse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.square(a.astype(np.float64) / 255 - b.astype(np.float64) / 255).sum())


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--instances", type=int, default=5, help="first N instances per task")
    args = parser.parse_args()
    suite = TaskSuite.load()
    print("| task | instances | SSE start vs goal | object term | arm term | object share |")
    print("|---|---|---|---|---|---|")
    for task in (f"tabletop/{t}" for t in ENV_TASKS["tabletop"]):
        rows = []
        for inst in suite.for_task(task)[: args.instances]:
            env = inst.make_env()
            env.reset_to(inst.init_state)
            start = env.render(64)
            start_pos = env.object_positions_from_state(inst.init_state)
            goal_pos = env.object_positions_from_state(inst.goal_state)
            env.reset_to(env.with_object_positions(inst.goal_state, start_pos))
            objects_back = env.render(64)
            env.reset_to(env.with_object_positions(inst.init_state, goal_pos))
            arm_at_start = env.render(64)
            env.close()
            rows.append((_sse(start, inst.goal_image), _sse(objects_back, inst.goal_image),
                         _sse(arm_at_start, inst.goal_image)))
        total, obj, arm = (statistics.mean(c) for c in zip(*rows, strict=True))
        print(f"| {task} | {len(rows)} | {total:.1f} | {obj:.1f} | {arm:.1f} | "
              f"{100 * obj / (obj + arm):.1f}% |")


if __name__ == "__main__":
    main()
