"""The ``vp2 train`` command: flags -> :class:`TrainConfig` -> :func:`train`.

::

    vp2 train --model svg_prime --env robodesk                 # data/robodesk-20x-64px
    vp2 train --model fitvid --preset mini --env tabletop --steps 20000 --perceptual lpips_vgg \\
        --perceptual-weight 10
    vp2 train --model fitvid --preset mini --env tabletop --steps 40000 --resume   # continue
    vp2 train --model mcvd --preset tiny --env robodesk --max-minutes 60   # a time budget

One flag per :class:`TrainConfig` field; the Python API is the same dataclass and
:func:`train`. ``--data`` defaults to the directory ``vp2 collect <env>`` writes. A run
continues from its newest checkpoint with the same command plus ``--resume`` (``--steps`` may
grow).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vp2.cli._fields import Flag, add_flags, build
from vp2.data.datasets import default_dataset, default_trajectories
from vp2.data.storage import MANIFEST, DatasetError, load_manifest
from vp2.models.registry import MODELS, make_config, model_names, parse_overrides
from vp2.training.config import TrainConfig
from vp2.training.perceptual import PERCEPTUAL_LOSSES
from vp2.training.trainer import train

NAME = "train"
HELP = "train a video prediction model on a collected dataset"
DESCRIPTION = (
    "Train a video prediction model on a collected dataset (docs/models.md). Continue a run "
    "with the same command and --resume."
)


def default_out_dir(config: TrainConfig) -> Path:
    """``runs/<model>-<preset>-<dataset name>[-<perceptual><weight>]-seed<seed>``."""
    preset = config.preset or MODELS[config.model].default_preset
    name = f"{config.model}-{preset}-{Path(config.dataset).name}"
    if config.perceptual and config.perceptual_weight > 0:
        name += f"-{config.perceptual}{config.perceptual_weight:g}"
    return Path("runs") / f"{name}-seed{config.seed}"


#: Shown under ``vp2 train --help``: the smallest presets and how to train on a CPU (the
#: figures are measured in docs/models.md).
SIZES_EPILOG = """\
smallest presets (parameters; docs/models.md has every preset and its timing):
  struct_vrnn tiny 0.10 M   maskvit tiny 0.30 M (+ maskvit_tokenizer tiny 0.18 M)
  fitvid mini 1.52 M        mcvd tiny 1.60 M (10 sampling steps)
  svg_prime m0.25k0.25 5.79 M; with --model-arg m=0.125 k=0.125: 1.65 M (the shipped model)
on a CPU: fitvid mini predicts a 200-sample planning batch in 18 s, svg_prime m0.25k0.25 in
41 s (2-core reference machine). On a CPU shared with other work run with OMP_NUM_THREADS=1:
under contention one thread trained 5x faster than two (docs/models.md)."""


def _flags() -> dict[str, Flag | None]:
    """One entry per :class:`TrainConfig` field (and ``--env``), in the order of ``vp2 train
    --help``; the help of ``--model``, ``--preset``, ``--env`` and ``--data`` lists what the
    registries hold."""
    envs = sorted(default_trajectories())
    presets = "; ".join(
        f"{name}: {', '.join(entry.presets)} (default {entry.default_preset})"
        for name, entry in sorted(MODELS.items())
    )
    what, data, opt, run = "what to train", "data", "optimisation", "run"
    return {
        "model": Flag(group=what, required=True, choices=model_names(), help="model to train"),
        "preset": Flag(group=what, help=f"size preset ({presets})"),
        "model_overrides": Flag(
            "--model-arg",
            group=what,
            nargs="+",
            action="extend",
            default=[],
            metavar="KEY=VALUE",
            help="model config overrides (repeatable), e.g. beta=1e-3 rnn_size=256",
        ),
        "env": Flag(
            group=data,
            cli_only=True,
            choices=envs,
            help="environment: trains on all its tasks; picks the default --data",
        ),
        "dataset": Flag(
            "--data",
            group=data,
            type=Path,
            default=None,
            metavar="DIR",
            help="dataset directory (default: the one `vp2 collect ENV` writes: "
            + ", ".join(str(default_dataset(e)) for e in envs)
            + ")",
        ),
        "tasks": Flag(group=data, metavar="STREAM", help="train on these data streams only"),
        "max_trajectories": Flag(
            "--num-trajectories",
            group=data,
            metavar="N",
            help="use only the dataset's first N trajectories (all tasks interleaved)",
        ),
        "steps": Flag(group=opt, help="total steps (default: %(default)s; paper: 153K)"),
        "max_minutes": Flag(
            group=opt,
            metavar="MIN",
            help="training time budget: stop (validate, write the final checkpoint) after the "
            "first step at which the run's training wall time, earlier --resume sessions "
            "included, reaches MIN minutes, or at --steps if that comes first (default: no "
            "budget)",
        ),
        "batch_size": Flag(group=opt, help="default: %(default)s"),
        "lr": Flag(group=opt, help="learning rate (default: the model's, 3e-4)"),
        "optimizer": Flag(
            group=opt, choices=["adam", "adamw"], help="default: the model's (Adam)"
        ),
        "weight_decay": Flag(group=opt, help="default: the model's (0)"),
        "grad_clip": Flag(
            group=opt,
            help="max gradient norm (default: the model's, FitVid 100, SVG' none; <= 0: off)",
        ),
        "seed": Flag(group=opt, help="weights, data order, noise"),
        "perceptual": Flag(
            group=opt,
            choices=sorted(PERCEPTUAL_LOSSES),
            help="add a perceptual loss term (LPIPS weights must be on disk: docs/metrics.md)",
        ),
        "perceptual_weight": Flag(
            group=opt,
            default=None,
            metavar="W",
            help="its weight (default 1 with --perceptual; the paper used 0, 1 and 10)",
        ),
        "out_dir": Flag(
            "--out",
            group=run,
            type=Path,
            default=None,
            metavar="DIR",
            help="run directory (default: runs/<model>-<preset>-<dataset>[-<perceptual><W>]"
            "-seed<seed>)",
        ),
        "resume": Flag(
            group=run, help="continue the run in --out from its newest checkpoint"
        ),
        "device": Flag(group=run, help="cuda, cuda:1, cpu, ... (default: CUDA if available)"),
        "amp": Flag(
            group=run,
            action=argparse.BooleanOptionalAction,
            help="mixed precision (default: on for CUDA only)",
        ),
        "workers": Flag(group=run, help="data loader processes (0: none)"),
        "eval_interval": Flag(
            group=run,
            metavar="STEPS",
            help="validate and save a prediction grid every STEPS (0: at the end)",
        ),
        "eval_batches": Flag(group=run),
        "ckpt_interval": Flag(
            group=run, metavar="STEPS", help="checkpoint every STEPS (and at the end)"
        ),
        "keep_checkpoints": Flag(group=run, metavar="N"),
        "log_interval": Flag(group=run, metavar="STEPS"),
        "tensorboard": Flag("--no-tensorboard", group=run, negate=True, help="CSV log only"),
        "progress": Flag("--no-progress", group=run, negate=True, help="no progress bar"),
    }


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 train`` flags to ``p`` (a sub-parser) and returns it."""
    p.epilog = SIZES_EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    add_flags(p, TrainConfig, _flags())
    return p


