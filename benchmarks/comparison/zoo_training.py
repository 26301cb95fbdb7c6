"""Train the five families round-robin at one budget each, tracking action conditioning.

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.comparison.zoo_training \\
        --data data/robodesk-20x-64px --levels 15 30 60 90 120 --out outputs/zoo-training

Every family of :data:`~benchmarks.comparison.model_comparison_settings.FAMILIES` (or ``--families``)
trains in rounds: round ``L`` brings each family's training time (``vp2 train --max-minutes``,
summed over resumed sessions; validation and checkpoint writing left out) to ``L`` minutes,
family after family, before any family starts round ``L + 1``. A session cut short therefore
leaves every family within one round of the others, and the same command continues where it
stopped (an interrupted training resumes from its newest checkpoint). The training time is
the process's **CPU time** (``--clock cpu``, the default on a CPU: one thread, data loaded in
the process, so a minute is a core-minute whatever else the machine runs) or wall time
(``--clock wall``, the default on a GPU). MaskViT trains its tokenizer for the first
``--tokenizer-minutes`` of its budget and its transformer for the rest (the transformer needs
the finished tokenizer).

After each round a family's weights are exported (float16, inference only) to
``snapshots/<family>-<L>min.pt`` and its **action conditioning** is measured on held-out clips:
the prediction error under each clip's true actions and under another clip's, measured as
``vp2 diagnose`` measures it (:func:`vp2.diagnose.model.measure_conditioning`): the ratio
shuffled / true with 95% bootstrap intervals over clips and over the clips' trajectories. The
target is an interval over trajectories wholly above ``--target`` (1.1): the clips are windows
of a few trajectories, so the interval over clips claims more than they hold.

Layout of ``--out``::

    zoo_training.json            settings and the command of the latest invocation
    train/<model>/               `vp2 train` run directories
    snapshots/<family>-<L>min.pt exported weights at the end of round L
    curve/<family>-<L>min.json   one point of the curve: minutes, steps, ratio, intervals
    curve.md, curve.svg          the table and the chart of every point so far

Each point records the settings it was made with; a second invocation with other settings for
the same ``--out`` stops with a message instead of mixing runs. ``--smoke`` is a tiny
configuration for the test (``tests/scripts/test_zoo_training.py``).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

import vp2
from benchmarks import common
from benchmarks.comparison.model_comparison_settings import (
    FAMILIES,
    STEP_CAP,
    device_name,
    done_record,
)
from benchmarks.comparison.zoo_training_curve import (
    _label,
    card_fields,
    curve_markdown,
    curve_svg,
    read_points,
    target_interval,
)
from vp2.data.storage import load_manifest
from vp2.diagnose.model import measure_conditioning
from vp2.envs import env_class
from vp2.report.charts import svg_file_text
from vp2.run.model_spec import parse_model_args as parse_model_args_of_vp2
from vp2.run.model_spec import resolve_model
from vp2.training import trainer as trainer_module
from vp2.training.checkpoint import list_checkpoints
from vp2.training.config import TrainConfig
from vp2.training.export import export_checkpoint
from vp2.training.trainer import train
from vp2.utils.io import atomic_path, json_safe, write_json_atomic
from vp2.utils.tensors import resolve_device

#: Context and predicted frames of the held-out clips (the planner's 2 and 10).


@dataclasses.dataclass(frozen=True)
class Settings:
    """The run's settings (flag names as field names); ``device`` is resolved."""

    out: Path
    data: Path
    families: tuple[str, ...]
    levels: tuple[float, ...]
    tokenizer_minutes: float
    batch_size: int
    lr: float | None
    device: str
    threads: int
    ckpt_interval: int
    eval_batches: int
    clips: int
    samples: int
    target: float
    clock: str  # "cpu": process CPU time; "wall": wall time
    smoke: bool
    command: str
    #: ``(family, key, value)``: a model setting of the family's predictor changed from its
    #: preset (``--model-arg``), for a variant trained to its own ``--out``.
    model_args: tuple[tuple[str, str, Any], ...] = ()
    #: ``--num-trajectories``: train on the dataset's first N trajectories only (a data-quantity
    #: point); the held-out clips it is measured on stay the whole dataset's.
    max_trajectories: int | None = None


def stage_minutes(family: str, level: float, tokenizer_minutes: float) -> list[float]:
    """The ``max_minutes`` of each of ``family``'s training stages at round ``level``
    (0: the stage has not started). MaskViT: the tokenizer's first, then the transformer."""
    stages = FAMILIES[family]
    if len(stages) == 1:
        return [level]
    first = min(level, tokenizer_minutes)
    return [first, max(0.0, level - tokenizer_minutes)]


