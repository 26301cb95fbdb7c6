"""MPPI, the benchmark's planner (SPEC §5)."""

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
from vp2.planning.samplers import ActionSampler, broadcast_std
from vp2.utils.fixedsum import softmax_weights, weighted_mean


def mppi_weights(scores: Tensor, gamma: float) -> Tensor:
    """MPPI weights ``w_n ∝ exp(γ · score_n)``, normalised to sum to 1.

    The softmax subtracts the maximum first, so large scores (pixel errors run to thousands)
    cannot overflow. ``γ`` multiplies the scores, as in the original VP² code and the paper's
    "scaling factor γ": it is an inverse temperature. Computed in float64 with the C library's
    ``exp`` and a correctly rounded sum (:func:`vp2.utils.fixedsum.softmax_weights`), so the
    weights are the same bits on every CPU; ``torch.softmax`` vectorises ``exp`` and its sum per
    CPU.

    Args:
        scores: ``(N,)`` scores.
        gamma: Inverse temperature ``γ >= 0``; ``0`` gives uniform weights.

    Returns:
        ``(N,)`` float64 weights on the scores' device.
    """
    return softmax_weights(scores, gamma)


class MPPI(SamplingOptimizer):
    """Model-predictive path integral planning, the benchmark's default planner (SPEC §5).

    Each iteration samples ``num_samples`` sequences around the mean with a fixed noise scale
    ``sigma`` and replaces the mean by their average weighted with :func:`mppi_weights`. The
    plan is the final mean. The benchmark runs one iteration per control step and gets
    refinement across steps from the warm start.

    Args:
        sigma: Noise scale per action dimension ``(A,)`` (or ``(H, A)``); see
            :data:`vp2.spec.SIGMA`.
        num_samples: Samples per iteration (200; 800 for ``open_slide``/``open_drawer``).
        gamma: Inverse temperature: weights ``∝ exp(gamma · score)``.
        num_iterations: Sampling iterations per call.
        sampler: Noise process; defaults to :class:`CorrelatedNoiseSampler` with ``β = 0.5``.
    """

    def __init__(
        self,
        sigma: Sequence[float] | Tensor,
        num_samples: int = spec.NUM_SAMPLES,
        gamma: float = spec.GAMMA,
        num_iterations: int = spec.NUM_ITERATIONS,
        sampler: ActionSampler | None = None,
    ) -> None:
        if gamma < 0:
            raise ValueError(f"gamma must be >= 0, got {gamma}")
        super().__init__(sigma, num_samples, num_iterations, sampler)
        self.gamma = gamma

    @classmethod
    def own_settings(
        cls, config: PlannerConfig, sigma: list[float], num_samples: int
    ) -> dict[str, Any]:
        """σ, the config's sample count (else the task's) and γ."""
        samples = config.num_samples if config.num_samples is not None else num_samples
        return {"sigma": sigma, "num_samples": samples, "gamma": config.gamma}

    def optimize(
        self, objective: Objective, initial_mean: Tensor, generator: torch.Generator
    ) -> tuple[Tensor, OptimizerInfo]:
        mean = check_mean(initial_mean)  # (H, A)
        std = broadcast_std(self.sigma, mean)  # (H, A)
        iteration_best: list[float] = []
        for _ in range(self.num_iterations):
            samples = self.sampler.sample(mean, std, self.num_samples, generator)  # (N, H, A)
            with torch.no_grad():
                scores = evaluate_objective(objective, samples)  # (N,)
            weights = mppi_weights(scores, self.gamma)  # (N,) float64
            # The weighted mean added pairwise in a fixed order, not a BLAS product whose
            # kernel (and so its last bits) is chosen per CPU.
            mean = weighted_mean(weights, samples)  # (H, A)
            iteration_best.append(float(scores.max()))
        info = OptimizerInfo(
            best_score=max(iteration_best),
            plan_score=None,
            num_evaluations=self.num_samples * self.num_iterations,
            num_objective_calls=self.num_iterations,
            iteration_best_scores=iteration_best,
        )
        return mean, info
