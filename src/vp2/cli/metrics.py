"""``vp2 metrics``: perceptual metrics of a model on held-out clips (docs/metrics.md)."""

from __future__ import annotations

import argparse
import logging
import re
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from vp2.data.datasets import default_dataset
from vp2.data.storage import MANIFEST, load_manifest
from vp2.metrics.evaluate import (
    DEFAULT_BATCH_SIZE,
    DEFAULT_NUM_CLIPS,
    METRICS_FILE,
    evaluate_model,
    write_metrics,
)
from vp2.training.perceptual import BACKBONES
from vp2.utils.kv import parse_key_values, yaml_value

log = logging.getLogger(__name__)

NAME = "metrics"
HELP = "perceptual metrics of a model on held-out clips"
DESCRIPTION = (
    "MSE, PSNR, SSIM, LPIPS and FVD of a model's predictions on a fixed, seeded set of held-"
    "out clips (docs/metrics.md)."
)


def model_slug(spec: str) -> str:
    """A file-name-safe form of a model spec (``svg_prime:runs/a`` -> ``svg_prime-runs-a``)."""
    slug = re.sub(r"[^A-Za-z0-9._-]+", "-", spec).strip("-.")
    return slug or "model"


def default_out(spec: str, env: str | None) -> Path:
    """``runs/metrics/<model-slug>[-<env>]/metrics.json``."""
    name = model_slug(spec) + (f"-{env}" if env else "")
    return Path("runs") / "metrics" / name / METRICS_FILE


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 metrics`` flags to ``p`` (a sub-parser) and returns it."""
    p.add_argument(
        "--model",
        required=True,
        help="model spec: repeat_last_frame | simulator | NAME:CHECKPOINT | zoo:NAME | "
        "package.module:factory | file.yaml",
    )
    p.add_argument(
        "--model-arg",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="model factory argument, repeatable; VALUE parsed as YAML",
    )
    p.add_argument(
        "--env", choices=["robodesk", "tabletop"], help="environment (picks the default --data)"
    )
    p.add_argument(
        "--data",
        type=Path,
        metavar="DIR",
        help="dataset (default: the one `vp2 collect ENV` writes)",
    )
    p.add_argument("--num-clips", type=int, default=DEFAULT_NUM_CLIPS, help="default: %(default)s")
    p.add_argument("--seed", type=int, default=0, help="clip choice and model noise")
    p.add_argument("--batch-size", type=int, default=DEFAULT_BATCH_SIZE, help="clips per batch")
    p.add_argument("--no-fvd", action="store_true", help="skip FVD (the slowest metric)")
    p.add_argument(
        "--lpips",
        nargs="*",
        choices=sorted(BACKBONES),
        default=["alex", "vgg"],
        metavar="NET",
        help="LPIPS backbones: alex vgg (default both; none: no LPIPS)",
    )
    p.add_argument(
        "--weights-dir", type=Path, metavar="DIR", help="weight files (default: docs/metrics.md)"
    )
    p.add_argument(
        "--require-all",
        action="store_true",
        help="fail instead of skipping a metric whose weight file is missing",
    )
    p.add_argument(
        "--out",
        type=Path,
        metavar="FILE",
        help="result JSON (default: runs/metrics/<model-slug>-<env>/metrics.json)",
    )
    p.add_argument("--device", help="cuda, cpu, ... (default: CUDA if available)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def run_from_args(args: argparse.Namespace) -> int:
    """Runs ``vp2 metrics`` from parsed arguments; prints the table and writes the JSON.

    Raises:
        ValueError / FileNotFoundError: with a message for the command line.
    """
    if args.data is None and args.env is None:
        raise ValueError("give --env ENV (for its default dataset) or --data DIR")
    data = args.data if args.data is not None else default_dataset(args.env)
    if not (Path(data) / MANIFEST).is_file():
        if args.data is None:
            how = f"`vp2 collect {args.env}` creates it, or pass --data DIR"
        else:
            how = f"create it with `vp2 collect {args.env or 'ENV'} --out {data}`"
        raise FileNotFoundError(f"no dataset at {data} ({MANIFEST} missing); {how}")
    env = args.env or load_manifest(data).get("config", {}).get("env")
    # Values are read as YAML, as `vp2 run --model-arg` reads them (`2` an int, `true` a bool).
    model_args = parse_key_values(args.model_arg, "model argument")
    result = evaluate_model(
        args.model,
        data,
        num_clips=args.num_clips,
        seed=args.seed,
        batch_size=args.batch_size,
        lpips_nets=tuple(args.lpips),
        fvd=not args.no_fvd,
        device=args.device,
        progress=not args.no_progress,
        model_args={k: yaml_value(v) for k, v in model_args.items()},
        env=env,
        weights_dir=args.weights_dir,
        require_all=args.require_all,
    )
    out = write_metrics(args.out or default_out(args.model, env), result)
    print(format_table(result))
    for name, why in result["skipped"].items():
        print(f"skipped {name}: {why}", file=sys.stderr)
    if result["num_clips"] < args.num_clips:  # the split has fewer: all of them were used
        n = result["num_clips"]
        log.warning(
            "--num-clips %d: the dataset's %s split has %d clips; evaluated those %d",
            args.num_clips, result["split"], n, n,
        )
    print(f"wrote {out}")
    return 0


def format_table(result: Mapping[str, Any]) -> str:
    """The display values as a two-column text table."""
    names = {
        "mse": "MSE",
        "psnr": "PSNR (dB)",
        "ssim_x100": "SSIM x100",
        "lpips_alex_x100": "LPIPS-Alex x100",
        "lpips_vgg_x100": "LPIPS-VGG x100",
        "fvd": "FVD",
    }
    lines = [f"{result['model'].get('name')} on {result['num_clips']} clips ({result['dataset']})"]
    for key, label in names.items():
        if key in result["display"]:
            lines.append(f"  {label:16s} {result['display'][key]:.4f}")
    return "\n".join(lines)