def train_config(s: Settings, family: str, index: int, minutes: float, level: float) -> TrainConfig:
    """The ``vp2 train`` run of stage ``index`` of ``family`` with a budget of ``minutes`` (in
    round ``level``; ``--smoke`` stops round n at step 2n instead, so that it is exact)."""
    stage = FAMILIES[family][index]
    overrides = dict(stage.overrides)
    if index == len(FAMILIES[family]) - 1:  # the predictor: the variant's settings
        overrides.update({key: value for f, key, value in s.model_args if f == family})
    if stage.tokenizer:
        prev = FAMILIES[family][index - 1]
        overrides["tokenizer_checkpoint"] = str(final_checkpoint(s.out / "train" / prev.model))
    return TrainConfig(
        model=stage.model,
        preset=stage.preset,
        model_overrides=overrides,
        dataset=str(s.data),
        max_trajectories=s.max_trajectories,
        out_dir=str(s.out / "train" / stage.model),
        steps=2 * (s.levels.index(level) + 1) if s.smoke else STEP_CAP,
        max_minutes=minutes,
        batch_size=s.batch_size,
        lr=s.lr,
        seed=0,
        eval_interval=0,
        eval_batches=s.eval_batches,
        ckpt_interval=s.ckpt_interval,
        keep_checkpoints=2,
        log_interval=100,
        workers=0,
        device=s.device,
        tensorboard=False,
        progress=sys.stderr.isatty(),
        resume=True,
    )


def final_checkpoint(run_dir: Path) -> Path:
    """The newest checkpoint of a finished tokenizer run (the transformer's input)."""
    found = list_checkpoints(run_dir)
    if not found:
        raise FileNotFoundError(f"no checkpoint in {run_dir}: train the tokenizer first")
    return found[-1]


def train_round(s: Settings, family: str, level: float) -> dict[str, Any]:
    """Brings ``family``'s stages to round ``level``; returns the last stage's state."""
    info: dict[str, Any] = {}
    for index, minutes in enumerate(stage_minutes(family, level, s.tokenizer_minutes)):
        if minutes <= 0:
            return {}  # the predictor has not started (MaskViT's transformer)
        result = train(train_config(s, family, index, minutes, level))
        info = {
            "model": FAMILIES[family][index].model,
            "step": result.step,
            "train_minutes": result.train_minutes,
            "checkpoint": str(result.checkpoint),
            "valid": dict(result.valid_metrics),
        }
        if index == 0 and len(FAMILIES[family]) > 1:
            info["tokenizer"] = {k: info[k] for k in ("step", "train_minutes")}
    return info


