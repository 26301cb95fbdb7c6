"""Trajectory optimizers for visual-foresight planning.

An optimizer knows nothing about models or images. It maximises a batched **objective**

    objective(actions)  ->  scores,        actions: (N, H, A) in [-1, 1],  scores: (N,)

where a higher score is better (a cost ``c`` is the score ``-c``). The planning agent builds the
objective from a video prediction model and a cost (:mod:`vp2.planning.costs`); the optimizer
only calls it. Every optimizer implements :meth:`Optimizer.optimize`::

    plan, info = optimizer.optimize(objective, initial_mean, generator)   # plan: (H, A)

The agent calls it once per control step, with ``initial_mean`` the previous plan shifted by one
step (:func:`shift_plan`) or zeros on the first step, and calls :meth:`Optimizer.reset` at the
start of each trial.

========  ===========================================================================
MPPI      SPEC §5 default. Weighted mean of correlated-noise samples.
CEM       Cross-entropy method; returns the best sample of the last iteration.
CEMGD     CEM, then gradient refinement of the best sequences (needs gradients).
LBFGS     ``torch.optim.LBFGS`` on one sequence (needs gradients).
========  ===========================================================================

Sampling-based optimizers evaluate the objective under ``torch.no_grad()``. Gradient-based ones
need an objective whose scores carry a ``grad_fn`` back to the actions and raise
:class:`NotDifferentiableError` otherwise. All work on the device and dtype of ``initial_mean``.

``base.py`` holds the contract (:class:`Optimizer`, :class:`OptimizerInfo`, the objective
checks, :func:`shift_plan`); ``mppi.py``, ``cem.py`` and ``gradient.py`` (CEM-GD, L-BFGS) the
optimizers. Each optimizer class also owns its settings: :meth:`Optimizer.settings` turns a run's
planner config, the env's σ and the task's sample count into its constructor arguments (what
:func:`vp2.planning.planner.planner_settings` records in every trial).
"""

from vp2.planning.optimizers.base import (
    NotDifferentiableError,
    Objective,
    Optimizer,
    OptimizerInfo,
    SamplingOptimizer,
    evaluate_objective,
    scores_and_gradients,
    shift_plan,
)
from vp2.planning.optimizers.cem import CEM, clamp_cem_variance
from vp2.planning.optimizers.gradient import CEMGD, LBFGS
from vp2.planning.optimizers.mppi import MPPI, mppi_weights

#: Optimizers by the names configs use.
OPTIMIZERS: dict[str, type[Optimizer]] = {
    "mppi": MPPI,
    "cem": CEM,
    "cem_gd": CEMGD,
    "lbfgs": LBFGS,
}

__all__ = [
    "CEM",
    "CEMGD",
    "LBFGS",
    "MPPI",
    "OPTIMIZERS",
    "NotDifferentiableError",
    "Objective",
    "Optimizer",
    "OptimizerInfo",
    "SamplingOptimizer",
    "clamp_cem_variance",
    "evaluate_objective",
    "mppi_weights",
    "scores_and_gradients",
    "shift_plan",
]
