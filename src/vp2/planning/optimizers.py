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
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

import torch
from torch import Tensor

from vp2.planning.samplers import (
    ACTION_HIGH,
    ACTION_LOW,
    DEFAULT_BETA,
    ActionSampler,
    CorrelatedNoiseSampler,
    broadcast_std,
)

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


def mppi_weights(scores: Tensor, gamma: float) -> Tensor:
    """MPPI weights ``w_n ∝ exp(γ · score_n)``, normalised to sum to 1.

    ``softmax`` subtracts the maximum first, so large scores (pixel errors run to thousands)
    cannot overflow. ``γ`` multiplies the scores, as in the original VP² code and the paper's
    "scaling factor γ": it is an inverse temperature.

    Args:
        scores: ``(N,)`` scores.
        gamma: Inverse temperature ``γ >= 0``; ``0`` gives uniform weights.

    Returns:
        ``(N,)`` weights.
    """
    return torch.softmax(gamma * scores, dim=0)


def clamp_cem_variance(mean: Tensor, var: Tensor) -> Tensor:
    """Limits CEM's sampling variance near the action bounds.

    ``var <= min(((μ + 1) / 2)², ((1 - μ) / 2)²)``: two standard deviations never reach past
    ``-1`` or ``1``, so clipping distorts the sampling distribution little.

    Args:
        mean: ``(H, A)`` mean.
        var: ``(H, A)`` variance.

    Returns:
        ``(H, A)`` clamped variance.
    """
    to_low = ((mean - ACTION_LOW) / 2) ** 2
    to_high = ((ACTION_HIGH - mean) / 2) ** 2
    return torch.minimum(var, torch.minimum(to_low, to_high))


class Optimizer(abc.ABC):
    """Maximises a batched objective over action sequences ``(H, A)`` in ``[-1, 1]``."""

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


def _check_mean(initial_mean: Tensor) -> Tensor:
    if initial_mean.ndim != 2:
        raise ValueError(f"initial_mean must have shape (H, A), got {tuple(initial_mean.shape)}")
    if not initial_mean.is_floating_point():
        raise ValueError(f"initial_mean must be a float tensor, got {initial_mean.dtype}")
    return initial_mean.detach().clamp(ACTION_LOW, ACTION_HIGH)


class MPPI(Optimizer):
    """Model-predictive path integral planning, the benchmark's default planner (SPEC §5).

    Each iteration samples ``num_samples`` sequences around the mean with a fixed noise scale
    ``sigma`` and replaces the mean by their average weighted with :func:`mppi_weights`. The
    plan is the final mean. The benchmark runs one iteration per control step and gets
    refinement across steps from the warm start.

    Args:
        sigma: Noise scale per action dimension ``(A,)`` (or ``(H, A)``); see
            :data:`vp2.planning.samplers.DEFAULT_SIGMA`.
        num_samples: Samples per iteration (200; 800 for ``open_slide``/``open_drawer``).
        gamma: Inverse temperature: weights ``∝ exp(gamma · score)``.
        num_iterations: Sampling iterations per call.
        sampler: Noise process; defaults to :class:`CorrelatedNoiseSampler` with ``β = 0.5``.
    """

    def __init__(
        self,
        sigma: Sequence[float] | Tensor,
        num_samples: int = 200,
        gamma: float = 0.05,
        num_iterations: int = 1,
        sampler: ActionSampler | None = None,
    ) -> None:
        if num_samples < 1 or num_iterations < 1:
            raise ValueError("num_samples and num_iterations must be >= 1")
        if gamma < 0:
            raise ValueError(f"gamma must be >= 0, got {gamma}")
        self.sigma = torch.as_tensor(sigma, dtype=torch.float64)
        self.num_samples = num_samples
        self.gamma = gamma
        self.num_iterations = num_iterations
        self.sampler = sampler if sampler is not None else CorrelatedNoiseSampler(DEFAULT_BETA)

    def optimize(
        self, objective: Objective, initial_mean: Tensor, generator: torch.Generator
    ) -> tuple[Tensor, OptimizerInfo]:
        mean = _check_mean(initial_mean)  # (H, A)
        std = broadcast_std(self.sigma, mean)  # (H, A)
        iteration_best: list[float] = []
        for _ in range(self.num_iterations):
            samples = self.sampler.sample(mean, std, self.num_samples, generator)  # (N, H, A)
            with torch.no_grad():
                scores = evaluate_objective(objective, samples)  # (N,)
            weights = mppi_weights(scores.to(samples), self.gamma)  # (N,)
            mean = (weights @ samples.flatten(1)).view_as(mean)  # (H, A) weighted mean
            iteration_best.append(float(scores.max()))
        info = OptimizerInfo(
            best_score=max(iteration_best),
            plan_score=None,
            num_evaluations=self.num_samples * self.num_iterations,
            num_objective_calls=self.num_iterations,
            iteration_best_scores=iteration_best,
        )
        return mean, info


