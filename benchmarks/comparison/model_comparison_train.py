"""Stage a. of the model comparison: ``vp2 train`` of every family at the time budget, resumed
from the newest checkpoint, or (``--skip-train``) the newest checkpoint as found."""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from benchmarks.comparison.model_comparison_settings import (
    FAMILIES,
    STEP_CAP,
    Settings,
    StageLog,
    TrainStage,
    device_name,
    done_record,
)
from vp2.training.checkpoint import list_checkpoints
from vp2.training.config import TrainConfig
from vp2.training.trainer import train
from vp2.utils.io import json_safe, write_json_atomic


def train_config(s: Settings, stage: TrainStage, tokenizer: str | None) -> TrainConfig:
    """The ``vp2 train`` run of one stage of a family."""
    overrides = dict(stage.overrides)
    if stage.tokenizer:
        overrides["tokenizer_checkpoint"] = tokenizer
    return TrainConfig(
        model=stage.model,
        preset=stage.preset,
        model_overrides=overrides,
        dataset=str(s.data),
        out_dir=str(s.out / "train" / stage.model),
        steps=STEP_CAP,
        max_minutes=s.budget_minutes * stage.share,
        batch_size=s.batch_size,
        seed=0,
        eval_interval=s.eval_interval,
        eval_batches=s.eval_batches,
        ckpt_interval=s.ckpt_interval,
        log_interval=s.log_interval,
        workers=s.loader_workers,
        device=s.device,
        tensorboard=False,
        progress=sys.stderr.isatty(),
        resume=True,
    )


def _train_settings(config: TrainConfig) -> dict[str, Any]:
    """What makes a training record reusable: everything that changes the weights."""
    keys = ("model", "preset", "model_overrides", "dataset", "batch_size", "seed", "max_minutes")
    return {k: getattr(config, k) for k in keys}


def train_stage(s: Settings, config: TrainConfig, stage_log: StageLog) -> dict[str, Any]:
    """Trains (or resumes, or finds done) one model; returns its record."""
    path = Path(config.out_dir).with_suffix(".json")
    settings = _train_settings(config)
    record = done_record(path, settings)
    if record is not None and (record.get("complete") or s.skip_train):
        stage_log.add("train", config.model, "done earlier", step=record["step"])
        return record
    if s.skip_train:
        # Evaluate whatever the run directory holds (e.g. trained elsewhere and copied here).
        existing = list_checkpoints(config.out_dir)
        if not existing:
            raise FileNotFoundError(f"--skip-train: no checkpoint in {config.out_dir}")
        payload = torch.load(existing[-1], map_location="cpu", weights_only=True)
        found = _train_settings(TrainConfig.from_dict(payload["train_config"]))
        if json_safe(found) != json_safe(settings):
            raise ValueError(
                f"--skip-train: {existing[-1]} was trained with {found}, this comparison asks "
                f"for {settings}"
            )
        seconds = float(payload.get("train_seconds", 0.0))
        budget_reached = seconds >= 60 * config.max_minutes
        record = {
            "step": int(payload["step"]),
            "train_minutes": seconds / 60,
            "budget_reached": budget_reached,
            "checkpoint": str(existing[-1]),
            # An unfinished run taken as it is: a later invocation without --skip-train
            # continues its training.
            "complete": budget_reached,
            "note": "--skip-train: the newest checkpoint, as found",
        }
        stage_log.add("train", config.model, "skipped (--skip-train)", step=record["step"])
    else:
        resumed = bool(list_checkpoints(config.out_dir))
        result = train(config)
        record = {
            "step": result.step,
            "train_minutes": result.train_minutes,
            "budget_reached": result.budget_reached,
            "checkpoint": str(result.checkpoint),
            "complete": True,
        }
        stage_log.add("train", config.model, "resumed" if resumed else "trained", step=result.step)
    run_record = json.loads((Path(config.out_dir) / "config.json").read_text())
    record.update(
        settings=settings,
        budget_minutes=config.max_minutes,
        parameters=run_record.get("parameters"),
        # A run found as it is says only the torch device it trained on.
        device=f"{run_record['device']} (elsewhere)" if s.skip_train else device_name(s.device),
        threads=None if s.skip_train else torch.get_num_threads(),
    )
    write_json_atomic(path, json_safe(record))
    return record


def train_family(s: Settings, family: str, stage_log: StageLog) -> list[dict[str, Any]]:
    """Trains a family's stages in order; returns their records (the last is the predictor)."""
    records: list[dict[str, Any]] = []
    for stage in FAMILIES[family]:
        tokenizer = records[-1]["checkpoint"] if stage.tokenizer else None
        records.append(train_stage(s, train_config(s, stage, tokenizer), stage_log))
    return records


def model_spec(family: str, records: Sequence[dict[str, Any]]) -> str:
    """The family's ``NAME:CHECKPOINT`` spec: its final checkpoint *file*, so that runs and
    metrics made with another checkpoint of the same run directory are refused, not mixed."""
    return f"{FAMILIES[family][-1].model}:{records[-1]['checkpoint']}"
