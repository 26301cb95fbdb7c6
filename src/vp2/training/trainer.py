"""Training a registered video prediction model on a vp2 dataset.

::

    from vp2.training import TrainConfig, train
    result = train(TrainConfig(model="fitvid", preset="mini", dataset="data/tabletop",
                               out_dir="runs/fitvid-mini", steps=10_000))
    model = load_model(result.checkpoint)        # vp2.models.load_model

A run directory holds ``config.json`` (the resolved configuration), ``metrics.csv`` (and
``tb/`` if TensorBoard is installed), ``samples/step_*.png`` (true vs predicted frames of
validation clips) and ``checkpoints/step_*.pt``. ``resume=True`` continues an interrupted run
from its newest checkpoint; on the same device the result is bit-identical to an
uninterrupted run, because every source of randomness is either restored from the checkpoint
(the posterior-noise generator) or a pure function of ``(seed, step)`` (the data order).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Sampler
from tqdm.auto import tqdm

from vp2.data.loader import ClipDataset
from vp2.data.storage import DatasetError, load_manifest
from vp2.models.base import PerceptualLoss, VideoPredictor
from vp2.models.registry import make_config, model_from_config, read_checkpoint
from vp2.training.checkpoint import (
    checkpoint_path,
    list_checkpoints,
    prune_checkpoints,
    restore_rng_state,
    rng_state,
    save_checkpoint,
)
from vp2.training.logger import MetricsLogger, prediction_grid, save_png
from vp2.utils.io import write_json_atomic

log = logging.getLogger(__name__)


def _lpips_factory(net: str) -> Callable[[torch.device], PerceptualLoss]:
    def factory(device: torch.device) -> PerceptualLoss:
        # Imported when used: the metrics stage sits downstream of training, and LPIPS is
        # the one piece of it training shares (frozen weights from local files).
        from vp2.metrics.lpips import lpips_loss

        return lpips_loss(net, device)

    return factory


#: Perceptual losses selectable by name in :class:`TrainConfig` (``perceptual="lpips_vgg"``):
#: name -> factory ``(device) -> PerceptualLoss``. ``lpips`` (AlexNet) and ``lpips_vgg`` are
#: :class:`vp2.metrics.LPIPS`; their weights must be on disk (docs/metrics.md).
PERCEPTUAL_LOSSES: dict[str, Callable[[torch.device], PerceptualLoss]] = {
    "lpips": _lpips_factory("alex"),
    "lpips_vgg": _lpips_factory("vgg"),
}

# Fields that may change when resuming: how long and how the run is observed, not what it
# computes.
_RESUMABLE_CHANGES = frozenset(
    {
        "steps",
        "resume",
        "workers",
        "progress",
        "eval_interval",
        "eval_batches",
        "ckpt_interval",
        "keep_checkpoints",
        "log_interval",
        "tensorboard",
        "out_dir",
    }
)


@dataclasses.dataclass
class TrainConfig:
    """Everything that determines a training run.

    Attributes:
        model: Registered model name (``"svg_prime"``, ``"fitvid"``).
        dataset: Dataset directory (from ``vp2 collect``); trained on its ``train`` split,
            validated on its ``valid`` split.
        out_dir: Run directory (created).
        preset: Model size preset (``None``: the model's default); see
            :func:`vp2.models.preset_names`.
        model_overrides: Config field overrides, e.g. ``{"beta": 1e-3}``; strings are
            converted to the field's type (command-line ``key=value``). ``action_dim`` and
            ``image_size`` come from the dataset.
        tasks: Train on these data streams only (``None``: all).
        max_trajectories: Use only the dataset's first N trajectories (data-quantity studies).
        steps: Total optimisation steps (the paper: 153 K).
        batch_size: Clips per step (the paper: 32).
        lr: Learning rate (``None``: the model's default, 3e-4 for both).
        optimizer: ``"adam"`` or ``"adamw"`` (``None``: the model's default, Adam).
        weight_decay: Weight decay (``None``: the model's default, 0).
        grad_clip: Max global gradient norm; ``None``: the model's default (FitVid 100, SVG′
            none); ``<= 0``: off.
        seed: Seeds weights, data order and sampling noise.
        perceptual: Name of an extra perceptual loss in :data:`PERCEPTUAL_LOSSES` (or pass a
            callable to :func:`train`).
        perceptual_weight: Its weight (the paper: 1 and 10 with LPIPS).
        eval_interval: Steps between validations (and prediction grids); 0 = only at the end.
        eval_batches: Validation batches per validation.
        ckpt_interval: Steps between checkpoints; one is always written at the end.
        keep_checkpoints: Newest checkpoints kept on disk.
        log_interval: Steps between training-loss log rows.
        workers: DataLoader worker processes (0 = load in the training process).
        device: ``"cuda"``, ``"cpu"``, ...; ``None``: CUDA if available.
        amp: Mixed precision (bf16 if supported, else fp16 with gradient scaling); ``None``:
            on for CUDA, off otherwise.
        tensorboard: Also log to TensorBoard when it is installed.
        progress: Show a progress bar (steps/s, ETA).
        resume: Continue from the newest checkpoint in ``out_dir`` (its configuration must
            match, except ``steps`` and logging settings). Without it, a run directory that
            already has checkpoints is refused.
    """

    model: str
    dataset: str
    out_dir: str
    preset: str | None = None
    model_overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    tasks: list[str] | None = None
    max_trajectories: int | None = None
    steps: int = 100_000
    batch_size: int = 32
    lr: float | None = None
    optimizer: str | None = None
    weight_decay: float | None = None
    grad_clip: float | None = None
    seed: int = 0
    perceptual: str | None = None
    perceptual_weight: float = 0.0
    eval_interval: int = 2_000
    eval_batches: int = 4
    ckpt_interval: int = 5_000
    keep_checkpoints: int = 2
    log_interval: int = 50
    workers: int = 2
    device: str | None = None
    amp: bool | None = None
    tensorboard: bool = True
    progress: bool = True
    resume: bool = False

    def __post_init__(self) -> None:
        self.dataset, self.out_dir = str(self.dataset), str(self.out_dir)
        self.tasks = list(self.tasks) if self.tasks is not None else None
        self.model_overrides = dict(self.model_overrides)
        for name in ("steps", "batch_size", "eval_batches", "keep_checkpoints", "log_interval"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.eval_interval < 0 or self.ckpt_interval < 0 or self.workers < 0:
            raise ValueError("eval_interval, ckpt_interval and workers must be >= 0")
        if self.perceptual_weight < 0:
            raise ValueError(f"perceptual_weight must be >= 0, got {self.perceptual_weight}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


@dataclasses.dataclass
class TrainResult:
    """What :func:`train` returns."""

    out_dir: Path
    checkpoint: Path  # the final checkpoint
    step: int
    train_metrics: dict[str, float]  # of the last step
    valid_metrics: dict[str, float]  # of the last validation (empty without a valid split)


def seed_torch(seed: int) -> None:
    """Seeds torch's global generators (CPU and every CUDA device).

    vp2 code never draws from them (weights are initialised in a forked RNG, noise comes from
    explicit generators); this covers third-party operations that do. Called by :func:`train`.
    """
    torch.manual_seed(seed)


def _child_seed(seed: int, *keys: int) -> int:
    # 63 bits: torch.Generator.manual_seed takes any int, but keep it a positive int64.
    return int(np.random.SeedSequence([seed, *keys]).generate_state(1, np.uint64)[0]) >> 1


class StepBatchSampler(Sampler[list[int]]):
    """Batch indices for steps ``start .. stop - 1``, a pure function of ``(seed, step)``.

    Each epoch is a fresh permutation (seeded by ``seed`` and the epoch number) cut into
    ``len(dataset) // batch_size`` full batches, so a resumed run draws exactly the batches the
    uninterrupted run would have, without saving any sampler state.
    """

    def __init__(self, num_items: int, batch_size: int, seed: int, start: int, stop: int):
        if num_items < batch_size:
            raise ValueError(f"dataset has {num_items} clips, fewer than batch_size={batch_size}")
        self.num_items, self.batch_size, self.seed = num_items, batch_size, seed
        self.start, self.stop = start, stop
        self.per_epoch = num_items // batch_size

    def __len__(self) -> int:
        return max(0, self.stop - self.start)

    def __iter__(self) -> Iterator[list[int]]:
        epoch, perm = -1, None
        for step in range(self.start, self.stop):
            e, i = divmod(step, self.per_epoch)
            if e != epoch:
                g = torch.Generator().manual_seed(_child_seed(self.seed, 1, e))
                epoch, perm = e, torch.randperm(self.num_items, generator=g)
            yield perm[i * self.batch_size : (i + 1) * self.batch_size].tolist()


def _frames_to_float(frames: torch.Tensor) -> torch.Tensor:
    # Clips travel as uint8 (4x less to copy) and become [0, 1] floats on the device. Made
    # contiguous because ClipDataset's frames are a permuted (channels-last) view when loaded
    # in-process but contiguous when they come from a worker, and convolutions pick different
    # kernels (different rounding) for the two layouts: results must not depend on `workers`.
    frames = frames.contiguous()
    return frames.float().div_(255.0) if frames.dtype == torch.uint8 else frames.float()


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


def _grad_clip(model: VideoPredictor, config: TrainConfig) -> float | None:
    clip = model.training_defaults.grad_clip if config.grad_clip is None else config.grad_clip
    return clip if clip is not None and clip > 0 else None


def _resolve_perceptual(
    config: TrainConfig, perceptual_fn: PerceptualLoss | None, device: torch.device
) -> PerceptualLoss | None:
    if config.perceptual_weight == 0:
        return None
    if perceptual_fn is not None:
        return perceptual_fn
    if config.perceptual is None:
        raise ValueError(
            "perceptual_weight > 0 needs a perceptual loss: set `perceptual` to a "
            f"name in {sorted(PERCEPTUAL_LOSSES)} or pass perceptual_fn to train()"
        )
    if config.perceptual not in PERCEPTUAL_LOSSES:
        raise ValueError(
            f"unknown perceptual loss {config.perceptual!r}; "
            f"known: {sorted(PERCEPTUAL_LOSSES) or 'none registered'}"
        )
    return PERCEPTUAL_LOSSES[config.perceptual](device)


def _check_resume(config: TrainConfig, saved: dict[str, Any], where: Path) -> None:
    current = config.to_dict()
    diffs = {
        k: (saved.get(k), v)
        for k, v in current.items()
        if k not in _RESUMABLE_CHANGES and saved.get(k) != v
    }
    if diffs:
        detail = ", ".join(f"{k}: checkpoint {a!r} vs now {b!r}" for k, (a, b) in diffs.items())
        raise ValueError(f"cannot resume from {where}: the configuration changed ({detail})")


@torch.no_grad()
def validate(
    model: VideoPredictor,
    batches: list[dict[str, torch.Tensor]],
    device: torch.device,
    seed: int,
    perceptual: PerceptualLoss | None = None,
    perceptual_weight: float = 0.0,
) -> tuple[dict[str, float], tuple[torch.Tensor, torch.Tensor] | None]:
    """Validation metrics on fixed batches, with fixed noise (comparable across steps).

    Returns ``({"valid/loss", "valid/mse", "valid/kl", "valid/pred_mse"}, (true, predicted)
    frames of the first batch)``. ``valid/mse`` is teacher-forced reconstruction;
    ``valid/pred_mse`` is the benchmark's setting: 10 frames rolled out from 2 with
    ``predict`` (prior samples).
    """
    was_training = model.training
    model.eval()
    sums: dict[str, float] = {}
    first = None
    try:
        for i, batch in enumerate(batches):
            frames = _frames_to_float(batch["frames"].to(device))  # (B, T, 3, H, W)
            actions = batch["actions"].to(device).float()  # (B, T - 1, A)
            gen = torch.Generator(device).manual_seed(_child_seed(seed, 2, i))
            out = model.compute_loss(frames, actions, gen, perceptual, perceptual_weight)
            c = model.num_context
            pred = model.predict(frames[:, :c], actions.clamp(-1, 1), generator=gen)
            metrics = {f"valid/{k}": float(v) for k, v in out.metrics.items()}
            metrics["valid/loss"] = float(out.loss)
            metrics["valid/pred_mse"] = float(((pred - frames[:, c:]) ** 2).mean())
            for k, v in metrics.items():
                sums[k] = sums.get(k, 0.0) + v
            if first is None:
                first = (frames[:4].cpu(), pred[:4].cpu())
    finally:
        model.train(was_training)
    return {k: v / max(1, len(batches)) for k, v in sums.items()}, first


def _validation_batches(dataset: ClipDataset, count: int, batch_size: int) -> list[dict[str, Any]]:
    """``count`` batches of clips spread evenly over the validation set (fixed across steps)."""
    n = min(len(dataset), count * batch_size)
    idx = np.linspace(0, len(dataset) - 1, n).round().astype(int)
    loader = DataLoader(torch.utils.data.Subset(dataset, idx.tolist()), batch_size=batch_size)
    return list(loader)


def train(config: TrainConfig, perceptual_fn: PerceptualLoss | None = None) -> TrainResult:
    """Trains (or resumes training) a model; see the module docstring.

    Args:
        config: The run.
        perceptual_fn: A perceptual loss ``(pred (N, 3, H, W), target) -> (N,)`` used with
            ``config.perceptual_weight`` (overrides ``config.perceptual``).

    Returns:
        Where the run and its final checkpoint are, and the last metrics.

    Raises:
        FileExistsError: ``out_dir`` has checkpoints and ``resume`` is off.
        ValueError: on a bad configuration, or a resume whose configuration changed.
        FloatingPointError: if the loss becomes NaN/inf (the message names the step and the
            newest checkpoint to resume from with a lower learning rate).
    """
    out_dir = Path(config.out_dir)
    device = torch.device(config.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    use_amp = device.type == "cuda" if config.amp is None else config.amp and device.type == "cuda"
    amp_dtype = torch.bfloat16 if use_amp and torch.cuda.is_bf16_supported() else torch.float16

    def autocast() -> contextlib.AbstractContextManager:
        # Mixed precision on CUDA only; fp16 needs the GradScaler below, bf16 does not.
        return torch.autocast("cuda", dtype=amp_dtype) if use_amp else contextlib.nullcontext()

    existing = list_checkpoints(out_dir)
    if existing and not config.resume:
        raise FileExistsError(
            f"{out_dir} already has checkpoints ({existing[-1].name}); pass resume=True to "
            "continue that run, or choose another out_dir"
        )
    resume_payload = read_checkpoint(existing[-1]) if (config.resume and existing) else None
    if resume_payload is not None:
        _check_resume(config, resume_payload["train_config"], existing[-1])

    seed_torch(config.seed)
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

    model = model_from_config(config.model, model_config, seed=_child_seed(config.seed, 0)).to(
        device
    )
    optimizer = _make_optimizer(model, config)
    scaler = torch.amp.GradScaler("cuda", enabled=use_amp and amp_dtype == torch.float16)
    noise = torch.Generator(device).manual_seed(_child_seed(config.seed, 3))
    clip = _grad_clip(model, config)
    perceptual = _resolve_perceptual(config, perceptual_fn, device)
    start = 0
    valid_metrics: dict[str, float] = {}
    if resume_payload is not None:
        model.load_state_dict(resume_payload["model"]["state_dict"])
        optimizer.load_state_dict(resume_payload["optimizer"])
        if resume_payload.get("scaler"):
            scaler.load_state_dict(resume_payload["scaler"])
        restore_rng_state(resume_payload["rng"], noise)
        start = int(resume_payload["step"])
        if start > config.steps:
            raise ValueError(
                f"cannot resume {out_dir} at step {start} with steps={config.steps}: the run is "
                "already past it"
            )
        valid_metrics = dict(resume_payload.get("metrics", {}))
        log.info("resuming %s from step %d", out_dir, start)

    manifest = load_manifest(config.dataset)
    dataset_info = {
        "path": str(Path(config.dataset).resolve()),
        "config": manifest.get("config", {}),
        "action_dim": train_set.action_dim,
        "image_shape": list(train_set.image_shape),
        "train_clips": len(train_set),
    }
    write_json_atomic(
        out_dir / "config.json",
        {
            "train": config.to_dict(),
            "model": {"name": model.name, "config": model.config_dict()},
            "parameters": model.num_parameters(),
            "dataset": dataset_info,
            "device": str(device),
            "amp": str(amp_dtype) if use_amp else None,
        },
    )
    logger = MetricsLogger(
        out_dir, resume_step=start if resume_payload else None, tensorboard=config.tensorboard
    )
    valid_batches = (
        _validation_batches(valid_set, config.eval_batches, config.batch_size) if valid_set else []
    )

    def make_checkpoint(step: int) -> Path:
        path = save_checkpoint(
            checkpoint_path(out_dir, step),
            {
                "model": {
                    "name": model.name,
                    "config": model.config_dict(),
                    "state_dict": model.state_dict(),
                },
                "step": step,
                "optimizer": optimizer.state_dict(),
                "scaler": scaler.state_dict() if scaler.is_enabled() else {},
                "rng": rng_state(noise),
                "train_config": config.to_dict(),
                "dataset": dataset_info,
                "metrics": valid_metrics,
            },
        )
        prune_checkpoints(out_dir, config.keep_checkpoints)
        return path

    def run_validation(step: int) -> None:
        nonlocal valid_metrics
        if not valid_batches:
            return
        valid_metrics, first = validate(
            model, valid_batches, device, config.seed, perceptual, config.perceptual_weight
        )
        logger.log(step, valid_metrics)
        if first is not None:
            grid = prediction_grid(*first)
            save_png(out_dir / "samples" / f"step_{step:08d}.png", grid)
            logger.log_image(step, "valid/predictions", grid)

    sampler = StepBatchSampler(
        len(train_set), config.batch_size, _child_seed(config.seed, 4), start, config.steps
    )
    loader = DataLoader(
        train_set,
        batch_sampler=sampler,
        num_workers=config.workers,
        pin_memory=device.type == "cuda",
    )
    train_metrics: dict[str, float] = {}
    last_checkpoint = existing[-1] if (resume_payload is not None and existing) else None
    model.train()
    bar = tqdm(
        total=config.steps,
        initial=start,
        unit="step",
        disable=not config.progress,
        desc=f"train {config.model}",
        dynamic_ncols=True,
    )
    tick, tick_step = time.perf_counter(), start
    try:
        step = start
        for batch in loader:
            frames = _frames_to_float(batch["frames"].to(device, non_blocking=True))
            actions = batch["actions"].to(device, non_blocking=True).float()
            with autocast():
                out = model.compute_loss(
                    frames, actions, noise, perceptual, config.perceptual_weight
                )
            scaler.scale(out.loss).backward()
            grad_norm = None
            if clip is not None:
                scaler.unscale_(optimizer)
                grad_norm = torch.nn.utils.clip_grad_norm_(model.parameters(), clip)
            scaler.step(optimizer)
            scaler.update()
            optimizer.zero_grad(set_to_none=True)
            step += 1
            bar.update(1)

            checkpoint_due = (
                config.ckpt_interval and step % config.ckpt_interval == 0
            ) or step == config.steps
            if step % config.log_interval == 0 or checkpoint_due:
                # Checked here rather than every step: reading the loss synchronises with the
                # GPU. A NaN makes every later loss NaN, so it is caught before any checkpoint.
                loss_value = float(out.loss.detach())
                if not math.isfinite(loss_value):
                    raise FloatingPointError(
                        f"loss is {loss_value} by step {step}; resume from "
                        f"{last_checkpoint or 'scratch'} with a lower lr (or amp=False)"
                    )
            if step % config.log_interval == 0 or step == config.steps:
                now = time.perf_counter()
                train_metrics = {
                    "train/loss": float(out.loss.detach()),
                    **{f"train/{k}": float(v) for k, v in out.metrics.items()},
                }
                if grad_norm is not None:
                    train_metrics["train/grad_norm"] = float(grad_norm)
                train_metrics["train/steps_per_s"] = (step - tick_step) / max(now - tick, 1e-9)
                tick, tick_step = now, step
                logger.log(step, train_metrics)
                bar.set_postfix(loss=f"{train_metrics['train/loss']:.4g}", refresh=False)
            if (config.eval_interval and step % config.eval_interval == 0) or step == config.steps:
                run_validation(step)
            if checkpoint_due:
                last_checkpoint = make_checkpoint(step)
        if last_checkpoint is None:  # defensive: the final step always writes one
            last_checkpoint = make_checkpoint(step)
    finally:
        bar.close()
        logger.close()
    return TrainResult(
        out_dir=out_dir,
        checkpoint=last_checkpoint,
        step=step,
        train_metrics=train_metrics,
        valid_metrics=valid_metrics,
    )
