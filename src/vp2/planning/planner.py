"""What the planning agent builds per task: its optimizer (SPEC §5), and, re-exported from
:mod:`vp2.planning.costs`, its cost (SPEC §6).

The optimizer's settings (:class:`PlannerConfig`) default to SPEC §5 per task: MPPI with the
task's sample count (``Task.num_samples`` of :data:`vp2.envs.tasks.TASKS`: 200, 800 for
``open_slide`` and ``open_drawer``), γ = 0.05 and the environment's σ. Each optimizer class
turns them into its constructor arguments (:meth:`vp2.planning.optimizers.Optimizer.settings`).
"""

from __future__ import annotations

import math
from typing import Any

from vp2 import spec
from vp2.envs.tasks import get_task
from vp2.planning.config import PlannerConfig
from vp2.planning.costs import COST_MODES, CostKind, CostMode, build_cost
from vp2.planning.optimizers import OPTIMIZERS, Optimizer

#: Optimizers that need gradients of the predictions with respect to the actions: the runner
#: checks the model gives them (:func:`vp2.models.contract.gradient_problem`) before any trial.
GRADIENT_OPTIMIZERS: tuple[str, ...] = ("cem_gd", "lbfgs")


def planner_settings(task: str, config: PlannerConfig) -> dict[str, Any]:
    """The optimizer's resolved constructor arguments for one task (recorded in every trial).

    Resolves what belongs to the task (the env's σ, checked against the action size; the task's
    sample count) and lets the optimizer class turn it and ``config`` into its arguments.

    Returns:
        ``{"optimizer": name, **kwargs}`` with plain-data values.
    """
    if config.optimizer not in OPTIMIZERS:
        raise ValueError(
            f"unknown optimizer {config.optimizer!r}; choose one of {', '.join(OPTIMIZERS)}"
        )
    check_optimizer_fields(config)
    registered = get_task(task)
    env_sigma = spec.SIGMA[registered.env]
    sigma = list(config.sigma if config.sigma is not None else env_sigma)
    if len(sigma) != len(env_sigma):
        raise ValueError(f"{task}: sigma has {len(sigma)} entries, the action has {len(env_sigma)}")
    kwargs = OPTIMIZERS[config.optimizer].settings(config, sigma, registered.num_samples)
    return {"optimizer": config.optimizer, **kwargs}


def check_optimizer_fields(config: PlannerConfig) -> None:
    """Refuses an :data:`~vp2.planning.config.OPTIMIZER_FIELDS` setting the config's optimizer
    does not read, or out of range (``lr > 0``, the counts ``>= 1``).

    Raises:
        ValueError: naming the setting (its ``vp2 run`` flag is the name with dashes).
    """
    for name, value in config.optimizer_fields().items():
        readers = [n for n, cls in OPTIMIZERS.items() if name in cls.config_fields]
        if name not in OPTIMIZERS[config.optimizer].config_fields:
            raise ValueError(
                f"planner setting {name}={value!r} is read by {' and '.join(readers)}, not by "
                f"{config.optimizer}: drop it or plan with {' or '.join(readers)}"
            )
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if name == "lr":
            ok, wanted = number and 0 < value < math.inf, "a number > 0"
        else:
            ok, wanted = number and isinstance(value, int) and value >= 1, "an integer >= 1"
        if not ok:
            raise ValueError(f"planner setting {name} must be {wanted}, got {value!r}")


def build_optimizer(task: str, config: PlannerConfig) -> Optimizer:
    """A fresh optimizer for one task, from :func:`planner_settings`."""
    settings = planner_settings(task, config)
    name = settings.pop("optimizer")
    return OPTIMIZERS[name](**settings)


__all__ = [
    "COST_MODES",
    "GRADIENT_OPTIMIZERS",
    "CostKind",
    "CostMode",
    "PlannerConfig",
    "build_cost",
    "build_optimizer",
    "check_optimizer_fields",
    "planner_settings",
]
