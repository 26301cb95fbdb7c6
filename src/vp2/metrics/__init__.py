"""Metrics of predicted frames: LPIPS (AlexNet / VGG), MSE, PSNR, SSIM.

All take ``(..., 3, H, W)`` images in [0, 1] and return one value per image ``(...)``.
:class:`LPIPS` is also the training's perceptual loss (``TrainConfig(perceptual="lpips")``).
Its weights are read from local files, never downloaded: see ``docs/metrics.md``.
"""

from vp2.metrics.image import gaussian_window, mse, psnr, ssim
from vp2.metrics.lpips import (
    BACKBONES,
    LPIPS,
    WEIGHTS_ENV,
    MissingWeightsError,
    alexnet_features,
    find_weights,
    lpips_loss,
    vgg16_features,
    weight_dirs,
)

__all__ = [
    "BACKBONES",
    "LPIPS",
    "WEIGHTS_ENV",
    "MissingWeightsError",
    "alexnet_features",
    "find_weights",
    "gaussian_window",
    "lpips_loss",
    "mse",
    "psnr",
    "ssim",
    "vgg16_features",
    "weight_dirs",
]
