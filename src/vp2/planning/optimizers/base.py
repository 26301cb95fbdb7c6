"""What every optimizer shares: the objective contract, the report, the base classes.

See :mod:`vp2.planning.optimizers` for the optimizers and how the agent calls them.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

import torch
from torch import Tensor

from vp2 import spec
from vp2.planning.config import PlannerConfig
from vp2.planning.samplers import ACTION_HIGH, ACTION_LOW, ActionSampler, CorrelatedNoiseSampler

#: ``objective(actions (N, H, A)) -> scores (N,)``, higher is better.
Objective = Callable[[Tensor], Tensor]


class NotDifferentiableError(TypeError):
    """Raised when a gradient-based optimizer gets scores that do not depend differentiably on
    the actions."""


@dataclass
class OptimizerInfo:
    """What an optimizer reports about one :meth:`Optimizer.optimize` call.

    Attributes:
        best_score: Highest score among all evaluated action sequences.
        plan_score: Score of the returned plan where it was evaluated (``None`` for MPPI, whose
            plan is a weighted mean that is never scored itself).
        num_evaluations: Number of action sequences scored (sum of batch sizes).
        num_objective_calls: Number of calls to the objective.
        iteration_best_scores: Best score of each iteration (sampling optimizers) or of each
            accepted step (gradient refinement).
    """

    best_score: float
    plan_score: float | None
    num_evaluations: int
    num_objective_calls: int
    iteration_best_scores: list[float] = field(default_factory=list)


def evaluate_objective(objective: Objective, actions: Tensor) -> Tensor:
    """Calls ``objective`` and checks that it kept its side of the contract.

    Args:
        objective: The batched objective.
        actions: ``(N, H, A)`` action sequences.

    Returns:
        ``(N,)`` scores.

    Raises:
        ValueError: If the scores are not a ``(N,)`` tensor of finite values.
    """
    scores = objective(actions)
    if not isinstance(scores, Tensor):
        raise ValueError(f"objective must return a torch.Tensor, got {type(scores).__name__}")
    if scores.shape != (actions.shape[0],):
        raise ValueError(
            f"objective must return scores of shape (N,) = ({actions.shape[0]},) for actions "
            f"of shape {tuple(actions.shape)}, got {tuple(scores.shape)}"
        )
    if not bool(torch.isfinite(scores).all()):
        raise ValueError("objective returned non-finite scores (NaN or inf)")
    return scores.to(actions.device)  # a no-op unless the objective scored on another device


def scores_and_gradients(
    objective: Objective, actions: Tensor, who: str = "this optimizer"
) -> tuple[Tensor, Tensor]:
    """Scores of ``actions`` and their gradients with respect to the actions.

    The objective must treat samples independently (a model in eval mode does), so the
    gradient of the summed scores gives every sequence its own gradient in one backward pass.
    Gradients go to the actions only; model parameters' ``.grad`` are left untouched.

    Args:
        objective: The batched objective.
        actions: ``(N, H, A)`` action sequences.
        who: Name used in the error message.

    Returns:
        ``(N,)`` detached scores and ``(N, H, A)`` gradients ``d score_n / d actions_n``.

    Raises:
        NotDifferentiableError: If the scores carry no gradient back to the actions.
    """
    leaf = actions.detach().requires_grad_(True)
    with torch.enable_grad():
        scores = evaluate_objective(objective, leaf)  # (N,)
        if scores.grad_fn is None:
            raise NotDifferentiableError(
                f"{who} needs a differentiable objective, but objective(actions) returned "
                "scores with no grad_fn. Build it from a differentiable model and cost (no "
                "torch.no_grad(), .detach(), .item() or NumPy inside) or use MPPI/CEM."
            )
        (grad,) = torch.autograd.grad(scores.sum(), leaf, allow_unused=True)
    if grad is None:
        raise NotDifferentiableError(
            f"{who} needs a differentiable objective, but its scores do not depend on the actions"
        )
    return scores.detach(), grad  # (N,), (N, H, A)


def shift_plan(plan: Tensor, steps: int = 1, pad: Literal["repeat", "zero"] = "repeat") -> Tensor:
    """Warm start: the plan for the next control step from the current one.

    Drops the first ``steps`` actions (they have been executed) and pads the end. The default,
    ``"repeat"``, repeats the last action, as the original VP² code does; ``"zero"`` pads with
    zero actions.

    Args:
        plan: ``(H, A)`` current plan.
        steps: Number of executed actions to drop (``0 <= steps <= H``).
        pad: ``"repeat"`` or ``"zero"``.

    Returns:
        ``(H, A)`` shifted plan (a new tensor).
    """
    horizon = plan.shape[0]
    if not 0 <= steps <= horizon:
        raise ValueError(f"steps must be in [0, {horizon}], got {steps}")
    if pad not in ("repeat", "zero"):
        raise ValueError(f"pad must be 'repeat' or 'zero', got {pad!r}")
    kept = plan[steps:]  # (H - steps, A)
    if pad == "zero" or kept.shape[0] == 0:
        filler = torch.zeros_like(plan[:steps])
    else:
        filler = kept[-1:].expand(steps, -1)
    return torch.cat([kept, filler], dim=0)


class Optimizer(abc.ABC):
    """Maximises a batched objective over action sequences ``(H, A)`` in ``[-1, 1]``.

    Attributes:
        config_fields: The :data:`vp2.planning.config.OPTIMIZER_FIELDS` this optimizer reads,
            each with the constructor argument it sets (e.g. L-BFGS: ``grad_steps`` ->
            ``num_steps``).
    """

    config_fields: ClassVar[dict[str, str]] = {}

    @classmethod
    def settings(
        cls, config: PlannerConfig, sigma: list[float], num_samples: int
    ) -> dict[str, Any]:
        """This optimizer's constructor arguments for one task, as plain data.

        Called by :func:`vp2.planning.planner.planner_settings`, whose result every trial
        record carries: the arguments of :meth:`own_settings`, then those of
        :attr:`config_fields` and ``num_iterations`` where the config sets them, then the
        config's ``options`` (which override).

        Args:
            config: The run's planner.
            sigma: Noise scale per action dimension (the config's, else the env's).
            num_samples: The task's planner sample count (``Task.num_samples``).
        """
        kwargs = cls.own_settings(config, sigma, num_samples)
        for name, argument in cls.config_fields.items():
            if getattr(config, name) is not None:
                kwargs[argument] = getattr(config, name)
        if config.num_iterations is not None:
            kwargs["num_iterations"] = config.num_iterations
        kwargs.update(config.options)
        return kwargs

    @classmethod
    def own_settings(
        cls, config: PlannerConfig, sigma: list[float], num_samples: int
    ) -> dict[str, Any]:
        """The arguments only this optimizer takes from the config and the task (none here)."""
        return {}

    @abc.abstractmethod
    def optimize(
        self, objective: Objective, initial_mean: Tensor, generator: torch.Generator
    ) -> tuple[Tensor, OptimizerInfo]:
        """Plans one control step.

        Called by the planning agent at every control step.

        Args:
            objective: ``actions (N, H, A) -> scores (N,)``, higher is better.
            initial_mean: ``(H, A)`` starting point (warm start or zeros); its device and dtype
                are used throughout.
            generator: The only source of randomness.

        Returns:
            The plan ``(H, A)`` in ``[-1, 1]`` and an :class:`OptimizerInfo`.
        """

    def reset(self) -> None:  # noqa: B027 -- deliberately a no-op default, not abstract
        """Forgets per-trial state; called by the agent at the start of every trial.

        Stateless optimizers keep this default, which does nothing.
        """

    def trial_state(self) -> dict[str, Any]:
        """The per-trial state carried between planning steps (JSON-able), for a trial resumed
        mid-way (:mod:`vp2.run.partial`); stateless optimizers have none."""
        return {}

    def load_trial_state(self, state: dict[str, Any]) -> None:  # noqa: B027 -- stateless default
        """Restores what :meth:`trial_state` returned."""


def check_mean(initial_mean: Tensor) -> Tensor:
    """``initial_mean``, a float ``(H, A)`` tensor (checked), detached and clipped to the box."""
    if initial_mean.ndim != 2:
        raise ValueError(f"initial_mean must have shape (H, A), got {tuple(initial_mean.shape)}")
    if not initial_mean.is_floating_point():
        raise ValueError(f"initial_mean must be a float tensor, got {initial_mean.dtype}")
    return initial_mean.detach().clamp(ACTION_LOW, ACTION_HIGH)


class SamplingOptimizer(Optimizer):
    """Base of the optimizers that sample candidates around a mean (MPPI, CEM, CEM-GD).

    Args:
        sigma: Noise scale per action dimension ``(A,)`` (or ``(H, A)``).
        num_samples: Candidates per iteration. Validated here, the one check on its way from
            ``vp2 run --num-samples`` to the model (``RunConfig.validate`` builds the
            optimizer to surface it before any trial).
        num_iterations: Sampling iterations per call.
        sampler: Noise process; defaults to :class:`CorrelatedNoiseSampler` with ``β = 0.5``.
    """

    def __init__(
        self,
        sigma: Sequence[float] | Tensor,
        num_samples: int,
        num_iterations: int,
        sampler: ActionSampler | None,
    ) -> None:
        if num_samples < 1:
            raise ValueError(f"num_samples must be >= 1, got {num_samples}")
        if num_iterations < 1:
            raise ValueError(f"num_iterations must be >= 1, got {num_iterations}")
        self.num_samples = num_samples
        self.sigma = torch.as_tensor(sigma, dtype=torch.float64)
        self.num_iterations = num_iterations
        self.sampler = sampler if sampler is not None else CorrelatedNoiseSampler(spec.BETA)
