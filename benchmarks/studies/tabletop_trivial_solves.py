"""Which tabletop instances does a trial solve without aiming?

For every tabletop instance of a suite (default: the shipped one), from its initial state: does
holding the zero action for a trial's 15 steps reach the goal (an object still rolling or
settling), and how many of ``--tries`` tries of uniform random actions (the trial's first
action zero, as the benchmark's random baseline plays it) reach it? Prints per category the
instances the zero action solves, the random tries that succeed, and the pushed object's
distance from its goal at the start (median). The random tries are drawn from ``--seed``, a
stream the suite's own check (``vp2.data.suite._solved_without_intent``) does not use, so on
a suite built with that check they measure what a fresh random agent would.

Usage::

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.studies.tabletop_trivial_solves \\
        [--suite FILE [--suite-format vp2-task-suite/4]] [--tries 4] [--seed 5000] [--records OUT.jsonl]
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from benchmarks import common
from vp2.data.suite import SUITE_FORMAT, TaskSuite, first_success, random_action_tries
from vp2.envs import TABLETOP_TASKS
from vp2.spec import NUM_CONTROL_STEPS


def measure(suite: TaskSuite, tries: int, seed: int) -> list[dict]:
    records = []
    for task in TABLETOP_TASKS:
        for inst in suite.for_task(f"tabletop/{task}"):
            env = inst.make_env(observation_size=None)
            env.reset_to(inst.init_state)
            start = env.goal_distance(env.object_positions(), inst.goal_state)
            zero = first_success(env, inst.init_state, inst.goal_state,
                                 np.zeros((NUM_CONTROL_STEPS, env.action_dim)))
            rng = np.random.default_rng([seed, inst.index, TABLETOP_TASKS.index(task)])
            random = [first_success(env, inst.init_state, inst.goal_state, actions)
                      for actions in random_action_tries(rng, tries, env.action_dim)]
            records.append({"task": f"tabletop/{task}", "instance": inst.index,
                            "start_distance": round(start, 4), "zero_action": zero,
                            "random": random})
            env.close()
    return records


def table(records: list[dict], tries: int) -> str:
    lines = ["| category | instances | solved by the zero action | random tries that succeed | "
             "start distance, median (m) |", "|---|---|---|---|---|"]
    total = [0, 0, 0, 0]
    for task in TABLETOP_TASKS:
        rows = [r for r in records if r["task"] == f"tabletop/{task}"]
        zero = [r["instance"] for r in rows if r["zero_action"] is not None]
        wins = sum(x is not None for r in rows for x in r["random"])
        n = len(rows) * tries
        total = [total[0] + len(rows), total[1] + len(zero), total[2] + wins, total[3] + n]
        lines.append(f"| {task} | {len(rows)} | {len(zero)} {zero if zero else ''} | {wins}/{n} "
                     f"({wins / max(n, 1):.1%}) | {np.median([r['start_distance'] for r in rows]):.3f} |")
    lines.append(f"| **all** | {total[0]} | {total[1]} | {total[2]}/{total[3]} "
                 f"({total[2] / max(total[3], 1):.1%}) | |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = common.argument_parser(__spec__.name, __doc__)
    ap.add_argument("--suite", type=Path, help="suite file (default: the shipped suite)")
    ap.add_argument("--suite-format", default=SUITE_FORMAT,
                    help="the suite file's version (an earlier suite's, e.g. vp2-task-suite/4)")
    ap.add_argument("--tries", type=int, default=4)
    ap.add_argument("--seed", type=int, default=5000)
    ap.add_argument("--records", type=Path, help="also write one JSON line per instance here")
    args = ap.parse_args(argv)
    common.print_header(__spec__.name, "one process")
    suite = TaskSuite.load(args.suite, format=args.suite_format)
    records = measure(suite, args.tries, args.seed)
    if args.records:
        args.records.write_text("".join(json.dumps(r) + "\n" for r in records))
    print(table(records, args.tries))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
