"""The benchmark: control trials with a model, the runner, and the results (SPEC §4).

- :class:`PlanningAgent` (``agent.py``): visual foresight with a model, a cost and MPPI.
- :class:`ControlTrial` (``trial.py``): one agent on one task instance for 15 steps.
- :func:`run_benchmark` (``runner.py``): model × tasks × instances × seeds, resumable,
  parallel, writing ``trials.jsonl``, GIFs and a summary.
- ``results.py``: reading records, success rates over seeds, oracle normalisation.
- ``plugins.py``: the model to benchmark from ``package.module:factory`` or a YAML file.
- ``classifiers.py``: the RoboDesk success classifiers (training, the shipped files, which
  are registered into :data:`CLASSIFIERS` on import).

See ``docs/benchmark.md``.
"""

from vp2.benchmark.agent import (
    CLASSIFIERS,
    COST_MODES,
    Agent,
    ClassifierRegistry,
    Observation,
    PlannerConfig,
    PlanningAgent,
    SimulatorStateModel,
    build_cost,
    build_optimizer,
    planner_settings,
)
from vp2.benchmark.classifiers import register_shipped_classifiers
from vp2.benchmark.plugins import PluginError, build_model, load_plugin, model_identity
from vp2.benchmark.results import (
    Summary,
    TaskSummary,
    TrialLog,
    format_summary,
    read_trials,
    summarize,
    task_success,
)
from vp2.benchmark.runner import (
    ModelFailure,
    RunConfig,
    RunResult,
    parse_model_args,
    read_config,
    run_benchmark,
    select_instances,
)
from vp2.benchmark.trial import NUM_CONTROL_STEPS, ControlTrial, TrialResult, trial_seed

# The RoboDesk success classifiers shipped in vp2/assets/classifiers, registered (not loaded)
# into CLASSIFIERS; a task without a file keeps the pixel_only fallback.
register_shipped_classifiers(CLASSIFIERS)

__all__ = [
    "CLASSIFIERS",
    "COST_MODES",
    "NUM_CONTROL_STEPS",
    "Agent",
    "ClassifierRegistry",
    "ControlTrial",
    "ModelFailure",
    "Observation",
    "PlannerConfig",
    "PlanningAgent",
    "PluginError",
    "RunConfig",
    "RunResult",
    "SimulatorStateModel",
    "Summary",
    "TaskSummary",
    "TrialLog",
    "TrialResult",
    "build_cost",
    "build_model",
    "build_optimizer",
    "format_summary",
    "load_plugin",
    "model_identity",
    "parse_model_args",
    "planner_settings",
    "read_config",
    "read_trials",
    "run_benchmark",
    "select_instances",
    "summarize",
    "task_success",
    "trial_seed",
]
