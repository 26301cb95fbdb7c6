"""Training a registered video prediction model on a vp2 dataset.

::

    from vp2.training import TrainConfig, train
    result = train(TrainConfig(model="fitvid", preset="mini", dataset="data/tabletop",
                               out_dir="runs/fitvid-mini", steps=10_000))
    model = load_model(result.checkpoint)        # vp2.models.load_model

A run directory holds ``config.json`` (the resolved configuration; at the end also how the
run finished), ``metrics.csv`` (and ``tb/`` if TensorBoard is installed), ``samples/step_*.png``
(true vs predicted frames of validation clips) and ``checkpoints/step_*.pt``. ``resume=True``
continues an interrupted run from its newest checkpoint; on the same device the result is
bit-identical to an uninterrupted run, because every source of randomness is either restored
from the checkpoint (the posterior-noise generator) or a pure function of ``(seed, step)`` (the
data order). ``max_minutes`` is a time budget: the run ends as at ``steps`` after the first
step at which its training wall time (validation and checkpoint writing left out), summed over
sessions (kept in every checkpoint), reaches it.

This module is the loop (one optimisation step, logging, validation, checkpoint timing);
:mod:`vp2.training.setup` builds the run and writes its checkpoints, :mod:`vp2.training.config`
holds :class:`TrainConfig` and :mod:`vp2.training.batches` the data order and seeds.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Iterator
from pathlib import Path

import torch
from torch.utils.data import DataLoader
from tqdm.auto import tqdm

from vp2.models.base import LossOutput, VideoPredictor
from vp2.models.layers import PerceptualLoss
from vp2.training.batches import StepBatchSampler, batch_to_device, child_seed
from vp2.training.config import TrainConfig, TrainResult
from vp2.training.logger import prediction_grid, save_png
from vp2.training.setup import TrainingRun, start_run

log = logging.getLogger(__name__)

#: The clock of the training time budget (``TrainConfig.max_minutes``), in seconds; a module
#: attribute so that tests can replace it with a deterministic one.
clock = time.monotonic


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
    run = start_run(config, perceptual_fn)
    sampler = StepBatchSampler(
        len(run.train_set), config.batch_size, child_seed(config.seed, 4), run.start, config.steps
    )
    loader = DataLoader(
        run.train_set,
        batch_sampler=sampler,
        num_workers=config.workers,
        pin_memory=run.device.type == "cuda",
    )
    train_metrics: dict[str, float] = {}
    run.model.train()
    bar = tqdm(
        total=config.steps,
        initial=run.start,
        unit="step",
        disable=not config.progress,
        desc=f"train {config.model}",
        dynamic_ncols=True,
    )
    rate = _StepRate(run.start)
    budget = None if config.max_minutes is None else 60.0 * config.max_minutes
    # A resumed run whose earlier sessions spent the budget is finished, like one at `steps`.
    budget_reached = budget is not None and run.train_seconds >= budget
    timer = _TrainingTime(run.train_seconds)
    try:
        step = run.start
        for batch in loader if not budget_reached else ():
            out, grad_norm = optimisation_step(run, batch)
            step += 1
            bar.update(1)
            run.train_seconds = timer.seconds()
            budget_reached = budget is not None and run.train_seconds >= budget

            last = step == config.steps or budget_reached
            checkpoint_due = _every(step, config.ckpt_interval) or last
            if step % config.log_interval == 0 or checkpoint_due:
                # Checked here rather than every step: reading the loss synchronises with the
                # GPU. A NaN makes every later loss NaN, so it is caught before any checkpoint.
                _check_finite(out.loss, step, run.last_checkpoint)
            if step % config.log_interval == 0 or last:
                train_metrics = _log_train_step(run, step, out, grad_norm, rate)
                bar.set_postfix(loss=f"{train_metrics['train/loss']:.4g}", refresh=False)
            with timer.paused():  # they depend on the intervals, not on the training
                if _every(step, config.eval_interval) or last:
                    run_validation(run, step)
                if checkpoint_due:
                    run.last_checkpoint = run.save_checkpoint(step)
            if last:
                break
        if run.last_checkpoint is None:  # defensive: the final step always writes one
            run.last_checkpoint = run.save_checkpoint(step)
    finally:
        bar.close()
        run.logger.close()
    if budget_reached:
        log.info(
            "%s: the budget of %g min was reached at step %d", run.out_dir, config.max_minutes, step
        )
    run.record_finish(step, budget_reached)
    return TrainResult(
        out_dir=run.out_dir,
        checkpoint=run.last_checkpoint,
        step=step,
        train_metrics=train_metrics,
        valid_metrics=run.valid_metrics,
        train_minutes=run.train_seconds / 60,
        budget_reached=budget_reached,
    )


def optimisation_step(
    run: TrainingRun, batch: dict[str, torch.Tensor]
) -> tuple[LossOutput, torch.Tensor | None]:
    """One optimiser update on a loader batch; returns the loss output and the gradient norm
    before clipping (``None`` without clipping)."""
    frames, actions = batch_to_device(batch, run.device, non_blocking=True)
    with run.autocast():
        out = run.model.compute_loss(
            frames, actions, run.noise, run.perceptual, run.config.perceptual_weight
        )
    run.scaler.scale(out.loss).backward()
    grad_norm = None
    if run.grad_clip is not None:
        run.scaler.unscale_(run.optimizer)
        grad_norm = torch.nn.utils.clip_grad_norm_(run.model.parameters(), run.grad_clip)
    run.scaler.step(run.optimizer)
    run.scaler.update()
    run.optimizer.zero_grad(set_to_none=True)
    return out, grad_norm


def run_validation(run: TrainingRun, step: int) -> None:
    """Validates at ``step``: logs the metrics, keeps them for the next checkpoint and saves
    the prediction grid of the first batch (``samples/step_*.png``)."""
    if not run.valid_batches:
        return
    run.valid_metrics, first = validate(
        run.model,
        run.valid_batches,
        run.device,
        run.config.seed,
        run.perceptual,
        run.config.perceptual_weight,
    )
    run.logger.log(step, run.valid_metrics)
    if first is not None:
        grid = prediction_grid(*first)
        save_png(run.out_dir / "samples" / f"step_{step:08d}.png", grid)
        run.logger.log_image(step, "valid/predictions", grid)


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
            frames, actions = batch_to_device(batch, device)  # (B, T, 3, H, W), (B, T - 1, A)
            gen = torch.Generator(device).manual_seed(child_seed(seed, 2, i))
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


def _every(step: int, interval: int) -> bool:
    """Whether ``step`` is a multiple of ``interval`` (never for ``interval == 0``)."""
    return bool(interval) and step % interval == 0


def _check_finite(loss: torch.Tensor, step: int, last_checkpoint: Path | None) -> None:
    loss_value = float(loss.detach())
    if not math.isfinite(loss_value):
        raise FloatingPointError(
            f"loss is {loss_value} by step {step}; resume from "
            f"{last_checkpoint or 'scratch'} with a lower lr (or amp=False)"
        )


class _TrainingTime:
    """The clock of the time budget: seconds of training, earlier sessions included, with
    validation and checkpoint writing left out (:meth:`paused`)."""

    def __init__(self, seconds_before: float):
        self.start, self.left_out = clock() - seconds_before, 0.0

    def seconds(self) -> float:
        return clock() - self.start - self.left_out

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        began = clock()
        try:
            yield
        finally:
            self.left_out += clock() - began


class _StepRate:
    """Training speed: steps per second between two log rows."""

    def __init__(self, step: int):
        self.time, self.step = time.perf_counter(), step

    def update(self, step: int, now: float) -> float:
        rate = (step - self.step) / max(now - self.time, 1e-9)
        self.time, self.step = now, step
        return rate


def _log_train_step(
    run: TrainingRun,
    step: int,
    out: LossOutput,
    grad_norm: torch.Tensor | None,
    rate: _StepRate,
) -> dict[str, float]:
    now = time.perf_counter()
    metrics = {
        "train/loss": float(out.loss.detach()),
        **{f"train/{k}": float(v) for k, v in out.metrics.items()},
    }
    if grad_norm is not None:
        metrics["train/grad_norm"] = float(grad_norm)
    metrics["train/steps_per_s"] = rate.update(step, now)
    metrics["train/minutes"] = run.train_seconds / 60  # all sessions (the budget's clock)
    run.logger.log(step, metrics)
    return metrics
