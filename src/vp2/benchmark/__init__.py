"""The benchmark: control trials with a model, the runner, and the results (SPEC §4).

==================  ==========================================================================
trial.py            ControlTrial: one agent on one task instance for 15 steps
config.py           RunConfig: one field per ``vp2 run`` flag, the planner's nested
                    (PlannerConfig); importing it does not load torch
model_spec.py       the model to benchmark from ``package.module:factory``, a YAML file or a
                    checkpoint (resolve_model), and ``--model-arg`` (parse_model_args)
runner.py           run_benchmark: model × tasks × instances × seeds, resumable, parallel
run_dir.py          RunDir, a run directory: config.yaml, trials.jsonl, summaries, the
                    trials its config covers, the checks of a resume
worker.py           what runs a trial in a worker process (or Ray actor) and its record
gifs.py             the GIFs of a trial
results.py          reading records, success rates over seeds, oracle normalisation
shipped_oracle.py   the simulator oracle's rates shipped with vp2, the default normaliser
oracle_tables.py    a shipped oracle table; which table normalises each task of a run
ship_oracle.py      ``vp2 ship-oracle``: oracle runs -> results/oracle -> that file
oracle_replay.py    replaying an oracle trial record against the simulator
main_job.py         ``vp2 main``: the README's small evaluation
diagnose.py         ``vp2 diagnose``: DiagnoseConfig, diagnose_model, write_report, and the
                    run's pre-check (precheck_model); its measures in diagnose_measures.py,
                    its thresholds and verdicts in diagnose_verdicts.py
==================  ==========================================================================

The planning agent lives in :mod:`vp2.planning`, the RoboDesk success classifiers in
:mod:`vp2.classifiers`, the HTML report in :mod:`vp2.report`. The names below are imported on
first use, so importing one module of the package does not load the others (or torch).

See ``docs/evaluation.md``.
"""

import importlib
from typing import Any

#: Where the names of the package live (imported on first use).
_LAZY_MODULES: dict[str, list[str]] = {
    "vp2.benchmark.config": ["RunConfig"],
    "vp2.benchmark.model_spec": [
        "PluginError", "load_plugin", "model_identity", "parse_model_args", "resolve_model"
    ],
    "vp2.benchmark.results": [
        "Summary", "TaskSummary", "TrialLog", "format_summary", "read_trials", "summarize",
        "task_success",
    ],
    "vp2.benchmark.run_dir": ["RunDir", "read_config"],
    "vp2.benchmark.runner": ["ModelFailure", "RunResult", "run_benchmark", "select_instances"],
    "vp2.benchmark.trial": ["ControlTrial", "TrialResult", "trial_seed"],
    "vp2.classifiers.registry": ["CLASSIFIERS", "ClassifierRegistry"],
    "vp2.planning.agent": ["Agent", "Observation", "PlanningAgent", "SimulatorStateModel"],
    "vp2.planning.planner": [
        "COST_MODES", "PlannerConfig", "build_cost", "build_optimizer", "planner_settings"
    ],
    "vp2.spec": ["NUM_CONTROL_STEPS"],
}
_LAZY = {name: module for module, names in _LAZY_MODULES.items() for name in names}


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_LAZY[name]), name)


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])


__all__ = sorted(_LAZY)
