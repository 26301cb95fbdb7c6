"""Per-frame image metrics on batched torch tensors: MSE, PSNR, SSIM.

Every function takes two tensors of the same shape ``(..., 3, H, W)`` (any leading batch /
time dimensions), RGB in [0, 1], and returns one value per image, shape ``(...)``. They run on
the inputs' device; integer inputs are rejected (divide uint8 frames by 255).

SSIM follows Wang et al. 2004 with the usual settings (those of scikit-image's
``structural_similarity(..., gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
data_range=1)``): an 11x11 Gaussian window with sigma 1.5, ``K1 = 0.01``, ``K2 = 0.03``,
local statistics over the positions where the window fits inside the image, averaged over
those positions and over the colour channels.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.nn import functional as F

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


def _check(name: str, x: Tensor, y: Tensor) -> None:
    if x.shape != y.shape:
        raise ValueError(f"{name}: inputs differ in shape: {tuple(x.shape)} vs {tuple(y.shape)}")
    if x.dim() < 3:
        raise ValueError(f"{name}: expected (..., C, H, W) images, got {tuple(x.shape)}")
    if not (x.is_floating_point() and y.is_floating_point()):
        raise ValueError(f"{name}: expected floating point images in [0, 1] (divide uint8 by 255)")


def _float(x: Tensor) -> Tensor:
    return x if x.dtype == torch.float64 else x.float()


def mse(x: Tensor, y: Tensor) -> Tensor:
    """Mean squared error per image, over channels and pixels: ``(..., C, H, W) -> (...)``."""
    _check("mse", x, y)
    return ((_float(x) - _float(y)) ** 2).mean(dim=(-3, -2, -1))


def psnr(x: Tensor, y: Tensor, data_range: float = 1.0) -> Tensor:
    """Peak signal-to-noise ratio in dB per image, ``10 log10(range^2 / MSE)``;
    ``inf`` for identical images."""
    err = mse(x, y)
    return 10 * torch.log10(data_range**2 / err)


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> Tensor:
    """The normalised 1-D Gaussian ``(size,)`` whose outer product is SSIM's window."""
    r = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-0.5 * (r / sigma) ** 2)
    return g / g.sum()


def ssim(
    x: Tensor,
    y: Tensor,
    data_range: float = 1.0,
    window: int = SSIM_WINDOW,
    sigma: float = SSIM_SIGMA,
) -> Tensor:
    """Structural similarity per image (mean SSIM over valid positions and channels).

    Args:
        x, y: ``(..., C, H, W)`` images, ``H, W >= window``.
        data_range: The value range of the images (1 for [0, 1]).
        window, sigma: Gaussian window side and standard deviation.

    Returns:
        ``(...)``; computed in float32 (float64 for float64 inputs).
    """
    _check("ssim", x, y)
    if min(x.shape[-2:]) < window:
        raise ValueError(
            f"ssim: images must be at least {window}x{window}, got {tuple(x.shape[-2:])}"
        )
    lead, (c, h, w) = x.shape[:-3], x.shape[-3:]
    x = _float(x).reshape(-1, 1, h, w)  # channels as separate images
    y = _float(y).reshape(-1, 1, h, w)
    g = gaussian_window(window, sigma).to(x)

    def blur(z: Tensor) -> Tensor:
        # Separable Gaussian, no padding: only positions where the whole window fits.
        z = F.conv2d(z, g.view(1, 1, -1, 1))
        return F.conv2d(z, g.view(1, 1, 1, -1))

    # Variances and covariance from mean-free images: they are shift invariant, and
    # E[x^2] - E[x]^2 of raw [0, 1] values loses digits to cancellation in float32.
    xc = x - x.mean(dim=(-2, -1), keepdim=True)
    yc = y - y.mean(dim=(-2, -1), keepdim=True)
    stats = blur(torch.cat([x, y, xc, yc, xc * xc, yc * yc, xc * yc], dim=1).view(-1, 1, h, w))
    stats = stats.view(-1, 7, *stats.shape[-2:])
    mu_x, mu_y, mc_x, mc_y, xx, yy, xy = stats.unbind(1)
    var_x, var_y, cov = xx - mc_x**2, yy - mc_y**2, xy - mc_x * mc_y
    c1, c2 = (SSIM_K1 * data_range) ** 2, (SSIM_K2 * data_range) ** 2
    s = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / (
        (mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2)
    )
    return s.mean(dim=(-2, -1)).view(*lead, c).mean(-1)


__all__ = ["gaussian_window", "mse", "psnr", "ssim"]
