"""``vp2 main``: the README's main job (vp2.benchmark.main_job)."""

from __future__ import annotations

import argparse
from pathlib import Path

from vp2.spec import MAIN_JOB_NUM_SAMPLES

NAME = "main"
HELP = "the README's main job: a small evaluation on the defaults"
DESCRIPTION = (
    "Evaluates the shipped small model and the trivial baselines on the first instance of "
    "every task category (vp2.benchmark.main_job). Re-running resumes."
)


def run_from_args(args: argparse.Namespace) -> int:
    from vp2.benchmark.main_job import MainJobConfig, run_main_job
    from vp2.report.page import write_run_report

    config = MainJobConfig(out=args.out, num_instances=args.num_instances,
                           seeds=tuple(args.seeds), tasks=tuple(args.tasks or ()),
                           model_samples=args.model_samples or None, workers=args.workers,
                           agents=tuple(args.agents), resume=not args.fresh)
    if args.fresh and Path(args.out).exists():
        raise FileExistsError(f"{args.out} exists; remove it or drop --fresh to resume it")
    table, path = run_main_job(config, after_run=write_run_report)
    print(f"\n{table}\n\nresults: {path}  (run directories next to it; "
          f"contact sheet of the tasks: {Path(args.out) / 'tasks.png'})")
    return 0


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 main`` arguments to ``p``."""
    p.add_argument("--out", default="outputs/main", help="output directory")
    p.add_argument("--num-instances", type=int, default=1, help="instances per task category")
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="control-run seeds")
    p.add_argument("--tasks", nargs="+", help="task categories or env names (default: all)")
    p.add_argument("--model-samples", type=int, default=MAIN_JOB_NUM_SAMPLES,
                   help="planner samples for the learned model (0: SPEC, 200/800)")
    p.add_argument("--workers", type=int, default=2, help="trial processes")
    p.add_argument("--agents", nargs="+", default=["model", "repeat_last_frame", "random"],
                   choices=["model", "repeat_last_frame", "random"])
    p.add_argument("--fresh", action="store_true", help="refuse an existing output directory")
    return p
