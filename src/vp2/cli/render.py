"""``vp2 render``: re-render a dataset at another resolution (docs/data.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from vp2.cli._common import add_executor_flags, make_executor_from_args

NAME = "render"
HELP = "re-render a dataset at another resolution"
DESCRIPTION = None


def run_from_args(args: argparse.Namespace) -> int:
    from vp2.data.render import rerender

    out = args.out or f"{str(args.dataset).rstrip('/')}-{args.size}px"
    with make_executor_from_args(args) as executor:
        root = rerender(args.dataset, out, args.size, workers=args.workers, executor=executor)
    print(f"dataset: {root}")
    return 0


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 render`` arguments to ``p``."""
    p.add_argument("dataset", type=Path)
    p.add_argument("--size", type=int, required=True)
    p.add_argument("--out", help="output dataset (default: <dataset>-<size>px)")
    p.add_argument("--workers", type=int, default=None)
    add_executor_flags(p)
    return p
