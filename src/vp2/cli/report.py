"""``vp2 report``: one self-contained HTML page of one or more runs (docs/report.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from vp2.report.page import DEFAULT_TRIALS_PER_TASK, write_report
from vp2.run.run_dir import REPORT_FILE

NAME = "report"
HELP = "self-contained HTML report of one or more runs"
DESCRIPTION = (
    "Writes one self-contained HTML page: success per task and model, normalised scores, the "
    "study when metrics exist, trial videos (docs/report.md)."
)


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 report`` arguments to ``p`` (a sub-parser) and returns it."""
    p.add_argument("run_dirs", nargs="+", type=Path, metavar="RUN_DIR", help="vp2 run directories")
    p.add_argument(
        "--out",
        type=Path,
        default=Path(REPORT_FILE),
        metavar="FILE",
        help="HTML file (default: %(default)s)",
    )
    p.add_argument(
        "--metrics",
        nargs="+",
        metavar="M.json",
        help="vp2 metrics JSON per RUN_DIR, in the same order ('-' for a run without; "
        "several environments: comma-separated); adds the metrics-versus-control study",
    )
    p.add_argument(
        "--trials-per-task",
        type=int,
        default=DEFAULT_TRIALS_PER_TASK,
        help="gallery trials per model and task (default: %(default)s)",
    )
    p.add_argument(
        "--labels",
        nargs="+",
        metavar="LABEL",
        help="model label per RUN_DIR, in the same order ('-' keeps the default: the model spec)",
    )
    p.add_argument("--title", help="page title")
    return p


def run_from_args(args: argparse.Namespace) -> int:
    """Runs ``vp2 report`` from parsed arguments."""
    metrics = None
    if args.metrics:
        metrics = [None if m == "-" else [x for x in m.split(",") if x] for m in args.metrics]
    out = write_report(
        args.run_dirs,
        args.out,
        metrics,
        trials_per_task=args.trials_per_task,
        title=args.title,
        labels=None if args.labels is None else [None if x == "-" else x for x in args.labels],
    )
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)")
    return 0