def _cem_search(
    objective: Objective,
    mean: Tensor,
    var: Tensor,
    sampler: ActionSampler,
    num_samples: int,
    num_iterations: int,
    num_elites: int,
    generator: torch.Generator,
) -> tuple[Tensor, Tensor, list[float]]:
    """Runs CEM; returns the last iteration's samples ``(N, H, A)``, scores ``(N,)`` and the
    best score of every iteration."""
    num_elites = min(num_elites, num_samples)
    iteration_best: list[float] = []
    for _ in range(num_iterations):
        std = clamp_cem_variance(mean, var).sqrt()  # (H, A)
        samples = sampler.sample(mean, std, num_samples, generator)  # (N, H, A)
        with torch.no_grad():
            scores = evaluate_objective(objective, samples)  # (N,)
        elites = samples[torch.topk(scores, num_elites).indices]  # (K, H, A)
        mean = elites.mean(dim=0)
        var = elites.var(dim=0, unbiased=False)
        iteration_best.append(float(scores.max()))
    return samples, scores, iteration_best


class CEM(Optimizer):
    """Cross-entropy method (model-specs §6).

    Each iteration samples around the mean with the variance limited by
    :func:`clamp_cem_variance`, then refits mean and variance to the ``num_elites`` best
    samples. Returns the best sample of the last iteration.

    Args:
        sigma: Initial standard deviation per action dimension ``(A,)`` (or ``(H, A)``).
        num_samples: Samples per iteration.
        num_iterations: Iterations per call.
        num_elites: Number of best samples the distribution is refitted to.
        sampler: Noise process; defaults to :class:`CorrelatedNoiseSampler` with ``β = 0.5``.
    """

    def __init__(
        self,
        sigma: Sequence[float] | Tensor,
        num_samples: int = 200,
        num_iterations: int = 3,
        num_elites: int = 10,
        sampler: ActionSampler | None = None,
    ) -> None:
        if num_samples < 1 or num_iterations < 1 or num_elites < 1:
            raise ValueError("num_samples, num_iterations and num_elites must be >= 1")
        self.sigma = torch.as_tensor(sigma, dtype=torch.float64)
        self.num_samples = num_samples
        self.num_iterations = num_iterations
        self.num_elites = num_elites
        self.sampler = sampler if sampler is not None else CorrelatedNoiseSampler(DEFAULT_BETA)

    def optimize(
        self, objective: Objective, initial_mean: Tensor, generator: torch.Generator
    ) -> tuple[Tensor, OptimizerInfo]:
        mean = _check_mean(initial_mean)  # (H, A)
        var = broadcast_std(self.sigma, mean) ** 2  # (H, A)
        samples, scores, iteration_best = _cem_search(
            objective,
            mean,
            var,
            self.sampler,
            self.num_samples,
            self.num_iterations,
            self.num_elites,
            generator,
        )
        best = int(torch.argmax(scores))
        info = OptimizerInfo(
            best_score=max(iteration_best),
            plan_score=float(scores[best]),
            num_evaluations=self.num_samples * self.num_iterations,
            num_objective_calls=self.num_iterations,
            iteration_best_scores=iteration_best,
        )
        return samples[best].clone(), info


