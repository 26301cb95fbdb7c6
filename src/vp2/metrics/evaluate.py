"""Perceptual metrics of a video prediction model on the held-out split (``vp2 metrics``).

::

    vp2 metrics --model svg_prime:runs/svg-robodesk --env robodesk
    vp2 metrics --model repeat_last_frame --env tabletop --num-clips 200 --lpips alex --no-fvd

Python API (the command calls exactly this)::

    result = evaluate_model("repeat_last_frame", "data/tabletop-100x-64px", num_clips=1000)
    write_metrics("runs/metrics/repeat_last_frame-tabletop", result)

A fixed, seeded sample of clips of the ``valid`` split (2 context + 10 future frames) is
predicted from the context frames and the clip's actions; every predicted frame is compared
with the true frame of the same time index: MSE, PSNR, SSIM, LPIPS (AlexNet, VGG) per frame,
averaged over frames and clips, and FVD between the set of predicted 10-frame videos and the
set of true ones. A metric whose weight file is missing is skipped with a message naming the
file (an error with ``require_all=True``). Nothing is downloaded; see ``docs/metrics.md``.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Subset
from tqdm.auto import tqdm

from vp2.data.loader import ClipDataset
from vp2.data.storage import MANIFEST, load_manifest
from vp2.metrics.fvd import FrechetVideoDistance, fvd_from_features
from vp2.metrics.image import mse, psnr, ssim
from vp2.metrics.lpips import BACKBONES, LPIPS, MissingWeightsError
from vp2.models.base import NUM_CONTEXT, NUM_FUTURE, checked, predict_in_chunks
from vp2.utils.io import write_json_atomic

log = logging.getLogger(__name__)

#: Clips evaluated by default (as the paper's FVD).
DEFAULT_NUM_CLIPS = 1000
#: Per-frame PSNR is capped here (an MSE of 1e-10): identical frames would give ``inf``.
PSNR_CAP = 100.0
#: The file :func:`write_metrics` writes inside a directory.
METRICS_FILE = "metrics.json"

_PER_FRAME = ("mse", "psnr", "ssim")


def _resolve_device(device: str | torch.device | None) -> torch.device:
    return torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))


def _load_metric(name: str, build: Any, require_all: bool, skipped: dict[str, str]) -> Any | None:
    try:
        return build()
    except MissingWeightsError as exc:
        if require_all:
            raise
        skipped[name] = str(exc)
        log.warning("skipping %s: %s", name, exc)
        return None


def _build_model(
    model_spec: Any,
    model_args: Mapping[str, Any] | None,
    env: str | None,
    dataset: ClipDataset,
    device: torch.device,
) -> tuple[Any, dict[str, Any]]:
    if not isinstance(model_spec, str):
        model = model_spec
        identity = {"spec": None, "name": getattr(model, "name", type(model).__name__)}
    else:
        from vp2.benchmark.plugins import build_model, model_identity

        model = build_model(
            model_spec, model_args, env=env or "", action_dim=dataset.action_dim, device=device
        )
        identity = model_identity(model_spec, model_args, model)
    model = checked(model)  # a wrong output shape or range fails with the model's name
    height, width, _ = dataset.image_shape  # stored frames are (H, W, 3)
    if model.image_size != height or height != width:
        raise ValueError(
            f"model {identity['name']} predicts {model.image_size}px frames but the dataset's "
            f"are {height}x{width}; evaluate on a dataset of its resolution "
            "(or pass model_args={'image_size': ...} to models that take it)"
        )
    if (model.num_context, model.num_future) != (dataset.context, dataset.future):
        raise ValueError(
            f"model {identity['name']} uses {model.num_context} context + {model.num_future} "
            f"future frames, the clips {dataset.context} + {dataset.future}"
        )
    return model, identity


def select_clips(num_available: int, num_clips: int, seed: int) -> list[int]:
    """The clip indices evaluated: ``min(num_clips, num_available)`` distinct indices drawn
    with ``seed`` (the same for every model), in increasing order."""
    if num_clips < 1:
        raise ValueError(f"num_clips must be >= 1, got {num_clips}")
    gen = torch.Generator().manual_seed(seed)
    chosen = torch.randperm(num_available, generator=gen)[: min(num_clips, num_available)]
    return sorted(chosen.tolist())


def evaluate_model(
    model_spec: Any,
    dataset: ClipDataset | str | os.PathLike[str],
    num_clips: int = DEFAULT_NUM_CLIPS,
    seed: int = 0,
    batch_size: int = 16,
    lpips_nets: Sequence[str] = ("alex", "vgg"),
    fvd: bool = True,
    device: str | torch.device | None = None,
    progress: bool = True,
    *,
    model_args: Mapping[str, Any] | None = None,
    env: str | None = None,
    weights_dir: str | os.PathLike[str] | None = None,
    require_all: bool = False,
    fvd_metric: FrechetVideoDistance | None = None,
) -> dict[str, Any]:
    """Scores a model's predictions on held-out clips; writes nothing.

    Args:
        model_spec: A model spec as ``vp2 run`` takes it (``repeat_last_frame``,
            ``svg_prime:CHECKPOINT``, ``package.module:factory``, a YAML file), or a built
            :class:`~vp2.models.base.VideoPredictionModel`.
        dataset: A dataset directory (its ``valid`` split is used) or a :class:`ClipDataset`.
        num_clips: Clips to evaluate (all of them if the split has fewer); FVD needs >= 2.
        seed: Seeds the choice of clips (:func:`select_clips`) and the model's sampling noise.
        batch_size: Clips per prediction and metric batch (also the I3D batch).
        lpips_nets: LPIPS backbones to score, of ``"alex"``, ``"vgg"``.
        fvd: Whether to compute FVD.
        device: Where the model and the metrics run (default: CUDA if available).
        progress: Show a progress bar.
        model_args: Keyword arguments of the model factory (spec strings only).
        env: Environment passed to the model factory (default: the dataset's).
        weights_dir: Directory with the LPIPS / I3D weight files (default lookup otherwise).
        require_all: Raise instead of skipping a metric whose weights are missing.
        fvd_metric: A ready :class:`FrechetVideoDistance` (e.g. with other weights); its own
            device and batch size are used.

    Returns:
        A JSON-able dict: ``metrics`` (means over clips and frames: ``mse``, ``psnr``,
        ``ssim``, ``lpips_alex``, ``lpips_vgg``, ``fvd``), ``display`` (SSIM and LPIPS x100),
        ``per_step`` (per predicted frame, 10 values each), ``skipped`` (metric -> why),
        ``clip_indices``, ``model``, ``dataset``, ``seconds`` and the settings.

    Raises:
        MissingWeightsError: with ``require_all``, a weight file is missing.
        ValueError: unknown LPIPS net, or a model that does not fit the dataset.
    """
    started = time.perf_counter()
    device = _resolve_device(device)
    for net in lpips_nets:
        if net not in BACKBONES:
            raise ValueError(f"unknown LPIPS network {net!r}; known: {', '.join(BACKBONES)}")
    dataset_path = None
    if not isinstance(dataset, ClipDataset):
        dataset_path = str(dataset)
        if env is None:
            env = load_manifest(dataset).get("config", {}).get("env")
        dataset = ClipDataset(dataset, split="valid", context=NUM_CONTEXT, future=NUM_FUTURE)
    model, identity = _build_model(model_spec, model_args, env, dataset, device)

    skipped: dict[str, str] = {}
    lpips = {}
    for net in dict.fromkeys(lpips_nets):
        metric = _load_metric(
            f"lpips_{net}", lambda net=net: LPIPS(net, weights_dir).to(device), require_all, skipped
        )
        if metric is not None:
            lpips[net] = metric
    fvd_model = None
    if fvd:
        fvd_model = fvd_metric or _load_metric(
            "fvd",
            lambda: FrechetVideoDistance(
                weights_dir=weights_dir, device=device, batch_size=batch_size
            ),
            require_all,
            skipped,
        )

    indices = select_clips(len(dataset), num_clips, seed)
    if fvd_model is not None and len(indices) < 2:
        raise ValueError(f"FVD needs at least 2 clips, the split has {len(indices)}")
    loader = DataLoader(Subset(dataset, indices), batch_size=batch_size, shuffle=False)
    noise = torch.Generator(device).manual_seed(seed)

    names = list(_PER_FRAME) + [f"lpips_{net}" for net in lpips]
    sums = {name: torch.zeros(model.num_future, dtype=torch.float64) for name in names}
    features: dict[str, list[np.ndarray]] = {"pred": [], "true": []}
    seconds = dict.fromkeys(["predict", "image", *[f"lpips_{n}" for n in lpips], "fvd"], 0.0)
    bar = tqdm(total=len(indices), unit="clip", desc="vp2 metrics", disable=not progress)
    for batch in loader:
        frames = batch["frames"].to(device)  # (B, C + T, 3, H, W)
        actions = batch["actions"].to(device).float()  # (B, C + T - 1, A)
        context, true = frames[:, : model.num_context], frames[:, model.num_context :]
        t0 = time.perf_counter()
        pred = predict_in_chunks(model, context, actions, generator=noise, grad=False)
        pred = pred.to(device)  # (B, T, 3, H, W), frames C .. C + T - 1 as `true`
        t1 = time.perf_counter()
        seconds["predict"] += t1 - t0
        with torch.no_grad():
            sums["mse"] += mse(pred, true).sum(0).double().cpu()
            sums["psnr"] += psnr(pred, true).clamp(max=PSNR_CAP).sum(0).double().cpu()
            sums["ssim"] += ssim(pred, true).sum(0).double().cpu()
            seconds["image"] += time.perf_counter() - t1
            for net, metric in lpips.items():
                t = time.perf_counter()
                sums[f"lpips_{net}"] += metric(pred, true).sum(0).double().cpu()
                seconds[f"lpips_{net}"] += time.perf_counter() - t
        if fvd_model is not None:
            t = time.perf_counter()
            features["pred"].append(fvd_model.features(pred))
            features["true"].append(fvd_model.features(true))
            seconds["fvd"] += time.perf_counter() - t
        bar.update(len(frames))
    bar.close()
    if dataset_path is not None:
        dataset.close()  # opened here: release its HDF5 handles

    n = len(indices)
    per_step = {name: (s / n).tolist() for name, s in sums.items()}
    metrics: dict[str, float] = {name: float(np.mean(v)) for name, v in per_step.items()}
    if fvd_model is not None:
        metrics["fvd"] = fvd_from_features(
            np.concatenate(features["pred"]), np.concatenate(features["true"])
        )
    else:
        seconds.pop("fvd")
    display = {k: v for k, v in metrics.items() if k in ("mse", "psnr", "fvd")}
    display.update({f"{k}_x100": 100 * v for k, v in metrics.items() if k == "ssim"})
    display.update({f"{k}_x100": 100 * v for k, v in metrics.items() if k.startswith("lpips")})
    seconds["total"] = time.perf_counter() - started
    return {
        "metrics": metrics,
        "display": display,
        "per_step": per_step,
        "skipped": skipped,
        "num_clips": n,
        "num_clips_requested": num_clips,
        "seed": seed,
        "split": "valid",
        "context": model.num_context,
        "future": model.num_future,
        "clip_indices": indices,
        "model": identity,
        "env": env,
        "dataset": dataset_path,
        "settings": {
            "psnr_cap_db": PSNR_CAP,
            "lpips_nets": list(lpips_nets),
            "fvd": fvd,
            "fvd_features": "I3D Kinetics-400 logits, 224x224 bilinear, [-1, 1]",
            "batch_size": batch_size,
            "device": str(device),
        },
        "seconds": seconds,
    }


def write_metrics(out: str | os.PathLike[str], result: Mapping[str, Any]) -> Path:
    """Writes ``result`` as JSON, atomically, to ``out`` (a ``.json`` file) or to
    ``out/metrics.json`` (a directory); returns the file."""
    path = Path(out)
    if path.suffix != ".json":
        path = path / METRICS_FILE
    write_json_atomic(path, dict(result))
    return path


# --------------------------------------------------------------------------- vp2 metrics


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
        help="model spec: repeat_last_frame | simulator | NAME:CHECKPOINT | "
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
    p.add_argument("--batch-size", type=int, default=16, help="clips per batch")
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
    from vp2.benchmark.runner import parse_model_args
    from vp2.training.command import default_dataset

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
        model_args=parse_model_args(args.model_arg),
        env=env,
        weights_dir=args.weights_dir,
        require_all=args.require_all,
    )
    out = write_metrics(args.out or default_out(args.model, env), result)
    print(format_table(result))
    for name, why in result["skipped"].items():
        print(f"skipped {name}: {why}", file=sys.stderr)
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


__all__ = [
    "DEFAULT_NUM_CLIPS",
    "METRICS_FILE",
    "PSNR_CAP",
    "configure_parser",
    "default_out",
    "evaluate_model",
    "format_table",
    "model_slug",
    "run_from_args",
    "select_clips",
    "write_metrics",
]
