from __future__ import annotations

import numpy as np
import pytest
import torch

from vp2.metrics import gaussian_window, mse, psnr, ssim

skimage_metrics = pytest.importorskip("skimage.metrics")


def _pair(shape, noise, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(shape, generator=g, dtype=dtype)
    # Smooth structure plus noise, so SSIM lands well inside (0, 1).
    x = torch.nn.functional.avg_pool2d(x.reshape(-1, *shape[-3:]), 3, 1, 1).reshape(shape)
    y = (x + noise * torch.randn(shape, generator=g, dtype=dtype)).clamp(0, 1)
    return x, y


def _hwc(t: torch.Tensor) -> np.ndarray:
    return t.permute(1, 2, 0).numpy()


@pytest.mark.parametrize("noise", [0.02, 0.1, 0.3])
def test_ssim_and_psnr_match_scikit_image(noise):
    x, y = _pair((2, 3, 3, 32, 40), noise, seed=int(noise * 100))  # (B, T, 3, H, W)
    ours_ssim = ssim(x.float(), y.float())
    ours_psnr = psnr(x.float(), y.float())
    assert ours_ssim.shape == ours_psnr.shape == (2, 3)
    for b in range(2):
        for t in range(3):
            ref = skimage_metrics.structural_similarity(
                _hwc(x[b, t]),
                _hwc(y[b, t]),
                channel_axis=-1,
                data_range=1.0,
                gaussian_weights=True,
                sigma=1.5,
                use_sample_covariance=False,
            )
            assert abs(float(ours_ssim[b, t]) - ref) < 1e-3
            ref_psnr = skimage_metrics.peak_signal_noise_ratio(
                x[b, t].numpy(), y[b, t].numpy(), data_range=1.0
            )
            assert abs(float(ours_psnr[b, t]) - ref_psnr) < 1e-3
    # In float64 the agreement is to rounding.
    ref = skimage_metrics.structural_similarity(
        _hwc(x[0, 0]),
        _hwc(y[0, 0]),
        channel_axis=-1,
        data_range=1.0,
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
    )
    assert float(ssim(x, y)[0, 0]) == pytest.approx(ref, abs=1e-10)


def test_hand_made_values():
    x = torch.full((1, 3, 16, 16), 0.5)
    y = x + 0.1
    assert float(mse(x, y)) == pytest.approx(0.01, rel=1e-5)
    assert float(psnr(x, y)) == pytest.approx(20.0, abs=1e-4)
    assert float(psnr(x, x)) == float("inf")
    assert float(ssim(x, x)) == pytest.approx(1.0, abs=1e-6)
    # Constant images: SSIM reduces to the luminance term (2 mu_x mu_y + C1) / (mu_x^2 +
    # mu_y^2 + C1).
    c1 = 0.01**2
    assert float(ssim(x, y)) == pytest.approx((2 * 0.5 * 0.6 + c1) / (0.25 + 0.36 + c1), abs=1e-5)
    # An inverted checkerboard has the same means and variances but covariance -var.
    board = (torch.arange(16)[:, None] + torch.arange(16)[None, :]) % 2
    board = board.float().expand(1, 3, 16, 16)
    assert float(ssim(board, 1 - board)) < -0.9


def test_window_and_errors():
    g = gaussian_window()
    assert g.shape == (11,) and float(g.sum()) == pytest.approx(1.0)
    assert float(g[5] / g[6]) == pytest.approx(np.exp(0.5 / 1.5**2))
    with pytest.raises(ValueError, match="differ in shape"):
        mse(torch.zeros(1, 3, 8, 8), torch.zeros(1, 3, 8, 9))
    with pytest.raises(ValueError, match="divide uint8 by 255"):
        ssim(
            torch.zeros(1, 3, 16, 16, dtype=torch.uint8),
            torch.zeros(1, 3, 16, 16, dtype=torch.uint8),
        )
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(torch.zeros(1, 3, 8, 8), torch.zeros(1, 3, 8, 8))
