"""Action samplers: draw candidate action sequences around a mean sequence.

Sampling-based optimizers (:class:`~vp2.planning.optimizers.MPPI`,
:class:`~vp2.planning.optimizers.CEM`) call :meth:`ActionSampler.sample` once per iteration to
get ``N`` candidate sequences of ``H`` actions of dimension ``A``. Samples are always clipped to
the action box ``[-1, 1]``.

The benchmark's sampler is :class:`CorrelatedNoiseSampler` (SPEC §5): along the horizon the noise
is an AR(1) process

    n_0 = σ_0 ε_0,        n_t = β n_{t-1} + (1 - β) σ_t ε_t,        ε_t ~ N(0, I),

with ``β = 0.5``, so that sampled action sequences are smooth in time. With a constant ``σ`` the
per-step variance starts at ``σ²`` and decays towards ``σ² (1 - β) / (1 + β)`` (``σ²/3`` for
``β = 0.5``); :func:`correlated_noise_std` gives it exactly.

Randomness only ever comes from the ``torch.Generator`` passed in. Noise is drawn on the
generator's device and then moved to the mean's device, so a CPU generator gives the same
samples whether planning runs on a CPU or a GPU. Float32 noise from a CPU generator is
:func:`vp2.utils.fixedsum.normal_float32`, the numbers of ``torch.randn`` on any CPU (torch's
own differ in the last bits where ATen runs its AVX2 kernels), and the AR(1) recursion
multiplies and adds in two correctly rounded steps, so samples are the same bits on every CPU.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Sequence

import torch
from torch import Tensor

from vp2 import spec
from vp2.utils.fixedsum import normal_float32

ACTION_LOW = -1.0
ACTION_HIGH = 1.0


def standard_normal(shape: Sequence[int], generator: torch.Generator, like: Tensor) -> Tensor:
    """Draws ``N(0, 1)`` noise from ``generator`` with the dtype and device of ``like``.

    The draw happens on the generator's own device (torch requires it) and is then moved, which
    keeps results independent of where the planner runs. Float32 from a CPU generator goes
    through :func:`~vp2.utils.fixedsum.normal_float32`: the same bits on every CPU.
    """
    shape = tuple(shape)
    if generator.device.type == "cpu" and like.dtype == torch.float32:
        noise = normal_float32(math.prod(shape), generator).view(shape)
    else:
        noise = torch.randn(shape, generator=generator, device=generator.device, dtype=like.dtype)
    return noise.to(like.device)


def broadcast_std(std: Tensor | Sequence[float] | float, mean: Tensor) -> Tensor:
    """Returns ``std`` as a tensor of ``mean``'s shape ``(H, A)``, dtype and device.

    Accepts a scalar, a per-dimension ``(A,)`` vector or a full ``(H, A)`` array.
    """
    std_t = torch.as_tensor(std).to(mean)
    if std_t.ndim == 1 and std_t.shape[0] != mean.shape[-1]:
        raise ValueError(
            f"std has {std_t.shape[0]} entries but actions have dimension {mean.shape[-1]}"
        )
    if bool((std_t < 0).any()):
        raise ValueError("std must be non-negative")
    return std_t.expand_as(mean)


def correlated_noise_std(
    horizon: int, sigma: Tensor | Sequence[float], beta: float = spec.BETA
) -> Tensor:
    """Exact per-step standard deviation of :class:`CorrelatedNoiseSampler` noise.

    With ``v_0 = σ²`` and ``v_t = β² v_{t-1} + (1 - β)² σ²`` (the ε are independent).

    Args:
        horizon: Number of steps ``H``.
        sigma: Per-dimension scales ``(A,)``.
        beta: Correlation coefficient.

    Returns:
        ``(H, A)`` standard deviations.
    """
    sigma_t = torch.as_tensor(sigma, dtype=torch.float64)
    var = [sigma_t**2]
    for _ in range(1, horizon):
        var.append(beta**2 * var[-1] + (1 - beta) ** 2 * sigma_t**2)
    return torch.stack(var).sqrt()  # (H, A)


class ActionSampler(abc.ABC):
    """Draws candidate action sequences around a mean, clipped to ``[-1, 1]``.

    Subclasses define the noise process in :meth:`noise`; :meth:`sample` adds it to the mean and
    clips. Optimizers call :meth:`sample` once per iteration.
    """

    @abc.abstractmethod
    def noise(self, num_samples: int, std: Tensor, generator: torch.Generator) -> Tensor:
        """Zero-mean noise for ``num_samples`` sequences.

        Args:
            num_samples: Number of sequences ``N``.
            std: ``(H, A)`` noise scales per step and action dimension.
            generator: Source of randomness.

        Returns:
            ``(N, H, A)`` noise with ``std``'s dtype and device.
        """

    def sample(
        self,
        mean: Tensor,
        std: Tensor | Sequence[float] | float,
        num_samples: int,
        generator: torch.Generator,
    ) -> Tensor:
        """Draws ``num_samples`` sequences ``mean + noise``, clipped to ``[-1, 1]``.

        Args:
            mean: ``(H, A)`` mean action sequence.
            std: Noise scale: scalar, ``(A,)`` or ``(H, A)``.
            num_samples: Number of sequences ``N``.
            generator: Source of randomness.

        Returns:
            ``(N, H, A)`` action sequences in ``[-1, 1]``.
        """
        if mean.ndim != 2:
            raise ValueError(f"mean must have shape (H, A), got {tuple(mean.shape)}")
        std_t = broadcast_std(std, mean)  # (H, A)
        samples = mean + self.noise(num_samples, std_t, generator)  # (N, H, A)
        return samples.clamp_(ACTION_LOW, ACTION_HIGH)


class GaussianSampler(ActionSampler):
    """Independent Gaussian noise at every step: ``n_t = σ_t ε_t``."""

    def noise(self, num_samples: int, std: Tensor, generator: torch.Generator) -> Tensor:
        eps = standard_normal((num_samples, *std.shape), generator, std)  # (N, H, A)
        return eps * std


class CorrelatedNoiseSampler(ActionSampler):
    """AR(1) noise along the horizon (SPEC §5): ``n_t = β n_{t-1} + (1 - β) σ_t ε_t``.

    Args:
        beta: Correlation coefficient ``β`` in ``[0, 1)``; ``β = 0`` gives the white noise of
            :class:`GaussianSampler`.
    """

    def __init__(self, beta: float = spec.BETA) -> None:
        if not 0.0 <= beta < 1.0:
            raise ValueError(f"beta must be in [0, 1), got {beta}")
        self.beta = float(beta)

    def noise(self, num_samples: int, std: Tensor, generator: torch.Generator) -> Tensor:
        eps = standard_normal((num_samples, *std.shape), generator, std)  # (N, H, A)
        innovation = eps * std  # (N, H, A): σ_t ε_t
        innovation[:, 1:] *= 1 - self.beta  # the first step enters without the (1 - β) factor
        # A short loop of single-threaded element-wise ops over the horizon: the equivalent
        # (H, H) filter matrix product is faster on an idle CPU but goes through a threaded
        # GEMM that stalls for milliseconds when the cores are shared. Multiply, then add:
        # torch.add(..., alpha=β) is one fused multiply-add in ATen's vector kernels and two
        # roundings in its scalar ones, so its last bits depend on the CPU.
        noise = torch.empty_like(innovation)
        noise[:, 0] = innovation[:, 0]
        for t in range(1, std.shape[0]):
            torch.add(innovation[:, t], noise[:, t - 1] * self.beta, out=noise[:, t])
        return noise
