"""The optimizers that need gradients of the scores with respect to the actions: CEM-GD and
L-BFGS. They raise :class:`~vp2.planning.optimizers.base.NotDifferentiableError` for an
objective without them."""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import Any, Literal

import torch
from torch import Tensor

from vp2.planning.config import PlannerConfig
from vp2.planning.optimizers.base import (
    Objective,
    Optimizer,
    OptimizerInfo,
    check_mean,
    scores_and_gradients,
)
from vp2.planning.optimizers.cem import CEM
from vp2.planning.samplers import ACTION_HIGH, ACTION_LOW, ActionSampler

log = logging.getLogger(__name__)


class CEMGD(CEM):
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

    config_fields = {
        "num_elites": "num_elites",
        "num_samples_first": "num_samples_first",
        "num_refined": "num_refined",
        "lr": "lr",
        "grad_steps": "max_steps",
    }

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
        if min(num_samples_first, num_refined) < 1:
            raise ValueError("num_samples_first and num_refined must be >= 1")
        if not 0 < shrink < 1:
            raise ValueError(f"shrink must be in (0, 1), got {shrink}")
        if not lr > 0 or max_steps < 1:
            raise ValueError(f"lr must be > 0 and max_steps >= 1, got {lr} and {max_steps}")
        super().__init__(sigma, num_samples, num_iterations, num_elites, sampler)
        self.num_samples_first, self.num_refined = num_samples_first, num_refined
        self.lr, self.betas, self.eps = lr, betas, eps
        self.shrink, self.max_failures, self.max_steps = shrink, max_failures, max_steps
        self._first_call = True

    @classmethod
    def own_settings(
        cls, config: PlannerConfig, sigma: list[float], num_samples: int
    ) -> dict[str, Any]:
        """σ, and the config's sample count only where it sets one: the task's count is for
        MPPI, CEM-GD keeps its own ``num_samples_first`` / ``num_samples`` defaults."""
        kwargs: dict[str, Any] = {"sigma": sigma}
        if config.num_samples is not None:
            kwargs["num_samples"] = config.num_samples
        return kwargs

    def reset(self) -> None:
        """Makes the next call use ``num_samples_first`` CEM samples again."""
        self._first_call = True

    def trial_state(self) -> dict[str, Any]:
        return {"first_call": self._first_call}

    def load_trial_state(self, state: dict[str, Any]) -> None:
        self._first_call = bool(state["first_call"])

    def optimize(
        self, objective: Objective, initial_mean: Tensor, generator: torch.Generator
    ) -> tuple[Tensor, OptimizerInfo]:
        num_samples = self.num_samples_first if self._first_call else self.num_samples
        self._first_call = False
        samples, scores, iteration_best = self.search(
            objective, initial_mean, num_samples, generator
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


class _NonFiniteStep(Exception):
    """L-BFGS's line search proposed a non-finite point (see :meth:`LBFGS.optimize`)."""


class LBFGS(Optimizer):
    """``torch.optim.LBFGS`` on a single action sequence (model-specs §6).

    The actions are parametrised as ``tanh(u)`` and L-BFGS optimises the unconstrained ``u``:
    every evaluated sequence lies inside ``(-1, 1)`` and the objective stays smooth, which
    L-BFGS's curvature estimates and the strong-Wolfe line search rely on (clamping would give
    zero gradients past the bounds and kinks at them). The start is ``atanh`` of the initial
    mean pulled ``boundary_eps`` inside the box, so that a saturated warm start still has a
    gradient. The plan is the best sequence evaluated. If the line search proposes a non-finite
    point (it can, on an objective that returns different scores for the same actions, as a
    model that samples its latents on every call does), the optimization stops there and the
    best sequence evaluated so far is the plan; the non-finite point is never evaluated.

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

    config_fields = {"lr": "lr", "grad_steps": "num_steps"}

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
        if num_steps < 1 or not lr > 0:
            raise ValueError(f"LBFGS needs num_steps >= 1 and lr > 0, got {num_steps} and {lr}")
        self.lr, self.num_steps, self.max_iter = lr, num_steps, max_iter
        self.history_size, self.line_search_fn = history_size, line_search_fn
        self.tolerance_change, self.tolerance_grad = tolerance_change, tolerance_grad
        self.boundary_eps = boundary_eps

    @classmethod
    def settings(
        cls, config: PlannerConfig, sigma: list[float], num_samples: int
    ) -> dict[str, Any]:
        """No σ and no sample count (one sequence, no sampling); ``options`` only.

        Raises:
            ValueError: if the config sets ``num_iterations``: L-BFGS has none.
        """
        if config.num_iterations is not None:
            raise ValueError("lbfgs has no sampling iterations; set options={'num_steps': ...}")
        return super().settings(config, sigma, num_samples)

    def optimize(
        self, objective: Objective, initial_mean: Tensor, generator: torch.Generator
    ) -> tuple[Tensor, OptimizerInfo]:
        mean = check_mean(initial_mean)  # (H, A)
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
            if not torch.isfinite(u).all():
                raise _NonFiniteStep
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
            try:
                loss = float(lbfgs.step(closure))
            except _NonFiniteStep:
                # The strong-Wolfe line search stepped to NaN: on a noisy objective (a model
                # that samples its latents anew on every call) it can evaluate one step length
                # twice, get two scores, and interpolate 0/0. Nothing better can follow.
                log.debug("LBFGS: the line search produced a non-finite step; stopping with "
                          "the best of %d evaluated sequences", len(scores_seen))
                break
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
