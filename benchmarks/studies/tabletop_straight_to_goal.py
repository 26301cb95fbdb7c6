"""Does matching the goal image's arm pose push the object? A planning-free check per instance.

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.studies.tabletop_straight_to_goal

The pixel cost of a tabletop goal image is mostly the arm (docs/findings/oracle.md). A planner
that only matched the arm would move the hand to its pose in the goal state. This drives the
hand straight there (a proportional controller on the grip site, full speed beyond 3.3 cm,
gripper closed) for the trial's 14 actions from every tabletop instance's initial state and
counts the instances it solves, split by push direction (towards +x, away from the robot, or
back).
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from benchmarks import common  # noqa: E402
from vp2.data.suite import TRIAL_FREE_ACTIONS, TaskSuite  # noqa: E402
from vp2.envs import split_name  # noqa: E402
from vp2.envs.tabletop import OBJECT_NAMES, TabletopEnv  # noqa: E402


def straight_to_goal_pose(inst) -> bool:
    env = inst.make_env(observation_size=None)
    env.reset_to(inst.goal_state)
    goal_hand = env.end_effector_position()
    env.reset_to(inst.init_state)
    _, rot = env.base_frame()
    solved = False
    for _ in range(TRIAL_FREE_ACTIONS):
        delta = rot.T @ (goal_hand - env.end_effector_position())
        env.step(np.r_[np.clip(delta / env.scene.controller.output_max * 1.5, -1, 1), 1.0])
        solved = solved or env.is_success(inst.goal_state)
    env.close()
    return solved


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--suite", default=None, help="task suite file (default: the shipped one)")
    args = parser.parse_args()
    suite = TaskSuite.load(args.suite)
    print("| task | solved | pushes away from the robot | pushes back |")
    print("|---|---|---|---|")
    for task in [t for t in suite.tasks if t.startswith("tabletop/")]:
        away, back = [], []
        for inst in suite.for_task(task):
            start = TabletopEnv.object_positions_from_state(inst.init_state)
            goal = TabletopEnv.object_positions_from_state(inst.goal_state)
            k = OBJECT_NAMES.index(split_name(task)[1].removeprefix("push_"))
            (away if goal[k, 0] >= start[k, 0] else back).append(straight_to_goal_pose(inst))
        print(f"| {task} | {sum(away) + sum(back)} / {len(away) + len(back)} | "
              f"{sum(away)} / {len(away)} | {sum(back)} / {len(back)} |")


if __name__ == "__main__":
    main()
