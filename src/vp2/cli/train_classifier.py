"""The ``vp2 train-classifier`` command: train, evaluate and save RoboDesk success classifiers.

:func:`configure_parser` and :func:`run_from_args` serve ``vp2 train-classifier``; :func:`main`
serves ``python -m vp2.classifiers.command`` (the same arguments). See ``docs/classifiers.md``
(Success classifiers) for the measured accuracy and cost.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

import torch

from vp2.classifiers.checkpoint import save_classifier
from vp2.classifiers.data import LABELS
from vp2.classifiers.networks import ARCHS
from vp2.classifiers.registry import (
    ASSETS_DIR,
    METRICS_FILE,
    checkpoint_name,
    short_task,
    update_metrics,
)
from vp2.classifiers.train import LR_SCHEDULES, ClassifierTrainConfig, train_task
from vp2.cli._fields import NOT_A_FLAG, Flag, add_flags, build
from vp2.data.storage import DatasetError
from vp2.envs import ROBODESK_TASKS

NAME = "train-classifier"
HELP = "train RoboDesk success classifiers"
DESCRIPTION = (
    "Train the per-task RoboDesk success classifiers of the planning cost on a collected "
    "dataset (docs/classifiers.md)."
)


def _pos_weight(value: str | None) -> float | str | None:
    return value if value in (None, "balanced") else float(value)


#: One entry per :class:`~vp2.classifiers.train.ClassifierTrainConfig` field (and the command's
#: own flags), in the order of ``vp2 train-classifier --help``. ``--arch`` takes several: one
#: config per architecture.
FLAGS: dict[str, Flag | None] = {
    "data": Flag(
        cli_only=True, required=True, type=Path, help="dataset directory (vp2 collect robodesk)"
    ),
    "tasks": Flag(
        cli_only=True, nargs="+", default=None,
        help="RoboDesk tasks, e.g. push_red (default: all 7)",
    ),
    "arch": Flag(
        cli_only=True,
        nargs="+",
        choices=ARCHS,
        default=["ours"],
        help="networks to train: ours (shipped) and/or paper (for comparison)",
    ),
    "steps": Flag(help="gradient steps of ours (paper: 3000)"),
    "paper_steps": Flag(
        cli_only=True,
        type=int,
        default=None,
        help="gradient steps of the paper's network (default: --steps)",
    ),
    "lr": NOT_A_FLAG,
    "lr_schedule": Flag(
        choices=LR_SCHEDULES,
        help="learning rate over the steps: constant (the paper's) or cosine (decays to 0)",
    ),
    "width": Flag(help="channel multiplier of ours (1: 58 K parameters; 2: 4x the multiply-adds)"),
    "batch_size": Flag(help="frames per gradient step"),
    "grad_clip": NOT_A_FLAG,
    "shift": Flag(help="random-shift augmentation in pixels (0: off)"),
    "pos_weight": Flag(
        help="positive-class loss weight: a number or 'balanced' (default: none)",
        convert=_pos_weight,
    ),
    "label": Flag(
        choices=sorted(LABELS),
        help="frame label: success (the simulator's success flag), dense (the paper's: "
        "dense reward summed over the step's 50 repeats >= 30) or progress (soft: 0.7 ** "
        "steps until the paper's label first holds)",
    ),
    "seed": Flag(),
    "device": Flag(),
    "threads": Flag(cli_only=True, type=int, default=None, help="torch CPU threads"),
    "ship": Flag(
        cli_only=True,
        action="store_true",
        default=False,
        help="write ours into the package (vp2/assets/classifiers) with metrics.json; "
        "the paper's checkpoints (50 MB each) go to --out",
    ),
    "out": Flag(
        cli_only=True,
        type=Path,
        default=None,
        help="run directory (default: runs/classifiers); with --ship it holds only the "
        "paper's checkpoints",
    ),
}


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 train-classifier`` arguments to ``p`` (one per :data:`FLAGS` entry)."""
    add_flags(p, ClassifierTrainConfig, FLAGS)
    return p


def _command_line(args: argparse.Namespace) -> str:
    parts = ["vp2 train-classifier", f"--data {args.data}"]
    if args.tasks:
        parts.append("--tasks " + " ".join(args.tasks))
    parts.append("--arch " + " ".join(args.arch))
    parts.append(f"--steps {args.steps}")
    if args.paper_steps is not None:
        parts.append(f"--paper-steps {args.paper_steps}")
    parts += [f"--batch-size {args.batch_size}", f"--shift {args.shift}", f"--seed {args.seed}"]
    if args.label != "success":
        parts.append(f"--label {args.label}")
    if args.width != 1:
        parts.append(f"--width {args.width}")
    if args.lr_schedule != "constant":
        parts.append(f"--lr-schedule {args.lr_schedule}")
    if args.pos_weight is not None:
        parts.append(f"--pos-weight {args.pos_weight}")
    if args.threads is not None:
        parts.append(f"--threads {args.threads}")
    if args.ship:
        parts.append("--ship")
    if args.out is not None:
        parts.append(f"--out {args.out}")
    return " ".join(parts)


def run_from_args(args: argparse.Namespace) -> int:
    """Runs ``vp2 train-classifier``: trains, evaluates and saves per task and arch.

    Prints one table row per (task, arch): held-out frames, positives, accuracy, precision,
    recall. Returns 0.
    """
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    tasks = [short_task(t) for t in (args.tasks or ROBODESK_TASKS)]
    run_dir = Path(args.out) if args.out is not None else Path("runs/classifiers")
    metrics_dir = ASSETS_DIR if args.ship else run_dir
    command = _command_line(args)
    print("| task | arch | held-out frames (positive) | accuracy | precision | recall | file |")
    print("|---|---|---|---|---|---|---|")
    for task in tasks:
        for arch in args.arch:
            steps = args.paper_steps if arch == "paper" and args.paper_steps else args.steps
            width = args.width if arch == "ours" else 1
            config = build(ClassifierTrainConfig, args, FLAGS, arch=arch, steps=steps, width=width)
            model, meta = train_task(args.data, task, config, command)
            directory = ASSETS_DIR if args.ship and arch == "ours" else run_dir
            path = save_classifier(directory / checkpoint_name(task, arch), model, meta)
            entry = {k: v for k, v in meta.items() if k != "data"}
            entry["data"] = {k: meta["data"][k] for k in ("dataset", "train", "valid")}
            entry["file"] = str(path.name if directory == metrics_dir else path)
            entry["file_bytes"] = path.stat().st_size
            update_metrics(metrics_dir / METRICS_FILE, arch, task, entry)
            m = meta["heldout"]
            print(
                f"| {task} | {arch} | {m['frames']} ({m['positives']}) | {_fmt(m['accuracy'])} "
                f"| {_fmt(m['precision'])} | {_fmt(m['recall'])} | {path} |",
                flush=True,
            )
    print(f"metrics: {metrics_dir / METRICS_FILE}")
    return 0


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f}"


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m vp2.classifiers.command ...`` (same arguments as ``vp2 train-classifier``)."""
    parser = configure_parser(
        argparse.ArgumentParser(prog="vp2 train-classifier", description=__doc__.splitlines()[0])
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        return run_from_args(args)
    except (ValueError, DatasetError, FileNotFoundError) as exc:
        print(f"vp2 train-classifier: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