class CEMGD(Optimizer):
    """CEM followed by gradient refinement of its best sequences (CEM-GD, Huang et al. 2021).

    The CEM stage uses ``num_samples_first`` samples on the first call after :meth:`reset` and
    ``num_samples`` afterwards (a warm-started mean needs fewer). The ``num_refined`` best
    samples of CEM's last iteration are then refined, each independently and all in one batch,
    by projected Adam ascent on the score with backtracking:

    * a step is ``x <- clamp(x + lr · factor · m̂ / (√v̂ + eps), -1, 1)`` (Adam's bias-corrected
      moments of the score gradient, then the Euclidean projection onto the action box);
    * a step is accepted only if the score strictly improves; then the Adam moments advance
      and ``factor`` resets to 1;
    * otherwise the step is undone (moments included) and retried with ``factor`` halved;
      a sequence stops after ``max_failures`` consecutive failures or ``max_steps`` accepted
      steps.

    The original code clamped the actions to the lower bound and never stopped backtracking
    correctly; this is the intended algorithm. The plan is the best refined sequence, so it is
    never worse than CEM's best (for a deterministic objective).

    Args:
        sigma: Initial CEM standard deviation per action dimension.
        num_samples_first: CEM samples per iteration on the first call of a trial.
        num_samples: CEM samples per iteration on later calls.
        num_iterations: CEM iterations.
        num_elites: CEM elites.
        num_refined: Number of best CEM samples refined by gradient ascent.
        lr: Adam step size.
        shrink: Factor applied to the step after a failed step.
        max_failures: Consecutive failed steps after which refinement of a sequence stops.
        max_steps: Accepted steps after which refinement of a sequence stops.
        betas: Adam moment decay rates.
        eps: Adam denominator offset.
        sampler: CEM noise process; defaults to :class:`CorrelatedNoiseSampler`.
    """

    def __init__(
        self,
        sigma: Sequence[float] | Tensor,
        num_samples_first: int = 500,
        num_samples: int = 50,
        num_iterations: int = 3,
        num_elites: int = 10,
        num_refined: int = 1,
        lr: float = 1e-2,
        shrink: float = 0.5,
        max_failures: int = 7,
        max_steps: int = 15,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
        sampler: ActionSampler | None = None,
    ) -> None:
        if min(num_samples_first, num_samples, num_iterations, num_elites, num_refined) < 1:
            raise ValueError("sample, iteration, elite and refined counts must be >= 1")
        if not 0 < shrink < 1:
            raise ValueError(f"shrink must be in (0, 1), got {shrink}")
        self.sigma = torch.as_tensor(sigma, dtype=torch.float64)
        self.num_samples_first = num_samples_first
        self.num_samples = num_samples
        self.num_iterations = num_iterations
        self.num_elites = num_elites
        self.num_refined = num_refined
        self.lr = lr
        self.shrink = shrink
        self.max_failures = max_failures
        self.max_steps = max_steps
        self.betas = betas
        self.eps = eps
        self.sampler = sampler if sampler is not None else CorrelatedNoiseSampler(DEFAULT_BETA)
        self._first_call = True

    def reset(self) -> None:
        """Makes the next call use ``num_samples_first`` CEM samples again."""
        self._first_call = True

    def optimize(
        self, objective: Objective, initial_mean: Tensor, generator: torch.Generator
    ) -> tuple[Tensor, OptimizerInfo]:
        num_samples = self.num_samples_first if self._first_call else self.num_samples
        self._first_call = False
        mean = _check_mean(initial_mean)  # (H, A)
        var = broadcast_std(self.sigma, mean) ** 2  # (H, A)
        samples, scores, iteration_best = _cem_search(
            objective,
            mean,
            var,
            self.sampler,
            num_samples,
            self.num_iterations,
            self.num_elites,
            generator,
        )
        top = torch.topk(scores, min(self.num_refined, num_samples)).indices
        refined, refined_scores, steps_best, calls, evaluations = self.refine(
            objective, samples[top]
        )
        best = int(torch.argmax(refined_scores))
        info = OptimizerInfo(
            best_score=max(max(iteration_best), float(refined_scores[best])),
            plan_score=float(refined_scores[best]),
            num_evaluations=num_samples * self.num_iterations + evaluations,
            num_objective_calls=self.num_iterations + calls,
            iteration_best_scores=iteration_best + steps_best,
        )
        return refined[best], info

    def refine(
        self, objective: Objective, start: Tensor
    ) -> tuple[Tensor, Tensor, list[float], int, int]:
        """Projected Adam ascent with backtracking from each of ``start``'s sequences.

        Args:
            objective: Differentiable batched objective.
            start: ``(K, H, A)`` sequences in ``[-1, 1]``.

        Returns:
            Refined sequences ``(K, H, A)``, their scores ``(K,)``, the best score after each
            round, the number of objective calls and of scored sequences.
        """
        beta1, beta2 = self.betas
        x = start.detach().clone()  # (K, H, A) accepted points
        score, grad = scores_and_gradients(objective, x, "CEMGD")  # (K,), (K, H, A)
        calls, evaluations = 1, x.shape[0]
        m = torch.zeros_like(x)  # Adam first moment
        v = torch.zeros_like(x)  # Adam second moment
        num_adam_steps = torch.zeros(x.shape[0], dtype=torch.long)
        factor = torch.ones(x.shape[0], dtype=torch.float64)
        failures = torch.zeros(x.shape[0], dtype=torch.long)
        accepted = torch.zeros(x.shape[0], dtype=torch.long)
        active = torch.ones(x.shape[0], dtype=torch.bool)
        rounds_best: list[float] = []
        while bool(active.any()):
            # Bookkeeping lives on the CPU; index the (possibly CUDA) tensors with device copies.
            idx = active.nonzero().squeeze(1)  # (k,) still-refining sequences
            idx_d = idx.to(x.device)
            # A tentative Adam step; the moments are committed only if the step is accepted,
            # so a retry after a failure reuses the same gradient and state with a smaller step.
            g = grad[idx_d]
            m_new = beta1 * m[idx_d] + (1 - beta1) * g
            v_new = beta2 * v[idx_d] + (1 - beta2) * g * g
            t = (num_adam_steps[idx] + 1).to(torch.float64)
            m_hat = m_new / (1 - beta1**t).to(x)[:, None, None]
            v_hat = v_new / (1 - beta2**t).to(x)[:, None, None]
            step_size = (self.lr * factor[idx]).to(x)[:, None, None]
            step = step_size * m_hat / (v_hat.sqrt() + self.eps)
            candidate = (x[idx_d] + step).clamp(ACTION_LOW, ACTION_HIGH)  # (k, H, A)
            cand_score, cand_grad = scores_and_gradients(objective, candidate, "CEMGD")
            calls += 1
            evaluations += candidate.shape[0]

            improved_d = cand_score > score[idx_d]  # (k,) strict improvement only
            improved = improved_d.cpu()
            ok, bad = idx[improved], idx[~improved]
            ok_d = ok.to(x.device)
            x[ok_d] = candidate[improved_d]
            score[ok_d] = cand_score[improved_d]
            grad[ok_d] = cand_grad[improved_d]
            m[ok_d] = m_new[improved_d]
            v[ok_d] = v_new[improved_d]
            num_adam_steps[ok] += 1
            factor[ok] = 1.0
            failures[ok] = 0
            accepted[ok] += 1
            factor[bad] *= self.shrink
            failures[bad] += 1
            active &= (failures < self.max_failures) & (accepted < self.max_steps)
            rounds_best.append(float(score.max()))
        return x, score, rounds_best, calls, evaluations


