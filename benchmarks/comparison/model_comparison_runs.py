"""Stage d. of the model comparison: ``vp2 run`` of each model and baseline on the tasks
(``runs/<name>/``), resumed trial by trial."""

from __future__ import annotations

import sys
from typing import Any

from benchmarks.comparison.model_comparison_settings import BASELINES, Settings, StageLog
from vp2.benchmark.runner import RunResult, run_benchmark
from vp2.planning.config import PlannerConfig
from vp2.report.page import write_run_report
from vp2.run.config import RunConfig


def run_config(s: Settings, name: str, spec: str | None) -> RunConfig:
    """The ``vp2 run`` of a family (``spec``) or of a baseline (:data:`BASELINES`)."""
    shared: dict[str, Any] = dict(
        out=str(s.out / "runs" / name),
        tasks=s.tasks,
        num_instances=s.num_instances,
        seeds=s.seeds_of(name),
        planner=PlannerConfig(num_samples=s.num_samples),
        num_steps=s.num_steps,
        workers=s.workers,
        device=s.device,
        resume=True,  # a fresh directory starts, an existing one runs only its missing trials
        progress=sys.stderr.isatty(),
    )
    if spec is not None:
        return RunConfig(model=spec, **shared)
    baseline = dict(BASELINES[name])
    if baseline.get("agent") == "random":
        shared["planner"] = PlannerConfig()  # plans nothing: no planner setting departs from SPEC
    return RunConfig(**baseline, **shared)


def runs_stage(s: Settings, name: str, spec: str | None, stage_log: StageLog) -> RunResult:
    config = run_config(s, name, spec)
    result = run_benchmark(config, after_run=write_run_report)
    status = "ran" if result.num_run else "done earlier"
    stage_log.add(
        "run",
        name,
        status,
        num_run=result.num_run,
        num_skipped=result.num_skipped,
        trials=len(result.records),
        errors=result.num_errors,
    )
    return result
