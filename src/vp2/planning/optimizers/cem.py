"""The cross-entropy method (model-specs §6)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torch import Tensor

from vp2 import spec
from vp2.planning.config import PlannerConfig
from vp2.planning.optimizers.base import (
    Objective,
    OptimizerInfo,
    SamplingOptimizer,
    check_mean,
    evaluate_objective,
)
from vp2.planning.samplers import ACTION_HIGH, ACTION_LOW, ActionSampler, broadcast_std


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


class CEM(SamplingOptimizer):
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

    config_fields = {"num_elites": "num_elites"}

    def __init__(
        self,
        sigma: Sequence[float] | Tensor,
        num_samples: int = spec.NUM_SAMPLES,
        num_iterations: int = 3,
        num_elites: int = 10,
        sampler: ActionSampler | None = None,
    ) -> None:
        if num_elites < 1:
            raise ValueError(f"num_elites must be >= 1, got {num_elites}")
        super().__init__(sigma, num_samples, num_iterations, sampler)
        self.num_elites = num_elites

    @classmethod
    def own_settings(
        cls, config: PlannerConfig, sigma: list[float], num_samples: int
    ) -> dict[str, Any]:
        """σ and the config's sample count (else the task's)."""
        samples = config.num_samples if config.num_samples is not None else num_samples
        return {"sigma": sigma, "num_samples": samples}

    def search(
        self,
        objective: Objective,
        initial_mean: Tensor,
        num_samples: int,
        generator: torch.Generator,
    ) -> tuple[Tensor, Tensor, list[float]]:
        """Runs the CEM iterations from ``initial_mean`` with ``num_samples`` per iteration.

        Returns:
            The last iteration's samples ``(N, H, A)`` and scores ``(N,)``, and the best score
            of every iteration.
        """
        mean = check_mean(initial_mean)  # (H, A)
        var = broadcast_std(self.sigma, mean) ** 2  # (H, A)
        num_elites = min(self.num_elites, num_samples)
        iteration_best: list[float] = []
        for _ in range(self.num_iterations):
            std = clamp_cem_variance(mean, var).sqrt()  # (H, A)
            samples = self.sampler.sample(mean, std, num_samples, generator)  # (N, H, A)
            with torch.no_grad():
                scores = evaluate_objective(objective, samples)  # (N,)
            elites = samples[torch.topk(scores, num_elites).indices]  # (K, H, A)
            mean = elites.mean(dim=0)
            var = elites.var(dim=0, unbiased=False)
            iteration_best.append(float(scores.max()))
        return samples, scores, iteration_best

    def optimize(
        self, objective: Objective, initial_mean: Tensor, generator: torch.Generator
    ) -> tuple[Tensor, OptimizerInfo]:
        samples, scores, iteration_best = self.search(
            objective, initial_mean, self.num_samples, generator
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
