"""Stage c. of the model comparison: ``vp2 metrics`` of each model on held-out clips
(``metrics/<name>/metrics.json``), with one FVD metric shared by the models."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from benchmarks.comparison.model_comparison_settings import Settings, StageLog
from vp2.metrics.evaluate import DEFAULT_BATCH_SIZE, evaluate_model, write_metrics
from vp2.metrics.fvd import FrechetVideoDistance
from vp2.training.perceptual import MissingWeightsError


def shared_fvd(s: Settings) -> FrechetVideoDistance | None:
    """One FVD metric for every model's ``vp2 metrics``, so the held-out clips' I3D features
    are computed once (``FrechetVideoDistance.reference_features``); ``None`` when FVD is off
    or its weights are absent (each model's metrics then say why FVD was skipped)."""
    if not s.fvd:
        return None
    try:
        return FrechetVideoDistance(device=s.device, batch_size=DEFAULT_BATCH_SIZE)
    except MissingWeightsError:
        return None


def metrics_stage(
    s: Settings,
    name: str,
    spec: str,
    stage_log: StageLog,
    fvd_metric: FrechetVideoDistance | None = None,
) -> Path:
    """``vp2 metrics`` of one model: ``metrics/<name>/metrics.json`` (``fvd_metric``: one
    shared by the models, see :func:`shared_fvd`)."""
    path = s.out / "metrics" / name / "metrics.json"
    settings = {
        "model": spec,
        "data": str(s.data),
        "num_clips": s.metrics_clips,
        "seed": 0,
        "lpips": list(s.lpips),
        "fvd": s.fvd,
    }
    if path.is_file():
        done = json.loads(path.read_text())
        if done.get("comparison_settings") != settings:
            raise ValueError(f"{path} was made with other settings; use another --out or delete it")
        # FVD skipped for want of its weights, which are here now: measure again
        if not ("fvd" in done.get("skipped", {}) and fvd_metric is not None):
            stage_log.add("metrics", name, "done earlier")
            return path
    result = evaluate_model(
        spec,
        s.data,
        num_clips=s.metrics_clips,
        seed=0,
        batch_size=DEFAULT_BATCH_SIZE,
        lpips_nets=s.lpips,
        fvd=s.fvd,
        device=s.device,
        progress=sys.stderr.isatty(),
        fvd_metric=fvd_metric,
    )
    result["comparison_settings"] = settings
    write_metrics(path, result)
    stage_log.add(
        "metrics", name, "ran", mse=result["metrics"]["mse"], skipped=list(result["skipped"])
    )
    return path
