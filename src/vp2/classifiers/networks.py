"""The success classifier networks and the module the planning cost calls.

Both networks map ``images (M, 3, 64, 64) float in [0, 1] -> logits (M,)``:

* :class:`PaperClassifier`, the paper's (8 full-resolution 3×3 convolutions, then
  ``Linear 12288 → 1024 → 1``; about 246 M multiply-adds per 64×64 frame);
* :class:`SuccessClassifier`, ours, shipped (four stride-2 convolutions and a small head;
  about 3 M).

:class:`FrameClassifierModule` wraps a trained network with the benchmark's input contract.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

#: Side of the frames the classifiers are trained on (the benchmark's 64×64).
IMAGE_SIZE = 64
ARCHS: tuple[str, ...] = ("ours", "paper")


class PaperClassifier(nn.Module):
    """The paper's success classifier (VP² appendix, Table ``classifier_architecture``).

    Eight 3×3 convolutions at full resolution (padding 1): ``3 → 32``, three residual blocks
    of two ``32 → 32`` convolutions (``x + conv(relu(conv(x)))``, each block followed by a
    ReLU), and ``32 → 3``; then ``Flatten (3·64·64 = 12288) → Linear 1024 → ReLU → Linear 1``.
    The residual connections and the 3-channel last convolution are the authors' released
    code; the paper's table lists the same eight convolutions without them (its flatten size
    12288 = 3 × 64 × 64 only fits a 3-channel last layer). About 246 M multiply-adds and
    12.7 M parameters per 64×64 frame.
    """

    arch = "paper"

    def __init__(self, image_size: int = IMAGE_SIZE, width: int = 32) -> None:
        super().__init__()
        self.image_size = image_size
        self.stem = nn.Conv2d(3, width, 3, padding=1)
        self.blocks = nn.ModuleList(
            nn.Sequential(
                nn.Conv2d(width, width, 3, padding=1),
                nn.ReLU(inplace=True),
                nn.Conv2d(width, width, 3, padding=1),
            )
            for _ in range(3)
        )
        self.last = nn.Conv2d(width, 3, 3, padding=1)
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(3 * image_size * image_size, 1024),
            nn.ReLU(inplace=True),
            nn.Linear(1024, 1),
        )

    def forward(self, images: Tensor) -> Tensor:
        """``images (M, 3, S, S)`` in [0, 1] -> logits ``(M,)``."""
        x = self.stem(images)  # (M, 32, S, S)
        for block in self.blocks:
            x = F.relu(x + block(x))
        return self.head(self.last(x)).squeeze(-1)  # (M,)


#: Channels of the four convolutions and the hidden units of ours at width 1.
OURS_WIDTHS = (16, 32, 64, 32)
OURS_HIDDEN = 32


class SuccessClassifier(nn.Module):
    """Our success classifier: four stride-2 3×3 convolutions and a small dense head.

    ``64² × 3 → 32² × 16 → 16² × 32 → 8² × 64 → 4² × 32``, each convolution followed by a
    ReLU, then ``Flatten (512) → Linear 32 → ReLU → Linear 1``. Flattening the 4×4 map (rather
    than pooling it away) keeps *where* things are, which is what success is about on the desk
    (a block over the edge, a drawer pulled out, a button pressed). About 3.1 M multiply-adds
    (80× fewer than :class:`PaperClassifier`) and 58 K parameters (a 0.23 MB file).
    """

    arch = "ours"

    def __init__(
        self,
        image_size: int = IMAGE_SIZE,
        widths: Sequence[int] = OURS_WIDTHS,
        hidden: int = OURS_HIDDEN,
    ) -> None:
        super().__init__()
        if image_size % 2 ** len(widths):
            raise ValueError(f"image_size {image_size} must be divisible by {2 ** len(widths)}")
        self.image_size = image_size
        layers: list[nn.Module] = []
        in_ch = 3
        for w in widths:
            layers += [nn.Conv2d(in_ch, w, 3, stride=2, padding=1), nn.ReLU(inplace=True)]
            in_ch = w
        self.features = nn.Sequential(*layers)
        side = image_size // 2 ** len(widths)
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(in_ch * side * side, hidden),
            nn.ReLU(inplace=True),
            nn.Linear(hidden, 1),
        )

    def forward(self, images: Tensor) -> Tensor:
        """``images (M, 3, S, S)`` in [0, 1] -> logits ``(M,)``."""
        return self.head(self.features(images)).squeeze(-1)  # (M,)


_NETWORKS: dict[str, type[nn.Module]] = {"ours": SuccessClassifier, "paper": PaperClassifier}


def build_classifier(arch: str, image_size: int = IMAGE_SIZE, width: int = 1) -> nn.Module:
    """A freshly initialised classifier network (``"ours"`` or ``"paper"``).

    ``width`` multiplies the channels and the hidden units of ours (1: the 58 K-parameter
    network; 2: 4x the multiply-adds); the paper's network has one size.
    """
    if arch not in _NETWORKS:
        raise ValueError(f"unknown classifier arch {arch!r}; choose one of {', '.join(ARCHS)}")
    if width < 1:
        raise ValueError(f"width must be a positive integer, got {width}")
    if arch != "ours":
        if width != 1:
            raise ValueError(f"width applies to the 'ours' network only, not {arch!r}")
        return _NETWORKS[arch](image_size=image_size)
    return SuccessClassifier(
        image_size=image_size,
        widths=tuple(w * width for w in OURS_WIDTHS),
        hidden=OURS_HIDDEN * width,
    )


def multiply_adds(model: nn.Module, image_size: int = IMAGE_SIZE) -> int:
    """Multiply-adds of one frame through the convolutions and linear layers of ``model``."""
    total = 0

    def count(module: nn.Module, inputs: tuple[Tensor, ...], output: Tensor) -> None:
        nonlocal total
        if isinstance(module, nn.Conv2d):
            kernel = module.in_channels // module.groups * math.prod(module.kernel_size)
            total += output[0].numel() * kernel
        elif isinstance(module, nn.Linear):
            total += module.in_features * module.out_features

    hooks = [m.register_forward_hook(count) for m in model.modules()]
    try:
        with torch.no_grad():
            model(torch.zeros(1, 3, image_size, image_size))
    finally:
        for h in hooks:
            h.remove()
    return total


class FrameClassifierModule(nn.Module):
    """What the planning cost calls: a trained network with the benchmark's input contract.

    ``images (M, 3, H, W)`` float in [0, 1] -> success logits ``(M,)``. Frames of another size
    are resized to the network's training size (area average down, bilinear up); inputs are made
    contiguous (a channels-last view changes convolution rounding on the CPU).

    :meth:`exact_logits` gives logits that are the same bits on every CPU
    (:mod:`vp2.classifiers.exact`); the simulator oracle's planning cost calls it.
    """

    #: Frames per chunk of :meth:`exact_logits` (bounds the float64 ``unfold`` buffers: about
    #: 60 MB at 256 frames of 64x64 for ours).
    exact_chunk = 256

    def __init__(self, network: nn.Module, task: str, meta: dict[str, Any]) -> None:
        super().__init__()
        self.network = network
        self.task = task
        self.meta = meta
        self.image_size = int(meta.get("image_size", IMAGE_SIZE))

    def forward(self, images: Tensor) -> Tensor:
        if images.ndim != 4 or images.shape[1] != 3:
            raise ValueError(
                f"{self.task} classifier: images must have shape (M, 3, H, W), "
                f"got {tuple(images.shape)}"
            )
        if images.shape[-2:] != (self.image_size, self.image_size):
            size = (self.image_size, self.image_size)
            if images.shape[-1] > self.image_size:  # box filter: 128 -> 64 averages 2x2 blocks
                images = F.interpolate(images, size=size, mode="area")
            else:
                images = F.interpolate(images, size=size, mode="bilinear", align_corners=False)
        return self.network(images.contiguous())  # (M,)

    def exact_logits(self, images: Tensor) -> Tensor:
        """The logits ``(M,)`` float32 computed so that they are the same bits on every CPU
        and device (:func:`vp2.classifiers.exact.exact_network`); within about ``1e-6`` of
        :meth:`forward`. Frames must be of the network's size or a multiple of it."""
        from vp2.classifiers.exact import box_downsample, exact_network

        if images.ndim != 4 or images.shape[1] != 3:
            raise ValueError(
                f"{self.task} classifier: images must have shape (M, 3, H, W), "
                f"got {tuple(images.shape)}"
            )
        exact = self.__dict__.get("_exact")  # not a submodule: the state dict stays the same
        if exact is None or next(exact.buffers()).device != images.device:
            exact = self.__dict__["_exact"] = exact_network(self.network).to(images.device)
        x = images.detach().double()
        if x.shape[-2:] != (self.image_size, self.image_size):
            x = box_downsample(x, self.image_size)
        with torch.no_grad():
            out = [exact(chunk) for chunk in x.split(self.exact_chunk)]
        return torch.cat(out).float()  # (M,)