class LBFGS(Optimizer):
    """``torch.optim.LBFGS`` on a single action sequence (model-specs §6).

    The actions are parametrised as ``tanh(u)`` and L-BFGS optimises the unconstrained ``u``:
    every evaluated sequence lies inside ``(-1, 1)`` and the objective stays smooth, which
    L-BFGS's curvature estimates and the strong-Wolfe line search rely on (clamping would give
    zero gradients past the bounds and kinks at them). The start is ``atanh`` of the initial
    mean pulled ``boundary_eps`` inside the box, so that a saturated warm start still has a
    gradient. The plan is the best sequence evaluated.

    ``lr`` is L-BFGS's initial step length (the paper tuned it over 1e-3, 1e-2, 5e-2, 7e-2).
    The optimizer is deterministic and ignores the generator.

    Args:
        lr: Step length of ``torch.optim.LBFGS``.
        num_steps: Calls of ``LBFGS.step`` (the original ran 100); stops early once the loss
            changes by less than ``tolerance_change`` between calls.
        max_iter: L-BFGS iterations per step call.
        history_size: L-BFGS memory.
        tolerance_change: L-BFGS's tolerance on loss and step changes.
        tolerance_grad: L-BFGS's tolerance on the gradient.
        line_search_fn: ``"strong_wolfe"`` or ``None``.
        boundary_eps: How far inside ``[-1, 1]`` the initial mean is pulled.
    """

    def __init__(
        self,
        lr: float = 5e-2,
        num_steps: int = 100,
        max_iter: int = 20,
        history_size: int = 100,
        tolerance_change: float = 1e-4,
        tolerance_grad: float = 1e-7,
        line_search_fn: Literal["strong_wolfe"] | None = "strong_wolfe",
        boundary_eps: float = 1e-3,
    ) -> None:
        if num_steps < 1:
            raise ValueError("num_steps must be >= 1")
        self.lr = lr
        self.num_steps = num_steps
        self.max_iter = max_iter
        self.history_size = history_size
        self.tolerance_change = tolerance_change
        self.tolerance_grad = tolerance_grad
        self.line_search_fn = line_search_fn
        self.boundary_eps = boundary_eps

    def optimize(
        self, objective: Objective, initial_mean: Tensor, generator: torch.Generator
    ) -> tuple[Tensor, OptimizerInfo]:
        mean = _check_mean(initial_mean)  # (H, A)
        start = mean.clamp(ACTION_LOW + self.boundary_eps, ACTION_HIGH - self.boundary_eps)
        u = torch.atanh(start).requires_grad_(True)  # (H, A) unconstrained
        lbfgs = torch.optim.LBFGS(
            [u],
            lr=self.lr,
            max_iter=self.max_iter,
            history_size=self.history_size,
            tolerance_change=self.tolerance_change,
            tolerance_grad=self.tolerance_grad,
            line_search_fn=self.line_search_fn,
        )
        best_score = -math.inf
        best_actions = start.clone()
        scores_seen: list[float] = []

        def closure() -> Tensor:
            nonlocal best_score, best_actions
            actions = torch.tanh(u.detach())  # (H, A)
            score, grad = scores_and_gradients(objective, actions[None], "LBFGS")  # (1,), (1, H, A)
            # Chain rule through tanh by hand: d(-score)/du = -grad * (1 - tanh(u)^2).
            u.grad = -grad[0] * (1 - actions**2)
            value = float(score[0])
            scores_seen.append(value)
            if value > best_score:
                best_score, best_actions = value, actions.clone()
            return -score[0]

        previous = None
        for _ in range(self.num_steps):
            loss = float(lbfgs.step(closure))
            if previous is not None and abs(previous - loss) < self.tolerance_change:
                break
            previous = loss
        info = OptimizerInfo(
            best_score=best_score,
            plan_score=best_score,
            num_evaluations=len(scores_seen),
            num_objective_calls=len(scores_seen),
            iteration_best_scores=scores_seen,
        )
        return best_actions, info


#: Optimizers by the names configs use.
OPTIMIZERS: dict[str, type[Optimizer]] = {
    "mppi": MPPI,
    "cem": CEM,
    "cem_gd": CEMGD,
    "lbfgs": LBFGS,
}
