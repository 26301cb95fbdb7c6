"""The benchmark: running control trials of a model, resumably and in parallel (SPEC §4).

==================  ==========================================================================
runner.py           run_benchmark: model × tasks × instances × seeds, resumable, parallel;
                    the diagnosis's pre-check before the first trial, the shipped oracle's
                    normalisation of the summary
worker.py           what runs a trial in a worker process (or Ray actor) and its record
gifs.py             the GIFs of a trial
main_job.py         ``vp2 main``: the README's small evaluation
==================  ==========================================================================

What a run is made of (its config, ``--model`` resolution, the control trial and its partial
file, the run directory, the records and scores) lives in :mod:`vp2.run`, the shipped oracle
in :mod:`vp2.oracle`, ``vp2 diagnose`` and the pre-check in :mod:`vp2.diagnose`; the names of
:mod:`vp2.run` are exported here too. The planning agent lives in :mod:`vp2.planning`, the
RoboDesk success classifiers in :mod:`vp2.classifiers`, the HTML report in :mod:`vp2.report`.
The names below are imported on first use, so importing one module of the package does not
load the others (or torch).

See ``docs/evaluation.md``.
"""

from vp2.utils.lazy import lazy_exports

#: Where the names of the package live (imported on first use).
_LAZY_MODULES: dict[str, list[str]] = {
    "vp2.run.config": ["RunConfig"],
    "vp2.run.model_spec": [
        "PluginError", "load_plugin", "model_identity", "parse_model_args", "resolve_model"
    ],
    "vp2.run.results": [
        "Summary", "TaskSummary", "TrialLog", "format_summary", "summarize", "task_success",
    ],
    "vp2.run.run_dir": ["RunDir", "read_config", "read_trials"],
    "vp2.benchmark.runner": ["ModelFailure", "RunResult", "run_benchmark", "select_instances"],
    "vp2.run.trial": ["ControlTrial", "TrialResult", "trial_seed"],
    "vp2.classifiers.registry": ["CLASSIFIERS", "ClassifierRegistry"],
    "vp2.planning.agent": ["Agent", "Observation", "PlanningAgent", "SimulatorStateModel"],
    "vp2.planning.planner": [
        "COST_MODES", "PlannerConfig", "build_cost", "build_optimizer", "planner_settings"
    ],
    "vp2.spec": ["NUM_CONTROL_STEPS"],
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _LAZY_MODULES)
