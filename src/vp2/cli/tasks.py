"""``vp2 tasks generate|list|show|verify``: the task suite (docs/data.md)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from vp2.cli._common import add_executor_flags, make_executor_from_args
from vp2.utils.seeds import check_seed

log = logging.getLogger(__name__)

NAME = "tasks"
HELP = "the task suite: generate, list, show, verify"
DESCRIPTION = None


def run_from_args(args: argparse.Namespace) -> int:
    from vp2.data import suite as suite_lib

    if args.tasks_command == "generate":
        counts = dict(suite_lib.SUITE_COUNTS)
        unknown = [t for t in args.tasks or () if t not in counts]
        if unknown:
            raise ValueError(f"unknown task categories {', '.join(unknown)}; the suite's are "
                             f"{', '.join(counts)}")
        if args.tasks:
            counts = {t: counts[t] for t in args.tasks}
        if args.count is not None:
            if args.count < 1:
                raise ValueError(f"--count must be >= 1, got {args.count}")
            counts = dict.fromkeys(counts, args.count)
        check_seed(args.seed, "--seed")
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)  # a bad --out fails before generating
        with make_executor_from_args(args) as executor:
            suite = suite_lib.generate_suite(counts, seed=args.seed, workers=args.workers,
                                             executor=executor)
        suite.save(out)
        print(f"task suite: {out} ({len(suite)} instances)")
        return 0
    suite = suite_lib.TaskSuite.load(args.suite)
    if args.tasks_command == "verify":
        return _verify(suite, args)
    if args.tasks_command == "list":
        for task in suite.tasks:
            insts = suite.for_task(task)
            steps = [len(i.actions) for i in insts]
            print(f"{task:34s} {len(insts):3d} instances  scripted steps to goal: "
                  f"min {min(steps)} / mean {sum(steps) / len(steps):.1f} / max {max(steps)}")
        print(f"total: {len(suite)} instances")
        return 0
    # show
    from vp2.data.suite_view import suite_contact_sheet

    available = len(suite.for_task(args.task))
    if 0 < available < args.max:
        log.warning(
            "--max %d: %s has %d instances in the suite; showing those %d",
            args.max, args.task, available, available,
        )
    png = suite_contact_sheet(suite, args.task, args.out, max_instances=args.max)
    print(f"contact sheet: {png}")
    return 0


def _verify(suite, args: argparse.Namespace) -> int:
    from vp2.data.suite_verify import verify_suite

    report = verify_suite(suite, tasks=tuple(args.tasks or ()), regenerate=args.regenerate,
                          replay=not args.no_replay, progress=not args.no_progress)
    for mismatch in report.mismatches:
        print(f"MISMATCH {mismatch}")
    verdict = ("every instance reproduced bit for bit" if report.ok else
               f"{len(report.mismatches)} instance(s) differ on this machine: trials here do not "
               "run on the suite's instances (docs/data.md, 'Reproducibility')")
    print(f"{args.suite or 'the shipped suite'}: {report.replayed} replayed, "
          f"{report.regenerated} regenerated; {verdict}")
    return 0 if report.ok else 1


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 tasks`` arguments to ``p``."""
    tsub = p.add_subparsers(dest="tasks_command", required=True)
    g = tsub.add_parser("generate", help="generate a task suite with fixed seeds")
    g.add_argument("--out", default="task_suite.npz")
    g.add_argument("--seed", type=int, default=2023)
    g.add_argument("--tasks", nargs="+", help="only these task categories")
    g.add_argument("--count", type=int, help="instances per category (default: SPEC §2)")
    g.add_argument("--workers", type=int, default=None)
    add_executor_flags(g)
    lst = tsub.add_parser("list", help="instances per task category")
    lst.add_argument("--suite", help="suite file (default: the shipped suite)")
    show = tsub.add_parser("show", help="contact sheet of start and goal images")
    show.add_argument("task", help="task category, e.g. robodesk/push_red")
    show.add_argument("--suite", help="suite file (default: the shipped suite)")
    show.add_argument("--out", default=None, help="PNG path (default: outputs/tasks/<task>.png)")
    show.add_argument("--max", type=int, default=12, help="instances to show")
    ver = tsub.add_parser(
        "verify", help="replay every instance and regenerate a few, bit for bit (exit 1 on a "
        "mismatch)")
    ver.add_argument("--suite", help="suite file (default: the shipped suite)")
    ver.add_argument("--tasks", nargs="+", help="task categories or env names (default: all)")
    ver.add_argument("--regenerate", type=int, default=1, metavar="K",
                     help="regenerate the first K instances of each category from their seeds")
    ver.add_argument("--no-replay", action="store_true", help="only regenerate")
    ver.add_argument("--no-progress", action="store_true")
    return p