def point(s: Settings, family: str, level: float) -> dict[str, Any] | None:
    """Trains ``family`` to round ``level`` and measures its conditioning (or reads the point
    if done); ``None`` when the family has no predictor yet at that round."""
    path = s.out / "curve" / f"{family}-{_label(level)}.json"
    settings = {
        "family": family,
        "level": level,
        "data": str(s.data),
        "batch_size": s.batch_size,
        "lr": s.lr,
        "tokenizer_minutes": s.tokenizer_minutes,
        "clock": s.clock,
        "clips": s.clips,
        "samples": s.samples,
    }
    record = done_record(path, settings)
    if record is not None:
        return record
    started = time.perf_counter()
    info = train_round(s, family, level)
    if not info:
        return None
    snapshot = s.out / "snapshots" / f"{family}-{_label(level)}.pt"
    snapshot.parent.mkdir(parents=True, exist_ok=True)
    export_checkpoint(info["checkpoint"], snapshot)
    spec = f"{info['model']}:{snapshot}"
    measured = time.perf_counter()
    stats, moving = conditioning(s, spec)
    record = {
        "settings": settings,
        "family": family,
        "level_minutes": level,
        "model": spec,
        "step": info["step"],
        "train_minutes": info["train_minutes"],
        "tokenizer": info.get("tokenizer"),
        "valid": info["valid"],
        "conditioning": stats,
        "conditioning_moving": moving,
        "above_target": target_interval(stats)[0] > s.target,
        "device": device_name(s.device),
        "threads": torch.get_num_threads(),
        "conditioning_seconds": time.perf_counter() - measured,
        "seconds": time.perf_counter() - started,
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
    write_json_atomic(path, json_safe(record))
    return record


def conditioning(s: Settings, spec: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """The conditioning measure of a snapshot (all pixels, changing pixels)."""
    env = load_manifest(s.data).get("config", {}).get("env", "robodesk")
    device = torch.device(s.device)
    model = resolve_model(spec, {}, env=env, action_dim=int(env_class(env).action_dim),
                          device=device)
    stats = measure_conditioning(model, s.data, s.clips, s.samples, 0, device)
    return stats, stats.pop("moving")


def remeasure(s: Settings) -> list[dict[str, Any]]:
    """Measures again the conditioning of the points of ``s.families`` and ``s.levels`` that
    predate the interval over trajectories (their snapshots, the same clips and seeds: the
    ratio and the interval over clips come out as before), and rewrites those points; trains
    nothing. Returns the points rewritten."""
    done = []
    for level in s.levels:
        for family in s.families:
            path = s.out / "curve" / f"{family}-{_label(level)}.json"
            if not path.is_file():
                continue
            record = json.loads(path.read_text())
            if "trajectory_ci" in record["conditioning"]:
                continue
            measured = time.perf_counter()
            stats, moving = conditioning(s, record["model"])
            if abs(stats["ratio"] - record["conditioning"]["ratio"]) > 1e-6 * stats["ratio"]:
                raise SystemExit(
                    f"{path}: the snapshot's ratio is now {stats['ratio']:.6f}, was "
                    f"{record['conditioning']['ratio']:.6f}: not the same measure; not rewritten"
                )
            record.update(
                conditioning=stats, conditioning_moving=moving,
                above_target=target_interval(stats)[0] > s.target,
                conditioning_seconds=time.perf_counter() - measured,
                remeasured=datetime.datetime.now(datetime.timezone.utc).isoformat(
                    timespec="seconds"),
            )  # fmt: skip
            write_json_atomic(path, json_safe(record))
            low, high = stats["trajectory_ci"]
            print(f"[{_label(level)}] {family}: ratio {stats['ratio']:.3f}, over "
                  f"{stats['trajectories']} trajectories [{low:.3f}, {high:.3f}]", flush=True)
            done.append(record)
    publish(s)
    return done


def publish(s: Settings) -> None:
    points = read_points(s.out)
    with atomic_path(s.out / "curve.md") as tmp:
        Path(tmp).write_text(curve_markdown(points, s.target, s.command))
    with atomic_path(s.out / "curve.svg") as tmp:
        Path(tmp).write_text(svg_file_text(curve_svg(points, s.target, s.clock)))


def run(s: Settings) -> list[dict[str, Any]]:
    """Every round of every family, in order; returns the points measured or found."""
    torch.set_num_threads(s.threads)
    # The trainer's budget clock: CPU time makes a minute a core-minute on a shared machine.
    trainer_module.clock = time.process_time if s.clock == "cpu" else time.monotonic
    s.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(s.out / "zoo_training.json", json_safe(dataclasses.asdict(s)))
    done = []
    for level in s.levels:
        for family in s.families:
            record = point(s, family, level)
            if record is None:
                print(f"[{_label(level)}] {family}: tokenizer only so far", flush=True)
                continue
            c = record["conditioning"]
            print(
                f"[{_label(level)}] {family}: step {record['step']}, ratio {c['ratio']:.3f} "
                f"[{c['ci'][0]:.3f}, {c['ci'][1]:.3f}]",
                flush=True,
            )
            done.append(record)
            publish(s)
    return done


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = common.argument_parser(__spec__.name, __doc__ or "")
    p.add_argument("--data", type=Path, default=Path("data/robodesk-20x-64px"))
    p.add_argument("--families", nargs="+", default=list(FAMILIES), choices=list(FAMILIES))
    p.add_argument(
        "--levels",
        nargs="+",
        type=float,
        default=[15, 30, 60, 90, 120],
        help="cumulative training minutes per family at the end of each round",
    )
    p.add_argument(
        "--tokenizer-minutes",
        type=float,
        default=20.0,
        help="MaskViT: minutes of its budget spent on the tokenizer (default 20)",
    )
    p.add_argument("--batch-size", type=int, default=8)
    p.add_argument("--lr", type=float, default=None, help="default: each model's own")
    p.add_argument("--device", default=None, help="default: cuda if available")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--ckpt-interval", type=int, default=500)
    p.add_argument("--eval-batches", type=int, default=8)
    p.add_argument("--clips", type=int, default=64, help="held-out clips per measurement")
    p.add_argument("--samples", type=int, default=2, help="sampling seeds per clip")
    p.add_argument("--target", type=float, default=1.1)
    p.add_argument(
        "--clock",
        choices=["cpu", "wall"],
        default=None,
        help="what a budget minute is: process CPU time (default on a CPU) or wall time (GPU)",
    )
    p.add_argument("--out", type=Path, default=Path("outputs/zoo-training"))
    p.add_argument(
        "--publish-only",
        action="store_true",
        help="rewrite curve.md and curve.svg from the points measured; train nothing",
    )
    p.add_argument(
        "--remeasure",
        action="store_true",
        help="measure again the conditioning of the points (of --families, --levels) made "
        "before the interval over trajectories existed, from their snapshots; train nothing",
    )
    p.add_argument(
        "--card",
        metavar="LABEL",
        help="write the zoo card fields of snapshot LABEL (e.g. svg_prime-30min) to "
        "OUT/cards/LABEL.json, for `vp2 zoo add SNAPSHOT --card-from`; train nothing",
    )
    p.add_argument(
        "--model-arg",
        action="append",
        default=[],
        metavar="FAMILY:KEY=VALUE",
        help="a setting of one family's model changed from its preset (e.g. "
        "struct_vrnn:keypoint_sigma=0.3): a variant, trained to its own --out; repeatable",
    )
    p.add_argument(
        "--num-trajectories",
        type=int,
        default=None,
        metavar="N",
        help="train on the dataset's first N trajectories only (a data-quantity study; the "
        "held-out clips measured stay the whole dataset's); default: all",
    )
    p.add_argument("--smoke", action="store_true", help="tiny settings for the test")
    return p.parse_args(argv)


def parse_model_args(items: Sequence[str], families: Sequence[str]) -> tuple[tuple[str, str, Any], ...]:
    """``FAMILY:KEY=VALUE`` items -> ``((family, key, value), ...)``; ``KEY=VALUE`` is read as
    ``vp2 run --model-arg`` reads it (:func:`vp2.run.model_spec.parse_model_args`)."""
    out = []
    for item in items:
        family, _, rest = item.partition(":")
        try:
            (key, value), = parse_model_args_of_vp2([rest]).items()
        except ValueError:
            family = ""
        if family not in FAMILIES:
            raise SystemExit(f"--model-arg {item!r}: expected FAMILY:KEY=VALUE with FAMILY one "
                             f"of {', '.join(FAMILIES)}")
        if family not in families:
            raise SystemExit(f"--model-arg {item!r}: {family} is not among --families")
        out.append((family, key, value))
    return tuple(out)


def settings_from_args(args: argparse.Namespace, argv: Sequence[str] | None) -> Settings:
    levels = tuple(sorted(set(args.levels)))
    if not levels or levels[0] <= 0:
        raise SystemExit(f"--levels must be positive minutes, got {args.levels}")
    if not args.data.is_dir():
        raise SystemExit(
            f"--data {args.data} is not a dataset directory; make the default one with "
            "`vp2 collect robodesk`"
        )
    if args.num_trajectories is not None and args.num_trajectories <= 0:
        raise SystemExit(f"--num-trajectories must be a positive count, got {args.num_trajectories}")
    device = str(resolve_device(args.device))
    clock = args.clock or ("cpu" if device == "cpu" else "wall")
    if clock == "cpu" and (args.threads != 1 or device != "cpu"):
        raise SystemExit(
            "--clock cpu counts one core's time: it needs --threads 1 on a CPU (use --clock wall)"
        )
    return Settings(
        out=args.out,
        data=args.data,
        families=tuple(args.families),
        levels=levels,
        tokenizer_minutes=args.tokenizer_minutes,
        batch_size=args.batch_size,
        lr=args.lr,
        device=device,
        threads=args.threads,
        ckpt_interval=args.ckpt_interval,
        eval_batches=args.eval_batches,
        clips=args.clips,
        samples=args.samples,
        target=args.target,
        clock=clock,
        smoke=args.smoke,
        command=common.command_line(__spec__.name, argv),
        model_args=parse_model_args(args.model_arg, args.families),
        max_trajectories=args.num_trajectories,
    )


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    s = settings_from_args(args, argv)
    saved = s.out / "zoo_training.json"
    if (args.publish_only or args.card or args.remeasure) and saved.is_file():
        # the page and the cards name the command that trained, not this one
        s = dataclasses.replace(s, command=json.loads(saved.read_text())["command"])
    if args.card:
        path = s.out / "curve" / f"{args.card}.json"
        if not path.is_file():
            raise SystemExit(f"--card {args.card}: no {path}; the round has not been measured")
        out = s.out / "cards" / f"{args.card}.json"
        out.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(out, card_fields(json.loads(path.read_text()), s.command))
        print(out)
        return
    if args.remeasure:
        remeasure(s)
        return
    if args.publish_only:
        publish(s)
        print((s.out / "curve.md").read_text())
        return
    common.print_header(__spec__.name, device_name(s.device))
    print(f"vp2 {vp2.__version__}: {len(s.families)} families, rounds {list(s.levels)} min")
    run(s)


if __name__ == "__main__":
    main()
