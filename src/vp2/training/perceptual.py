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

Nothing is downloaded. Two files per backbone are looked up on disk (see
:func:`find_weights` and ``docs/metrics.md``):

================  ==========================  =======================================
net               ImageNet trunk (torchvision)  LPIPS v0.1 linear layers
================  ==========================  =======================================
``"alex"``        ``alexnet-owt-7be5be79.pth``  ``alex.pth``
``"vgg"``         ``vgg16-397923af.pth``        ``vgg.pth``
================  ==========================  =======================================
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor, nn

if TYPE_CHECKING:
    from vp2.models.layers import PerceptualLoss

#: Environment variable naming a directory with the weight files.
WEIGHTS_ENV = "VP2_WEIGHTS_DIR"

# LPIPS "scaling layer": per-channel shift and scale applied to [-1, 1] images, so the
# backbone sees inputs normalised as for its ImageNet training.
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
# Added to the feature norm (as in the reference) so an all-zero feature vector stays zero.
_NORM_EPS = 1e-10


#: Where torchvision downloads its ImageNet checkpoints from (named in error messages only).
_TORCHVISION_URL = "https://download.pytorch.org/models/"


@dataclasses.dataclass(frozen=True)
class _Backbone:
    title: str
    trunk_file: str  # torchvision's ImageNet checkpoint (``features.N.*`` keys used)
    linear_file: str  # LPIPS v0.1 linear layers (``lin{k}.model.1.weight``)
    channels: tuple[int, ...]  # feature channels at the five tapped stages
    min_size: int  # the smallest H, W for which every stage has at least one pixel

    @property
    def trunk_url(self) -> str:
        return _TORCHVISION_URL + self.trunk_file


BACKBONES: dict[str, _Backbone] = {
    "alex": _Backbone(
        "AlexNet", "alexnet-owt-7be5be79.pth", "alex.pth", (64, 192, 384, 256, 256), 31
    ),
    "vgg": _Backbone("VGG16", "vgg16-397923af.pth", "vgg.pth", (64, 128, 256, 512, 512), 16),
}

_LINEAR_SOURCE = (
    "the LPIPS v0.1 linear layers: lpips/weights/v0.1/{name} inside the `lpips` pip package, "
    "or weights/v0.1/{name} in github.com/richzhang/PerceptualSimilarity"
)


class MissingWeightsError(FileNotFoundError):
    """A weight file LPIPS needs is not on disk (it is never downloaded)."""


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


# --------------------------------------------------------------------------- weight files


def weight_dirs(weights_dir: str | os.PathLike[str] | None = None) -> list[tuple[Path, str]]:
    """The directories searched for weight files, in order, each with where it comes from.

    An explicit ``weights_dir`` is the only place searched; otherwise ``$VP2_WEIGHTS_DIR``
    (if set), then the torch hub cache ``torch.hub.get_dir()/checkpoints`` (where
    torchvision keeps the ImageNet checkpoints it downloads).
    """
    if weights_dir is not None:
        return [(Path(weights_dir), "weights_dir argument")]
    dirs = []
    if os.environ.get(WEIGHTS_ENV):
        dirs.append((Path(os.environ[WEIGHTS_ENV]), f"${WEIGHTS_ENV}"))
    dirs.append((Path(torch.hub.get_dir()) / "checkpoints", "torch hub cache"))
    return dirs


def find_weights(
    net: str = "alex",
    weights_dir: str | os.PathLike[str] | None = None,
    *,
    trunk: bool = True,
    linear: bool = True,
) -> tuple[Path | None, Path | None]:
    """Paths of a backbone's two weight files: ``(trunk, linear layers)``.

    Each file is looked up independently in :func:`weight_dirs` (first hit wins), so the
    ImageNet trunk may stay in the torch hub cache while the LPIPS layers sit in
    ``$VP2_WEIGHTS_DIR``. ``trunk=False`` / ``linear=False`` skip a file (returned as
    ``None``).

    Raises:
        ValueError: unknown ``net``.
        MissingWeightsError: naming the missing files, the directories searched and where to
            get the files.
    """
    spec = _backbone(net)
    dirs = weight_dirs(weights_dir)
    wanted = [n for n, want in ((spec.trunk_file, trunk), (spec.linear_file, linear)) if want]
    found: dict[str, Path] = {}
    for name in wanted:
        for directory, _ in dirs:
            if (directory / name).is_file():
                found[name] = directory / name
                break
    missing = [n for n in wanted if n not in found]
    if missing:
        sources = {
            spec.trunk_file: f"the ImageNet {spec.title} from torchvision: {spec.trunk_url}",
            spec.linear_file: _LINEAR_SOURCE.format(name=spec.linear_file),
        }
        raise MissingWeightsError(
            f"LPIPS ({net}) weights missing: {', '.join(missing)}. "
            f"Looked in: {'; '.join(f'{d} ({why})' for d, why in dirs)}. "
            "vp2 never downloads weights; copy the files into one of these directories "
            f"(or point ${WEIGHTS_ENV} at a directory holding them). "
            + " ".join(f"{n} is {sources[n]}." for n in missing)
            + " See docs/metrics.md."
        )
    return found.get(spec.trunk_file), found.get(spec.linear_file)


def _backbone(net: str) -> _Backbone:
    if net not in BACKBONES:
        raise ValueError(f"unknown LPIPS network {net!r}; known: {', '.join(BACKBONES)}")
    return BACKBONES[net]


def _load_state_dict(path: Path) -> dict[str, Any]:
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # unpickling errors come in several types
        raise ValueError(f"{path}: not a loadable tensor state dict ({exc})") from exc
    if not isinstance(state, dict):
        raise ValueError(f"{path}: expected a state dict, got {type(state).__name__}")
    return state


# --------------------------------------------------------------------------- the metric


class LPIPS(nn.Module):
    """The LPIPS distance with frozen weights, in eval mode.

    Args:
        net: ``"alex"`` (the benchmark's metric) or ``"vgg"``.
        weights_dir: Directory holding both weight files (else see :func:`weight_dirs`).
        trunk_path, linear_path: Explicit files, overriding the lookup for that file.

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
    ):
        super().__init__()
        spec = _backbone(net)
        self.net, self.min_size = net, spec.min_size
        self.features, taps = alexnet_features() if net == "alex" else vgg16_features()
        self.taps = taps
        self.linear = nn.ParameterList(
            [nn.Parameter(torch.zeros(c)) for c in spec.channels]
        )  # per-stage channel weights of the 1x1 convs (no bias)
        self.register_buffer("shift", torch.tensor(_SHIFT).view(3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(_SCALE).view(3, 1, 1), persistent=False)

        if trunk_path is None or linear_path is None:
            found_trunk, found_linear = find_weights(
                net, weights_dir, trunk=trunk_path is None, linear=linear_path is None
            )
            trunk_path = trunk_path or found_trunk
            linear_path = linear_path or found_linear
        self.trunk_path, self.linear_path = Path(trunk_path), Path(linear_path)
        self._load_trunk(self.trunk_path)
        self._load_linear(self.linear_path, spec.channels)
        self.requires_grad_(False)
        self.eval()

    def _load_trunk(self, path: Path) -> None:
        state = _load_state_dict(path)
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

    def _load_linear(self, path: Path, channels: tuple[int, ...]) -> None:
        state = _load_state_dict(path)
        for k, c in enumerate(channels):
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
    up as in :func:`find_weights`.
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
