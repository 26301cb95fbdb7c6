"""What a benchmark run is made of: its settings, its model, one trial, its directory, its records.

==================  ==========================================================================
config.py           RunConfig: one field per ``vp2 run`` flag, the planner's nested
                    (PlannerConfig); importing it does not load torch
model_spec.py       the model to benchmark from ``package.module:factory``, a YAML file or a
                    checkpoint (resolve_model), and ``--model-arg`` (parse_model_args)
trial.py            ControlTrial: one agent on one task instance for 15 steps
partial.py          a trial's progress on disk, so that a cut-off trial resumes at its step
run_dir.py          RunDir, a run directory: every file name of it, config.yaml (and the
                    form of old ones), trials.jsonl, summaries, the trials its config
                    covers, the checks of a resume
results.py          the records' writer (TrialLog), success rates over seeds, normalising by
                    oracle rows
==================  ==========================================================================

This room knows nothing of the shipped oracle (:mod:`vp2.oracle`), the diagnosis
(:mod:`vp2.diagnose`) or the runner loop (:mod:`vp2.benchmark`), which all build on it. The
names below are imported on first use, so importing one module of the package does not load
the others (or torch).

See ``docs/evaluation.md``.
"""

from vp2.utils.lazy import lazy_exports

#: Where the names of the package live (imported on first use).
_LAZY_MODULES: dict[str, list[str]] = {
    "vp2.run.config": ["RunConfig"],
    "vp2.run.model_spec": [
        "ModelSpec", "PluginError", "check_spec", "load_plugin", "model_identity",
        "parse_model_args", "resolve_model",
    ],
    "vp2.run.partial": ["PartialTrial"],
    "vp2.run.results": [
        "Summary", "TaskSummary", "TrialLog", "format_summary", "summarize", "task_success",
    ],
    "vp2.run.run_dir": ["RunDir", "read_config", "read_trials"],
    "vp2.run.trial": ["ControlTrial", "TrialResult", "trial_seed"],
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _LAZY_MODULES)
