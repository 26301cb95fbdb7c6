"""``vp2 ship-oracle``: the shipped oracle (the default normaliser) from simulator-oracle runs."""

from __future__ import annotations

import argparse
from pathlib import Path

from vp2.benchmark.ship_oracle import build_oracle_asset, write_oracle_asset
from vp2.benchmark.shipped_oracle import ASSET_FILE, load_shipped_oracle

NAME = "ship-oracle"
HELP = "build the shipped oracle (the default normaliser) from simulator-oracle runs"
DESCRIPTION = (
    "Reads finished simulator-oracle run directories and writes the per-task success rates "
    "that vp2 run, main and report normalise scores by when no --oracle is given "
    "(docs/evaluation.md, 'The shipped oracle')."
)


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 ship-oracle`` arguments to ``p`` (a sub-parser) and returns it."""
    p.add_argument(
        "run_dirs",
        nargs="+",
        type=Path,
        metavar="RUN_DIR",
        help="simulator-oracle run directories (vp2 run --model simulator), finished, no errors",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="PATH",
        help=f"the file to write (default: the package's vp2/assets/{ASSET_FILE})",
    )
    p.add_argument("--note", default="", metavar="TEXT", help="free text stored with it")
    return p


def run_from_args(args: argparse.Namespace) -> int:
    """Runs ``vp2 ship-oracle`` from parsed arguments."""
    out = write_oracle_asset(build_oracle_asset(args.run_dirs, note=args.note), args.out)
    oracle = load_shipped_oracle(out)
    assert oracle is not None
    for name, t in oracle.tasks.items():
        print(
            f"{name:34s} {100 * t.rate:5.1f}%  ({t.successes}/{t.trials} trials, "
            f"{len(t.instances)} instances, {t.num_samples} samples)"
        )
    print(f"{oracle.describe()}\nwrote {out}")
    return 0
