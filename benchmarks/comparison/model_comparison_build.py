"""The model comparison's driver: every stage in order for one environment, resumed, with the
page rewritten after every run that planned trials (:func:`run_comparison`); and the files the
page reads besides the stages' (``comparison.json``, ``zoo/<label>.json``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import torch

import vp2
from benchmarks.comparison import records as evidence
from benchmarks.comparison.model_comparison_conditioning import conditioning_stage, diagnose_stage
from benchmarks.comparison.model_comparison_metrics import metrics_stage, shared_fvd
from benchmarks.comparison.model_comparison_publish import publish, publish_found
from benchmarks.comparison.model_comparison_runs import runs_stage
from benchmarks.comparison.model_comparison_settings import FAMILIES, Settings, StageLog
from benchmarks.comparison.model_comparison_train import model_spec, train_family
from vp2.run.model_spec import ModelSpec
from vp2.utils.io import json_safe, write_json_atomic


def write_build_record(s: Settings) -> None:
    """``comparison.json``: what ``results.md`` reads besides the stages' files (the settings,
    and what was compared)."""
    record = {
        **dataclasses.asdict(s),
        "family_stages": {
            f: [
                {**dataclasses.asdict(stage), "budget_minutes": s.budget_minutes * stage.share}
                for stage in FAMILIES[f]
            ]
            for f in s.families
        },
        "extra_models": dict(s.extras),
        "run_names": s.table_names(),
        "metrics_names": s.predictor_names(),
        "vp2_version": vp2.__version__,
        "torch_version": torch.__version__,
    }
    write_json_atomic(s.out / "comparison.json", json_safe(record))


def write_zoo_cards(s: Settings) -> list[Path]:
    """The card of each extra model from the zoo (``zoo:NAME``, checked against its
    checkpoint), as ``zoo/<label>.json``: the page's budget row reads it. Returns the files."""
    written = []
    for label, spec in s.extras:
        parsed = ModelSpec.parse(spec)
        if parsed.kind == "zoo":
            parsed.check()
            path = s.out / "zoo" / f"{label}.json"
            write_json_atomic(path, json_safe(parsed.zoo.to_json()))
            written.append(path)
    return written


def run_comparison(s: Settings, after_publish: Callable[[], object] | None = None) -> Path:
    """Runs (or resumes) every stage; returns the path of ``results.md``. ``after_publish`` is
    called each time the page is rewritten (a comparison of several environments rewrites its
    combined page there, so a build that spans sessions shows what it finished)."""
    if s.publish_only:
        return publish_found(s)
    published = after_publish or (lambda: None)
    s.out.mkdir(parents=True, exist_ok=True)
    stage_log = StageLog(s.out)
    if s.records is not None:
        restored = evidence.restore(s.records, s.out)
        if any(restored.values()):
            stage_log.add("records", str(s.records), "restored", **restored)
    write_build_record(s)
    write_zoo_cards(s)
    train_records = {f: train_family(s, f, stage_log) for f in s.families}
    specs = {f: model_spec(f, records) for f, records in train_records.items()}
    specs.update(s.extras)
    for family, spec in specs.items():
        conditioning_stage(s, family, spec, stage_log)
    predictors = {**specs, "repeat_last_frame": "repeat_last_frame"}
    for name, spec in predictors.items():
        diagnose_stage(s, name, spec, stage_log)
    fvd_metric = shared_fvd(s)  # loading the I3D takes a second, even when all is done
    metrics_files = {
        name: metrics_stage(s, name, spec, stage_log, fvd_metric)
        for name, spec in predictors.items()
    }
    save_records(s)
    # The baselines first (minutes), then the extra models, then the families in the order
    # given: the page is rewritten after every run that planned trials, so a build cut short
    # (a session's end) still publishes what it finished, and says what is pending.
    order = s.run_order()
    run_dirs: dict[str, Path] = {}
    for name in order:
        result = runs_stage(s, name, specs.get(name), stage_log)
        run_dirs[name] = result.run_dir
        save_records(s)
        pending = [n for n in order if n not in run_dirs]
        if pending and result.num_run:
            publish(s, run_dirs, metrics_files, stage_log, pending)
            published()
    page = publish(s, run_dirs, metrics_files, stage_log, [])
    published()
    return page


def save_records(s: Settings) -> None:
    """Copies what the part measured so far into its records (``--records``), if any."""
    if s.records is not None:
        evidence.save(s.out, s.records)
