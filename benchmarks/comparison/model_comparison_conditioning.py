"""Stage b. of the model comparison: what each model does with its actions. Its prediction error
under true and shuffled actions on held-out clips (``conditioning/<family>.json``), and
``vp2 diagnose`` of it at diagnose's default measurements (``diagnose/<name>.json``)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import torch

from benchmarks.comparison.model_comparison_settings import Settings, StageLog, done_record
from vp2.data.storage import load_manifest
from vp2.diagnose.model import DiagnoseConfig, diagnose_model, measure_conditioning
from vp2.envs import env_class
from vp2.run.model_spec import resolve_model
from vp2.run.run_dir import diagnosis_partial_path
from vp2.utils.io import json_safe, write_json_atomic


def conditioning_stage(s: Settings, family: str, spec: str, stage_log: StageLog) -> None:
    """True versus shuffled actions on held-out clips, measured as ``vp2 diagnose`` measures
    them (:func:`vp2.diagnose.model.measure_conditioning`, seed 0: the same clips and
    shuffle): ``conditioning/<family>.json``."""
    path = s.out / "conditioning" / f"{family}.json"
    settings = {
        "model": spec,
        "data": str(s.data),
        "clips": s.conditioning_clips,
        "samples": s.conditioning_samples,
        "measure": "vp2.diagnose.model.measure_conditioning",
    }
    if done_record(path, settings) is not None:
        stage_log.add("conditioning", family, "done earlier")
        return
    started = time.perf_counter()
    device = torch.device(s.device)
    env = load_manifest(s.data).get("config", {}).get("env", "robodesk")
    model = resolve_model(spec, {}, env=env, action_dim=int(env_class(env).action_dim),
                          device=device)
    result = measure_conditioning(model, s.data, s.conditioning_clips,
                                  s.conditioning_samples, 0, device)
    record = {"settings": settings, **result, "seconds": time.perf_counter() - started}
    write_json_atomic(path, json_safe(record))
    stage_log.add("conditioning", family, "ran", ratio=record["ratio"])


# --------------------------------------------------------------------------- b. diagnose


def diagnose_stage(s: Settings, name: str, spec: str, stage_log: StageLog) -> Path:
    """``vp2 diagnose`` of one model: ``diagnose/<name>.json`` holds ``settings`` and the
    diagnose ``report``. Clips and probed instances stay at diagnose's defaults unless the
    settings give them (``--smoke``), since its predicted score was fitted at those."""
    path = s.out / "diagnose" / f"{name}.json"
    env = load_manifest(s.data).get("config", {}).get("env", "robodesk")
    fields = {"clips": s.diagnose_clips, "instances_per_task": s.diagnose_instances}
    fields = {k: v for k, v in fields.items() if v is not None}
    config = DiagnoseConfig(
        model=spec, env=env, data=str(s.data), num_samples=s.num_samples, device=s.device,
        progress=sys.stderr.isatty(), **fields,
    )  # fmt: skip
    settings = {
        "model": spec, "data": str(s.data), "env": env, "num_samples": s.num_samples,
        "clips": config.clips, "instances_per_task": config.instances_per_task,
        "sampling_seeds": config.sampling_seeds, "seed": config.seed,
    }  # fmt: skip
    if done_record(path, settings) is not None:
        stage_log.add("diagnose", name, "done earlier")
        return path
    partial = diagnosis_partial_path(path)  # a stopped diagnosis goes on from it
    report = diagnose_model(config, partial=partial)
    write_json_atomic(path, json_safe({"settings": settings, "report": report}))
    partial.unlink(missing_ok=True)
    stage_log.add(
        "diagnose", name, "ran", predicted=report.get("predicted_control_score"),
        seconds=report["timing"]["total_s"],
    )  # fmt: skip
    return path
