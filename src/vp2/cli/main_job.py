"""``vp2 main``: the README's main job (vp2.benchmark.main_job)."""

from __future__ import annotations

import argparse
from pathlib import Path

from vp2.benchmark.main_job import AGENTS, MainJobConfig, run_main_job
from vp2.cli._fields import NOT_A_FLAG, Flag, add_flags, build

NAME = "main"
HELP = "the README's main job: a small evaluation on the defaults"
DESCRIPTION = (
    "Evaluates the shipped small models (one per environment) and the trivial baselines on "
    "the first instance of every task category (vp2.benchmark.main_job). Re-running resumes."
)


#: One entry per :class:`~vp2.benchmark.main_job.MainJobConfig` field, in the order of
#: ``vp2 main --help``.
FLAGS: dict[str, Flag | None] = {
    "out": Flag(help="output directory"),
    "num_instances": Flag(help="instances per task category"),
    "seeds": Flag(help="control-run seeds"),
    "tasks": Flag(help="task categories or env names (default: all)"),
    "model_samples": Flag(
        help="planner samples for the learned model (0: SPEC, 200/800)",
        convert=lambda n: n or None,
    ),
    "workers": Flag(help="trial processes"),
    "agents": Flag(choices=list(AGENTS)),
    "resume": Flag("--fresh", negate=True, help="refuse an existing output directory"),
    "suite": NOT_A_FLAG,
    "num_steps": NOT_A_FLAG,
}


def run_from_args(args: argparse.Namespace) -> int:
    from vp2.report.page import write_run_report

    config = build(MainJobConfig, args, FLAGS)
    if args.fresh and Path(args.out).exists():
        raise FileExistsError(f"{args.out} exists; remove it or drop --fresh to resume it")
    table, path = run_main_job(config, after_run=write_run_report)
    print(f"\n{table}\n\nresults: {path}  (run directories next to it; "
          f"contact sheet of the tasks: {Path(args.out) / 'tasks.png'})")
    return 0


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 main`` arguments to ``p`` (one per :data:`FLAGS` entry)."""
    add_flags(p, MainJobConfig, FLAGS)
    return p
