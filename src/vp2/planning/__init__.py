"""Planning: action samplers, trajectory optimizers, costs on predicted frames, and the agents.

The pieces meet in one convention: an optimizer maximises a batched objective
``objective(actions (N, H, A)) -> scores (N,)`` (higher is better, actions in ``[-1, 1]``),
which the planning agent builds as ``-cost(model(actions))``. The optimizers know nothing about
models; the costs know nothing about actions. See ``docs/planning.md``.

==============  ==============================================================================
samplers.py     ActionSampler (ABC), CorrelatedNoiseSampler, GaussianSampler
optimizers/     Optimizer (ABC; each class turns a PlannerConfig into its settings), MPPI, CEM,
                CEMGD, LBFGS, OPTIMIZERS, shift_plan
costs.py        PixelSSE, ClassifierCost, PerceptualCost, WeightedCost, EnsembleCost,
                build_cost (a task's cost, in the form its registry entry names)
config.py       PlannerConfig (plain data, no torch)
planner.py      planner_settings, build_optimizer (SPEC per task)
agent.py        PlanningAgent, RandomActions, Observation, Agent protocol
==============  ==============================================================================

The SPEC numbers (σ, β, γ, sample counts, cost weights) live in :mod:`vp2.spec`; which task
uses which (its sample count, cost form and weights, classifier key) in the task registry,
:data:`vp2.envs.tasks.TASKS`.

Every name is imported on first use: :class:`PlannerConfig` (``config.py``) is plain data that a
run's configuration reads without torch; the agent brings in the models and the classifier
registry, which the samplers, optimizers and costs do without (:func:`build_cost` imports the
classifier registry when it first needs a classifier).
"""

from vp2.utils.lazy import lazy_exports

#: Where each name lives; every one is imported on first use.
_LAZY_MODULES: dict[str, list[str]] = {
    "vp2.planning.config": ["PlannerConfig"],
    "vp2.planning.costs": (
        "COST_MODES ClassifierCost CostKind CostMode CostTerm EnsembleCost PerceptualCost PixelSSE "
        "WeightedCost build_cost choose_members classifier_cost ensemble_disagreement pixel_sse "
        "robodesk_cost tabletop_cost"
    ).split(),
    "vp2.planning.optimizers": (
        "CEM CEMGD LBFGS MPPI OPTIMIZERS NotDifferentiableError Objective Optimizer OptimizerInfo "
        "shift_plan"
    ).split(),
    "vp2.planning.samplers": "ActionSampler CorrelatedNoiseSampler GaussianSampler".split(),
    "vp2.planning.agent": (
        "Agent Observation PlanningAgent RandomActions SimulatorStateModel check_agent_for_env"
    ).split(),
    "vp2.planning.planner": (
        "GRADIENT_OPTIMIZERS build_optimizer planner_settings"
    ).split(),
}
__getattr__, __dir__, _ = lazy_exports(__name__, _LAZY_MODULES)

__all__ = [
    "CEM",
    "CEMGD",
    "COST_MODES",
    "GRADIENT_OPTIMIZERS",
    "LBFGS",
    "MPPI",
    "OPTIMIZERS",
    "ActionSampler",
    "Agent",
    "ClassifierCost",
    "CorrelatedNoiseSampler",
    "CostKind",
    "CostMode",
    "CostTerm",
    "EnsembleCost",
    "GaussianSampler",
    "NotDifferentiableError",
    "Objective",
    "Observation",
    "Optimizer",
    "OptimizerInfo",
    "PerceptualCost",
    "PixelSSE",
    "PlannerConfig",
    "PlanningAgent",
    "RandomActions",
    "SimulatorStateModel",
    "WeightedCost",
    "build_cost",
    "build_optimizer",
    "check_agent_for_env",
    "choose_members",
    "classifier_cost",
    "ensemble_disagreement",
    "pixel_sse",
    "planner_settings",
    "robodesk_cost",
    "shift_plan",
    "tabletop_cost",
]
