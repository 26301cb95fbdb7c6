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
import dataclasses
import sys
from pathlib import Path

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


_DEFAULTS = {f.name: f.default for f in dataclasses.fields(TrainConfig)}


def default_out_dir(config: TrainConfig) -> Path:
    """``runs/<model>-<preset>-<dataset name>[-<perceptual><weight>]-seed<seed>``."""
    preset = config.preset or MODELS[config.model].default_preset
    name = f"{config.model}-{preset}-{Path(config.dataset).name}"
    if config.perceptual and config.perceptual_weight > 0:
        name += f"-{config.perceptual}{config.perceptual_weight:g}"
    return Path("runs") / f"{name}-seed{config.seed}"


def _add_int(
    group: argparse._ActionsContainer,
    flag: str,
    help: str | None = None,
    metavar: str | None = None,
    field: str | None = None,
) -> None:
    """An integer flag whose default is that of the :class:`TrainConfig` field it sets
    (``field``; default: the flag's name)."""
    default = _DEFAULTS[field or flag.removeprefix("--").replace("-", "_")]
    group.add_argument(flag, type=int, default=default, metavar=metavar, help=help)


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


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 train`` flags to ``p`` (a sub-parser) and returns it."""
    p.epilog = SIZES_EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    envs = sorted(default_trajectories())
    what = p.add_argument_group("what to train")
    what.add_argument("--model", required=True, choices=model_names(), help="model to train")
    presets = "; ".join(
        f"{name}: {', '.join(entry.presets)} (default {entry.default_preset})"
        for name, entry in sorted(MODELS.items())
    )
    what.add_argument("--preset", help=f"size preset ({presets})")
    what.add_argument(
        "--model-arg",
        nargs="+",
        action="extend",
        default=[],
        metavar="KEY=VALUE",
        help="model config overrides (repeatable), e.g. beta=1e-3 rnn_size=256",
    )

    data = p.add_argument_group("data")
    data.add_argument(
        "--env", choices=envs, help="environment: trains on all its tasks; picks the default --data"
    )
    data.add_argument(
        "--data",
        type=Path,
        metavar="DIR",
        help="dataset directory (default: the one `vp2 collect ENV` writes: "
        + ", ".join(str(default_dataset(e)) for e in envs)
        + ")",
    )
    data.add_argument(
        "--tasks", nargs="+", metavar="STREAM", help="train on these data streams only"
    )
    _add_int(
        data,
        "--num-trajectories",
        "use only the dataset's first N trajectories (all tasks interleaved)",
        metavar="N",
        field="max_trajectories",
    )

    opt = p.add_argument_group("optimisation")
    _add_int(opt, "--steps", "total steps (default: %(default)s; paper: 153K)")
    opt.add_argument(
        "--max-minutes",
        type=float,
        metavar="MIN",
        help="training time budget: stop (validate, write the final checkpoint) after the first "
        "step at which the run's training wall time, earlier --resume sessions included, "
        "reaches MIN minutes, or at --steps if that comes first (default: no budget)",
    )
    _add_int(opt, "--batch-size", "default: %(default)s")
    opt.add_argument("--lr", type=float, help="learning rate (default: the model's, 3e-4)")
    opt.add_argument("--optimizer", choices=["adam", "adamw"], help="default: the model's (Adam)")
    opt.add_argument("--weight-decay", type=float, help="default: the model's (0)")
    opt.add_argument(
        "--grad-clip",
        type=float,
        help="max gradient norm (default: the model's, FitVid 100, SVG' none; <= 0: off)",
    )
    _add_int(opt, "--seed", "weights, data order, noise")
    opt.add_argument(
        "--perceptual",
        choices=sorted(PERCEPTUAL_LOSSES),
        help="add a perceptual loss term (LPIPS weights must be on disk: docs/metrics.md)",
    )
    opt.add_argument(
        "--perceptual-weight",
        type=float,
        metavar="W",
        help="its weight (default 1 with --perceptual; the paper used 0, 1 and 10)",
    )

    run = p.add_argument_group("run")
    run.add_argument(
        "--out",
        type=Path,
        metavar="DIR",
        help="run directory (default: runs/<model>-<preset>-<dataset>[-<perceptual><W>]"
        "-seed<seed>)",
    )
    run.add_argument(
        "--resume", action="store_true", help="continue the run in --out from its newest checkpoint"
    )
    run.add_argument("--device", help="cuda, cuda:1, cpu, ... (default: CUDA if available)")
    run.add_argument(
        "--amp",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="mixed precision (default: on for CUDA only)",
    )
    _add_int(run, "--workers", "data loader processes (0: none)")
    _add_int(
        run,
        "--eval-interval",
        "validate and save a prediction grid every STEPS (0: at the end)",
        metavar="STEPS",
    )
    _add_int(run, "--eval-batches")
    _add_int(run, "--ckpt-interval", "checkpoint every STEPS (and at the end)", metavar="STEPS")
    _add_int(run, "--keep-checkpoints", metavar="N")
    _add_int(run, "--log-interval", metavar="STEPS")
    run.add_argument("--no-tensorboard", action="store_true", help="CSV log only")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
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
    # One flag per TrainConfig field, of the same name except for these.
    renamed = {
        "dataset": str(data),
        "out_dir": "",
        "model_overrides": overrides,
        "max_trajectories": args.num_trajectories,
        "perceptual_weight": weight,
        "tensorboard": not args.no_tensorboard,
        "progress": not args.no_progress,
    }
    fields = [f.name for f in dataclasses.fields(TrainConfig) if f.name not in renamed]
    config = TrainConfig(**{name: getattr(args, name) for name in fields}, **renamed)
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
