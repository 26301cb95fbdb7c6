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

import logging
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Subset
from tqdm.auto import tqdm

from vp2.data.loader import ClipDataset, select_clips
from vp2.data.storage import load_manifest
from vp2.metrics.fvd import FrechetVideoDistance, fvd_from_features
from vp2.metrics.image import mse, psnr, ssim
from vp2.models.contract import checked, predict_in_chunks
from vp2.spec import NUM_CONTEXT, NUM_FUTURE
from vp2.training.perceptual import BACKBONES, LPIPS, MissingWeightsError
from vp2.utils.io import write_json_atomic
from vp2.utils.tensors import resolve_device

log = logging.getLogger(__name__)

#: Clips evaluated by default (as the paper's FVD).
DEFAULT_NUM_CLIPS = 1000
#: Clips per prediction, metric and I3D batch by default.
DEFAULT_BATCH_SIZE = 16
#: Per-frame PSNR is capped here (an MSE of 1e-10): identical frames would give ``inf``.
PSNR_CAP = 100.0
#: The file :func:`write_metrics` writes inside a directory.
METRICS_FILE = "metrics.json"

_PER_FRAME = ("mse", "psnr", "ssim")


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
        from vp2.run.model_spec import model_identity, resolve_model

        model = resolve_model(
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
    if model.action_dim != dataset.action_dim:
        raise ValueError(
            f"model {identity['name']} takes {model.action_dim}-D actions but the dataset's are "
            f"{dataset.action_dim}-D; evaluate it on a dataset of the environment it was "
            "trained for (a checkpoint's card or config names it)"
        )
    if (model.num_context, model.num_future) != (dataset.context, dataset.future):
        raise ValueError(
            f"model {identity['name']} uses {model.num_context} context + {model.num_future} "
            f"future frames, the clips {dataset.context} + {dataset.future}"
        )
    return model, identity


def evaluate_model(
    model_spec: Any,
    dataset: ClipDataset | str | os.PathLike[str],
    num_clips: int = DEFAULT_NUM_CLIPS,
    seed: int = 0,
    batch_size: int = DEFAULT_BATCH_SIZE,
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
    device = resolve_device(device)
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

    lpips, fvd_model, skipped = _load_metrics(
        lpips_nets, fvd, fvd_metric, weights_dir, device, batch_size, require_all
    )
    indices = select_clips(len(dataset), num_clips, seed)
    if fvd_model is not None and len(indices) < 2:
        raise ValueError(f"FVD needs at least 2 clips, the split has {len(indices)}")
    loader = DataLoader(Subset(dataset, indices), batch_size=batch_size, shuffle=False)
    noise = torch.Generator(device).manual_seed(seed)
    bar = tqdm(total=len(indices), unit="clip", desc="vp2 metrics", disable=not progress)
    sums, features, seconds = _score(model, loader, noise, device, lpips, fvd_model, bar)
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


def _load_metrics(
    lpips_nets: Sequence[str],
    fvd: bool,
    fvd_metric: FrechetVideoDistance | None,
    weights_dir: str | os.PathLike[str] | None,
    device: torch.device,
    batch_size: int,
    require_all: bool,
) -> tuple[dict[str, LPIPS], FrechetVideoDistance | None, dict[str, str]]:
    """The LPIPS networks and the FVD metric whose weights are on disk, and why the others
    are skipped (metric name -> message)."""
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
    return lpips, fvd_model, skipped


def _score(
    model: Any,
    loader: DataLoader,
    noise: torch.Generator,
    device: torch.device,
    lpips: dict[str, LPIPS],
    fvd_model: FrechetVideoDistance | None,
    bar: tqdm,
) -> tuple[dict[str, torch.Tensor], dict[str, list[np.ndarray]], dict[str, float]]:
    """Predicts every clip of ``loader`` and scores it: the per-frame metric sums over clips
    (name -> ``(T,)`` float64), the I3D features of predicted and true videos, and the seconds
    spent per metric."""
    names = list(_PER_FRAME) + [f"lpips_{net}" for net in lpips]
    sums = {name: torch.zeros(model.num_future, dtype=torch.float64) for name in names}
    features: dict[str, list[np.ndarray]] = {"pred": [], "true": []}
    seconds = dict.fromkeys(["predict", "image", *[f"lpips_{n}" for n in lpips], "fvd"], 0.0)
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
            features["true"].append(fvd_model.reference_features(true))
            seconds["fvd"] += time.perf_counter() - t
        bar.update(len(frames))
    return sums, features, seconds


def write_metrics(out: str | os.PathLike[str], result: Mapping[str, Any]) -> Path:
    """Writes ``result`` as JSON, atomically, to ``out`` (a ``.json`` file) or to
    ``out/metrics.json`` (a directory); returns the file."""
    path = Path(out)
    if path.suffix != ".json":
        path = path / METRICS_FILE
    write_json_atomic(path, dict(result))
    return path


# --------------------------------------------------------------------------- vp2 metrics


__all__ = [
    "DEFAULT_NUM_CLIPS",
    "METRICS_FILE",
    "PSNR_CAP",
    "evaluate_model",
    "write_metrics",
]
