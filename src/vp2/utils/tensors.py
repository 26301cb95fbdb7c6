"""Small torch helpers every stage shares: the default device and image conversion."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor


def resolve_device(device: str | torch.device | None = None) -> torch.device:
    """``device`` as a :class:`torch.device`; ``None`` or ``""``: CUDA if available, else CPU."""
    if device is None or device == "":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def images_to_float(images: Tensor | np.ndarray, device: str | torch.device | None = None,
                    channels_first: bool = False) -> Tensor:
    """uint8 images in [0, 255] -> float32 in [0, 1] (floats pass through as float32).

    Args:
        images: ``(..., H, W, C)`` (``channels_first=False``) or any layout.
        device: where the result lives (``None``: where the input is; CPU for NumPy).
        channels_first: move the last axis to third-from-last, ``(..., H, W, C) -> (..., C, H, W)``.
    """
    x = torch.as_tensor(images)
    if device is not None:
        x = x.to(device)
    if channels_first:
        x = x.movedim(-1, -3).contiguous()
    return x.float().div_(255.0) if x.dtype == torch.uint8 else x.float()
