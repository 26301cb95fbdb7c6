"""``vp2 study``: perceptual metrics versus control success (docs/report.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from vp2.report.study import study
from vp2.report.study_output import write_study

NAME = "study"
HELP = "perceptual metrics versus control success"
DESCRIPTION = (
    "Table 1 of the paper and rank correlations between each metric and success over several "
    "models (docs/report.md)."
)


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 study`` flags to ``p`` (a sub-parser) and returns it."""
    p.add_argument(
        "--entry",
        nargs=3,
        action="append",
        required=True,
        metavar=("LABEL", "RUN_DIR", "METRICS_JSON"),
        help="one evaluated model: its label, `vp2 run` directory and `vp2 metrics` JSON "
        "(several environments: METRICS_JSON comma-separated); repeat for every model",
    )
    p.add_argument("--out", type=Path, default=Path("runs/study"), metavar="DIR",
                   help="where study.md, study.json and the scatter SVGs go (default: %(default)s)")
    return p


def run_from_args(args: argparse.Namespace) -> int:
    """Runs ``vp2 study`` from parsed arguments: prints the Markdown, writes the files."""
    entries = [
        (label, run_dir, [m for m in metrics.split(",") if m])
        for label, run_dir, metrics in args.entry
    ]
    result = study(entries)
    files = write_study(result, args.out)
    print(result.to_markdown())
    print(f"wrote {', '.join(str(f) for f in files)}")
    return 0
