"""Setting up a training run: datasets, model, optimiser, resume state, run directory.

:func:`start_run` turns a :class:`TrainConfig` into a :class:`TrainingRun`, the live state
that :func:`vp2.training.train` advances step by step; :meth:`TrainingRun.save_checkpoint`
writes that state back, and a resumed run reads it in :func:`start_run`. The order of the
set-up steps is part of the behaviour: building LPIPS and iterating data loaders draw from
torch's global generator, whose state every checkpoint records.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from pathlib import Path
from typing import Any

import torch

from vp2.data.loader import ClipDataset
from vp2.data.storage import DatasetError, load_manifest
from vp2.models.base import VideoPredictor
from vp2.models.checkpoint import read_model_checkpoint, write_model_checkpoint
from vp2.models.layers import PerceptualLoss
from vp2.models.registry import make_config, model_from_config
from vp2.training.batches import child_seed, seed_torch, validation_batches
from vp2.training.checkpoint import (
    checkpoint_path,
    list_checkpoints,
    prune_checkpoints,
    restore_rng_state,
    run_payload,
)
from vp2.training.config import TrainConfig, check_resumable
from vp2.training.logger import MetricsLogger
from vp2.training.perceptual import resolve_perceptual
from vp2.utils.io import write_json_atomic
from vp2.utils.tensors import resolve_device

log = logging.getLogger(__name__)


@dataclasses.dataclass
class TrainingRun:
    """A training run's live state, built by :func:`start_run`.

    Attributes:
        config: The run's configuration.
        out_dir: Its run directory.
        device: Where the model trains.
        amp_dtype: The mixed-precision dtype (bf16 if supported, else fp16), or ``None``
            without mixed precision.
        train_set: The training clips (uint8 frames).
        model: The model, on ``device``.
        optimizer, scaler: Its optimiser and gradient scaler (enabled for fp16 only).
        noise: The generator of the model's sampling noise during training.
        grad_clip: Max global gradient norm, or ``None``.
        perceptual: The perceptual loss term, or ``None``.
        dataset_info: Where the data came from (recorded in ``config.json`` and checkpoints).
        logger: The run's metrics log.
        valid_batches: Fixed validation batches (empty without a ``valid`` split).
        last_checkpoint: The newest checkpoint written (or resumed from).
        start: Steps already done (non-zero when resuming).
        valid_metrics: The latest validation metrics.
        train_seconds: Training wall time so far, earlier sessions included (restored from
            the checkpoint; the trainer advances it, ``config.max_minutes`` bounds it).
        run_record: What ``config.json`` holds (:meth:`record_finish` adds the outcome).
    """

    config: TrainConfig
    out_dir: Path
    device: torch.device
    amp_dtype: torch.dtype | None
    train_set: ClipDataset
    model: VideoPredictor
    optimizer: torch.optim.Optimizer
    scaler: torch.amp.GradScaler
    noise: torch.Generator
    grad_clip: float | None
    perceptual: PerceptualLoss | None
    dataset_info: dict[str, Any]
    logger: MetricsLogger
    valid_batches: list[dict[str, Any]]
    last_checkpoint: Path | None = None
    start: int = 0
    valid_metrics: dict[str, float] = dataclasses.field(default_factory=dict)
    train_seconds: float = 0.0
    run_record: dict[str, Any] = dataclasses.field(default_factory=dict)

    def autocast(self) -> contextlib.AbstractContextManager:
        """Mixed precision on CUDA only; fp16 needs the GradScaler, bf16 does not."""
        if self.amp_dtype is None:
            return contextlib.nullcontext()
        return torch.autocast("cuda", dtype=self.amp_dtype)

    def save_checkpoint(self, step: int) -> Path:
        """Writes the checkpoint of ``step`` (everything a resumed run needs), prunes old ones
        and returns its path."""
        path = write_model_checkpoint(
            checkpoint_path(self.out_dir, step),
            run_payload(
                self.model,
                step=step,
                optimizer=self.optimizer,
                scaler=self.scaler,
                noise=self.noise,
                train_config=self.config.to_dict(),
                dataset=self.dataset_info,
                metrics=self.valid_metrics,
                train_seconds=self.train_seconds,
            ),
        )
        prune_checkpoints(self.out_dir, self.config.keep_checkpoints)
        return path

    def record_finish(self, step: int, budget_reached: bool) -> None:
        """Adds how the run ended to ``config.json`` (called by the trainer at its end): the
        steps done, the training minutes of all sessions and what stopped it."""
        self.run_record["finished"] = {
            "step": step,
            "train_minutes": self.train_seconds / 60,
            "stopped_by": "max_minutes" if budget_reached else "steps",
        }
        write_json_atomic(self.out_dir / "config.json", self.run_record)


def start_run(config: TrainConfig, perceptual_fn: PerceptualLoss | None = None) -> TrainingRun:
    """Sets up (or resumes) the run ``config`` describes and writes its ``config.json``.

    Raises:
        FileExistsError: ``out_dir`` has checkpoints and ``resume`` is off.
        ValueError: on a bad configuration, or a resume whose configuration changed.
    """
    out_dir = Path(config.out_dir)
    device = resolve_device(config.device)
    use_amp = device.type == "cuda" if config.amp is None else config.amp and device.type == "cuda"
    amp_dtype = torch.bfloat16 if use_amp and torch.cuda.is_bf16_supported() else torch.float16
    resumed_from, resume_payload = _resume_payload(config, out_dir)

    seed_torch(config.seed)
    train_set, valid_set = _open_datasets(config)
    model = _build_model(config, train_set).to(device)
    optimizer = _make_optimizer(model, config)
    scaler = torch.amp.GradScaler("cuda", enabled=use_amp and amp_dtype == torch.float16)
    noise = torch.Generator(device).manual_seed(child_seed(config.seed, 3))
    clip = model.training_defaults.grad_clip if config.grad_clip is None else config.grad_clip
    perceptual = resolve_perceptual(
        config.perceptual, config.perceptual_weight, perceptual_fn, device
    )
    start, valid_metrics, train_seconds = 0, {}, 0.0
    if resume_payload is not None:
        start, valid_metrics, train_seconds = _restore(
            resume_payload, model, optimizer, scaler, noise
        )
        if start > config.steps:
            raise ValueError(
                f"cannot resume {out_dir} at step {start} with steps={config.steps}: the run is "
                "already past it"
            )
        log.info("resuming %s from step %d", out_dir, start)

    dataset_info = _dataset_info(config, train_set)
    run_record = {
        "train": config.to_dict(),
        "model": {"name": model.name, "config": model.config_dict()},
        "parameters": model.num_parameters(),
        "dataset": dataset_info,
        "device": str(device),
        "amp": str(amp_dtype) if use_amp else None,
    }
    write_json_atomic(out_dir / "config.json", run_record)
    logger = MetricsLogger(
        out_dir, resume_step=start if resume_payload else None, tensorboard=config.tensorboard
    )
    return TrainingRun(
        config=config,
        out_dir=out_dir,
        device=device,
        amp_dtype=amp_dtype if use_amp else None,
        train_set=train_set,
        model=model,
        optimizer=optimizer,
        scaler=scaler,
        noise=noise,
        grad_clip=clip if clip is not None and clip > 0 else None,
        perceptual=perceptual,
        dataset_info=dataset_info,
        logger=logger,
        # Drawn last: iterating a DataLoader advances torch's global generator.
        valid_batches=(
            validation_batches(valid_set, config.eval_batches, config.batch_size)
            if valid_set
            else []
        ),
        last_checkpoint=resumed_from,
        start=start,
        valid_metrics=valid_metrics,
        train_seconds=train_seconds,
        run_record=run_record,
    )


def _resume_payload(config: TrainConfig, out_dir: Path) -> tuple[Path | None, dict | None]:
    """The checkpoint a run resumes from and its contents (``None, None``: a fresh run)."""
    existing = list_checkpoints(out_dir)
    if existing and not config.resume:
        raise FileExistsError(
            f"{out_dir} already has checkpoints ({existing[-1].name}); pass resume=True to "
            "continue that run, or choose another out_dir"
        )
    if not (config.resume and existing):
        return None, None
    payload = read_model_checkpoint(existing[-1])
    check_resumable(config, payload["train_config"], existing[-1])
    return existing[-1], payload


def _restore(
    payload: dict[str, Any],
    model: VideoPredictor,
    optimizer: torch.optim.Optimizer,
    scaler: torch.amp.GradScaler,
    noise: torch.Generator,
) -> tuple[int, dict[str, float], float]:
    """Loads a checkpoint's states into a freshly built run; returns its step, its latest
    validation metrics and its training seconds (0 for checkpoints older than the budget)."""
    model.load_state_dict(payload["model"]["state_dict"])
    optimizer.load_state_dict(payload["optimizer"])
    if payload.get("scaler"):
        scaler.load_state_dict(payload["scaler"])
    restore_rng_state(payload["rng"], noise)
    return (
        int(payload["step"]),
        dict(payload.get("metrics", {})),
        float(payload.get("train_seconds", 0.0)),
    )


def _open_datasets(config: TrainConfig) -> tuple[ClipDataset, ClipDataset | None]:
    """The ``train`` and (if the dataset has one) ``valid`` splits, as uint8 clips."""
    train_set = ClipDataset(
        config.dataset,
        "train",
        tasks=config.tasks,
        max_trajectories=config.max_trajectories,
        uint8=True,
    )
    try:
        valid_set: ClipDataset | None = ClipDataset(
            config.dataset,
            "valid",
            tasks=config.tasks,
            max_trajectories=config.max_trajectories,
            uint8=True,
        )
    except DatasetError as exc:
        log.warning("no validation clips (%s); validation is skipped", exc)
        valid_set = None
    return train_set, valid_set


def _build_model(config: TrainConfig, train_set: ClipDataset) -> VideoPredictor:
    """The model to train, sized for the dataset (``action_dim``, ``image_size``)."""
    channels, height, width = train_set.image_shape[2], *train_set.image_shape[:2]
    if channels != 3 or height != width:
        raise ValueError(
            f"{config.dataset}: expected square RGB frames, got {train_set.image_shape}"
        )
    for key, value in (("action_dim", train_set.action_dim), ("image_size", height)):
        if key in config.model_overrides and int(config.model_overrides[key]) != value:
            raise ValueError(
                f"model override {key}={config.model_overrides[key]} disagrees with "
                f"the dataset ({value})"
            )
    model_config = make_config(
        config.model,
        config.preset,
        **{**config.model_overrides, "action_dim": train_set.action_dim, "image_size": height},
    )
    if train_set.clip_length != model_config.num_context + model_config.num_future:
        raise ValueError("dataset clips and model context/future lengths disagree")
    return model_from_config(config.model, model_config, seed=child_seed(config.seed, 0))


def _make_optimizer(model: VideoPredictor, config: TrainConfig) -> torch.optim.Optimizer:
    d = model.training_defaults
    name = (config.optimizer or d.optimizer).lower()
    lr = d.lr if config.lr is None else config.lr
    wd = d.weight_decay if config.weight_decay is None else config.weight_decay
    kwargs = {"lr": lr, "betas": d.betas, "eps": d.eps, "weight_decay": wd}
    if name == "adam":
        return torch.optim.Adam(model.parameters(), **kwargs)
    if name == "adamw":
        return torch.optim.AdamW(model.parameters(), **kwargs)
    raise ValueError(f"optimizer must be 'adam' or 'adamw', got {name!r}")


def _dataset_info(config: TrainConfig, train_set: ClipDataset) -> dict[str, Any]:
    manifest = load_manifest(config.dataset)
    return {
        "path": str(Path(config.dataset).resolve()),
        "config": manifest.get("config", {}),
        "action_dim": train_set.action_dim,
        "image_shape": list(train_set.image_shape),
        "train_clips": len(train_set),
    }