def _check_dataset(path: Path, env: str | None, defaulted: bool) -> None:
    if not (path / MANIFEST).is_file():
        if defaulted:
            how = f"`vp2 collect {env}` creates it"
        else:
            how = f"create it with `vp2 collect {env or 'ENV'} --out {path}`"
        raise FileNotFoundError(
            f"no dataset at {path} ({MANIFEST} missing); {how}, or pass --data DIR"
        )
    try:
        manifest_env = load_manifest(path).get("config", {}).get("env")
    except DatasetError as exc:
        raise ValueError(str(exc)) from exc
    if env is not None and manifest_env is not None and manifest_env != env:
        raise ValueError(f"--env {env} but {path} holds a {manifest_env!r} dataset")


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """The :class:`TrainConfig` a parsed ``vp2 train`` command line describes.

    Raises:
        FileNotFoundError: the dataset is missing (the message says which command creates it).
        ValueError: inconsistent flags, unknown preset or model field, a dataset of another
            environment.
    """
    if args.data is None and args.env is None:
        raise ValueError("give --env ENV (for its default dataset) or --data DIR")
    data = args.data if args.data is not None else default_dataset(args.env)
    _check_dataset(data, args.env, defaulted=args.data is None)

    overrides = parse_overrides(args.model_arg)
    make_config(args.model, args.preset, **overrides)  # unknown presets / fields fail here
    weight = args.perceptual_weight
    if weight is None:
        weight = 1.0 if args.perceptual else 0.0
    elif weight > 0 and not args.perceptual:
        raise ValueError(
            f"--perceptual-weight {weight:g} needs --perceptual NAME "
            f"({', '.join(sorted(PERCEPTUAL_LOSSES))})"
        )
    # Every other field straight from its flag.
    config = build(
        TrainConfig, args, _flags(), dataset=str(data), out_dir="", model_overrides=overrides,
        perceptual_weight=weight,
    )
    config.out_dir = str(args.out if args.out is not None else default_out_dir(config))
    return config


def run_from_args(args: argparse.Namespace) -> int:
    """Runs ``vp2 train`` from parsed arguments; returns the exit status.

    Errors the user can fix (missing dataset or weights, bad flags, a changed configuration
    on ``--resume``) are raised as ``FileNotFoundError`` / ``FileExistsError`` /
    ``ValueError`` with a message for the command line.
    """
    config = config_from_args(args)
    print(f"training {config.model} on {config.dataset} -> {config.out_dir}", flush=True)
    try:
        result = train(config)
    except DatasetError as exc:  # an incomplete or corrupted dataset
        raise ValueError(str(exc)) from exc
    except KeyboardInterrupt:
        print(
            f"\ninterrupted; continue from the newest checkpoint in {config.out_dir} with the "
            "same command plus --resume",
            file=sys.stderr,
        )
        return 130
    print(f"checkpoint: {result.checkpoint} (step {result.step})")
    stopped = (
        f" (the {config.max_minutes:g}-minute budget ended it)" if result.budget_reached else ""
    )
    print(f"training time: {result.train_minutes:.2f} min{stopped}")
    for key, value in sorted(result.valid_metrics.items()):
        print(f"{key}: {value:.6g}")
    return 0
