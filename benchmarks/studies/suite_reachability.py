"""How many scripted actions each task instance needs, against a control trial's 14.

    .venv/bin/python -m benchmarks.studies.suite_reachability [--suite PATH]

A control trial has 15 steps and executes the zero action first (SPEC §4): 14 actions to
reach the goal; suite version 2 keeps every instance within 12 (SPEC §2). The second table is
the distribution of the actions needed per category (the instances' difficulty) and where
along the scripted trajectory the instances start. The scripted policy's action count is a
fair estimate of what an instance needs when the policy drives the arm at the action limit;
the share of such steps (any of the first three action dimensions, the arm's translation,
with |a| > 0.95) is printed with it.
Prints Markdown tables (docs/measurements.md, "Task suite"; the first suite's in
docs/findings/suite-v2.md).
"""

from __future__ import annotations

import numpy as np

from benchmarks import common
from vp2.data.suite import MAX_INSTANCE_ACTIONS, TRIAL_FREE_ACTIONS, TaskSuite


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--suite", default=None, help="task suite file (default: the shipped one)")
    args = parser.parse_args()
    suite = TaskSuite.load(args.suite)
    print(f"| task | scripted actions min / median / max | instances reachable in "
          f"{TRIAL_FREE_ACTIONS} actions | steps at the action limit |")
    print("|---|---|---|---|")
    for task in suite.tasks:
        insts = suite.for_task(task)
        lengths = np.array([len(i.actions) for i in insts])
        actions = np.concatenate([i.actions for i in insts])
        saturated = np.mean(np.abs(actions[:, :3]).max(axis=1) > 0.95)
        print(f"| {task} | {lengths.min()} / {np.median(lengths):g} / {lengths.max()} | "
              f"{int(np.sum(lengths <= TRIAL_FREE_ACTIONS))} / {len(insts)} | {100 * saturated:.0f}% |")
    counts = range(1, MAX_INSTANCE_ACTIONS + 1)
    print("\nInstances per number of scripted actions needed; start step along the trajectory\n")
    print("| task | " + " | ".join(str(k) for k in counts) + " | start step min / median / max |")
    print("|---|" + "---|" * (len(counts) + 1))
    for task in suite.tasks:
        insts = suite.for_task(task)
        lengths = [len(i.actions) for i in insts]
        starts = np.array([i.start_step for i in insts])
        cells = " | ".join(str(lengths.count(k) or "") for k in counts)
        print(f"| {task} | {cells} | {starts.min()} / {np.median(starts):g} / {starts.max()} |")


if __name__ == "__main__":
    main()
