"""Planning: action samplers, trajectory optimizers, costs on predicted frames, and the agents.

The pieces meet in one convention: an optimizer maximises a batched objective
``objective(actions (N, H, A)) -> scores (N,)`` (higher is better, actions in ``[-1, 1]``),
which the planning agent builds as ``-cost(model(actions))``. The optimizers know nothing about
models; the costs know nothing about actions. See ``docs/planning.md``.

==============  ==============================================================================
samplers.py     ActionSampler (ABC), CorrelatedNoiseSampler, GaussianSampler
optimizers/     Optimizer (ABC), MPPI, CEM, CEMGD, LBFGS, OPTIMIZERS, shift_plan
costs.py        PixelSSE, ClassifierCost, PerceptualCost, WeightedCost, EnsembleCost
planner.py      build_cost, PlannerConfig, planner_settings, build_optimizer (SPEC per task)
agent.py        PlanningAgent, RandomActions, Observation, Agent protocol
==============  ==============================================================================

The SPEC numbers (σ, β, γ, sample counts, cost weights) live in :mod:`vp2.spec`.

The names of ``planner.py`` and ``agent.py`` are imported on first use: they bring in the
models and the classifier registry, which the samplers, optimizers and costs do without.
"""

import importlib
from typing import Any

from vp2.planning.costs import (
    ClassifierCost,
    CostTerm,
    EnsembleCost,
    PerceptualCost,
    PixelSSE,
    WeightedCost,
    choose_members,
    classifier_cost,
    ensemble_disagreement,
    pixel_sse,
    robodesk_cost,
    tabletop_cost,
)
from vp2.planning.optimizers import (
    CEM,
    CEMGD,
    LBFGS,
    MPPI,
    OPTIMIZERS,
    NotDifferentiableError,
    Objective,
    Optimizer,
    OptimizerInfo,
    shift_plan,
)
from vp2.planning.samplers import ActionSampler, CorrelatedNoiseSampler, GaussianSampler

#: Where the names imported on first use live.
_LAZY_MODULES: dict[str, list[str]] = {
    "vp2.planning.agent": (
        "Agent Observation PlanningAgent RandomActions SimulatorStateModel check_agent_for_env"
    ).split(),
    "vp2.planning.planner": (
        "COST_MODES GRADIENT_OPTIMIZERS CostKind CostMode PlannerConfig build_cost "
        "build_optimizer planner_settings"
    ).split(),
}
_LAZY = {name: module for module, names in _LAZY_MODULES.items() for name in names}


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_LAZY[name]), name)


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
