"""Statistics and contracts of the action samplers (SPEC §5)."""

from __future__ import annotations

import pytest
import torch

from vp2.planning.samplers import (
    CorrelatedNoiseSampler,
    GaussianSampler,
    correlated_noise_std,
)
from vp2.spec import SIGMA

NUM = 20_000  # samples for the statistics: standard errors ~1/sqrt(NUM) = 0.007
HORIZON = 10


def _lag1_correlation(x: torch.Tensor) -> torch.Tensor:
    """Correlation between steps t-1 and t over samples: (N, H, A) -> (H-1, A)."""
    a, b = x[:, :-1], x[:, 1:]
    a = a - a.mean(0)
    b = b - b.mean(0)
    return (a * b).mean(0) / (a.std(0, unbiased=False) * b.std(0, unbiased=False))


def test_correlated_noise_follows_the_recursion_exactly() -> None:
    sigma = torch.tensor([0.5, 0.2, 0.1])
    std = sigma.expand(HORIZON, 3)
    sampler = CorrelatedNoiseSampler(beta=0.5)
    noise = sampler.noise(7, std, torch.Generator().manual_seed(3))
    # Same draws, unrolled by hand: n_0 = σ ε_0, n_t = β n_{t-1} + (1 - β) σ ε_t.
    eps = torch.randn((7, HORIZON, 3), generator=torch.Generator().manual_seed(3))
    expected = [sigma * eps[:, 0]]
    for t in range(1, HORIZON):
        expected.append(0.5 * expected[-1] + 0.5 * sigma * eps[:, t])
    torch.testing.assert_close(noise, torch.stack(expected, dim=1))


def test_correlated_samples_have_the_implied_mean_std_and_correlation() -> None:
    beta = 0.5
    sigma = torch.tensor([0.1, 0.05, 0.0])  # small: clipping at ±1 never happens around 0.2
    mean = torch.full((HORIZON, 3), 0.2)
    samples = CorrelatedNoiseSampler(beta).sample(
        mean, sigma, NUM, torch.Generator().manual_seed(0)
    )

    assert samples.shape == (NUM, HORIZON, 3)
    torch.testing.assert_close(samples.mean(0), mean, atol=4 * 0.1 / NUM**0.5, rtol=0)
    expected_std = correlated_noise_std(HORIZON, sigma, beta).float()  # (H, A)
    torch.testing.assert_close(samples.std(0)[:, :2], expected_std[:, :2], rtol=0.03, atol=0)
    assert torch.equal(samples[..., 2], mean[..., 2].expand(NUM, HORIZON))  # σ = 0: no noise

    var = expected_std[:, :2] ** 2
    expected_corr = beta * (var[:-1] / var[1:]).sqrt()  # Cov(n_{t-1}, n_t) = β Var(n_{t-1})
    torch.testing.assert_close(
        _lag1_correlation(samples[..., :2]), expected_corr, atol=0.03, rtol=0
    )


def test_correlated_noise_std_decays_to_the_stationary_value() -> None:
    std = correlated_noise_std(50, [0.5], beta=0.5)
    assert std[0, 0] == pytest.approx(0.5)
    assert std[1, 0] == pytest.approx((0.25 * 0.25 + 0.25 * 0.25) ** 0.5)
    assert std[-1, 0] == pytest.approx(0.5 * (0.5 / 1.5) ** 0.5)  # σ √((1-β)/(1+β))


def test_gaussian_samples_are_uncorrelated_with_std_sigma() -> None:
    sigma = torch.tensor([0.1, 0.05])
    samples = GaussianSampler().sample(
        torch.zeros(HORIZON, 2), sigma, NUM, torch.Generator().manual_seed(1)
    )
    torch.testing.assert_close(samples.std(0), sigma.expand(HORIZON, 2), rtol=0.03, atol=0)
    assert _lag1_correlation(samples).abs().max() < 0.03


@pytest.mark.parametrize("sampler", [GaussianSampler(), CorrelatedNoiseSampler()])
def test_samples_are_clipped_to_the_action_box(sampler) -> None:
    mean = torch.full((HORIZON, 5), 0.9)
    mean[:, 1] = -0.9
    samples = sampler.sample(
        mean, SIGMA["robodesk"], 2_000, torch.Generator().manual_seed(2)
    )
    assert samples.min() >= -1.0 and samples.max() <= 1.0
    assert (samples[..., 0] == 1.0).any() and (samples[..., 1] == -1.0).any()  # clipping happened


def test_sampling_is_determined_by_the_generator() -> None:
    sampler = CorrelatedNoiseSampler()
    mean = torch.zeros(HORIZON, 4)
    draw = lambda seed: sampler.sample(  # noqa: E731
        mean, SIGMA["tabletop"], 16, torch.Generator().manual_seed(seed)
    )
    assert torch.equal(draw(5), draw(5))
    assert not torch.equal(draw(5), draw(6))
    assert torch.equal(draw(5)[..., 3], torch.zeros(16, HORIZON))  # tabletop gripper is fixed


def test_samples_keep_the_mean_dtype() -> None:
    mean = torch.zeros(HORIZON, 2, dtype=torch.float64)
    samples = CorrelatedNoiseSampler().sample(mean, 0.3, 4, torch.Generator().manual_seed(0))
    assert samples.dtype == torch.float64


def test_bad_arguments_raise() -> None:
    sampler = CorrelatedNoiseSampler()
    g = torch.Generator().manual_seed(0)
    with pytest.raises(ValueError, match="entries"):
        sampler.sample(torch.zeros(HORIZON, 4), [0.5, 0.5], 4, g)
    with pytest.raises(ValueError, match="shape"):
        sampler.sample(torch.zeros(HORIZON), 0.5, 4, g)
    with pytest.raises(ValueError, match="non-negative"):
        sampler.sample(torch.zeros(HORIZON, 1), [-0.1], 4, g)
    with pytest.raises(ValueError, match="beta"):
        CorrelatedNoiseSampler(beta=1.0)
