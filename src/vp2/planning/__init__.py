"""Planning: action samplers, trajectory optimizers and costs on predicted frames.

The pieces meet in one convention: an optimizer maximises a batched objective
``objective(actions (N, H, A)) -> scores (N,)`` (higher is better, actions in ``[-1, 1]``),
which the planning agent builds as ``-cost(model(actions))``. The optimizers know nothing about
models; the costs know nothing about actions. See ``docs/planning.md``.
"""

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
from vp2.planning.samplers import (
    DEFAULT_BETA,
    DEFAULT_SIGMA,
    ActionSampler,
    CorrelatedNoiseSampler,
    GaussianSampler,
)

__all__ = [
    "CEM",
    "CEMGD",
    "DEFAULT_BETA",
    "DEFAULT_SIGMA",
    "LBFGS",
    "MPPI",
    "OPTIMIZERS",
    "ActionSampler",
    "ClassifierCost",
    "CorrelatedNoiseSampler",
    "CostTerm",
    "EnsembleCost",
    "GaussianSampler",
    "NotDifferentiableError",
    "Objective",
    "Optimizer",
    "OptimizerInfo",
    "PerceptualCost",
    "PixelSSE",
    "WeightedCost",
    "choose_members",
    "classifier_cost",
    "ensemble_disagreement",
    "pixel_sse",
    "robodesk_cost",
    "shift_plan",
    "tabletop_cost",
]
