"""LPIPS with weight files made here: random state dicts with the real files' names and keys."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from torch.nn import functional as F

from tests.models.synthetic import write_moving_square_dataset
from vp2.training import TrainConfig, train
from vp2.training.perceptual import (
    BACKBONES,
    LPIPS,
    PERCEPTUAL_LOSSES,
    WEIGHTS_ENV,
    MissingWeightsError,
    alexnet_features,
    find_weights,
    vgg16_features,
)


def _write_weights(directory: Path, net: str, seed: int = 0) -> dict[str, dict]:
    """torchvision-style trunk (with classifier keys, which LPIPS ignores) and LPIPS-style
    linear layers, random, saved under the real file names."""
    directory.mkdir(parents=True, exist_ok=True)
    spec = BACKBONES[net]
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        trunk, _ = alexnet_features() if net == "alex" else vgg16_features()
        state = {f"features.{k}": v.clone() for k, v in trunk.state_dict().items()}
        state["classifier.1.weight"] = torch.randn(10, 4)
        linear = {
            f"lin{k}.model.1.weight": torch.rand(1, c, 1, 1) for k, c in enumerate(spec.channels)
        }
    torch.save(state, directory / spec.trunk_file)
    torch.save(linear, directory / spec.linear_file)
    return {"trunk": state, "linear": linear}


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    directory = tmp_path_factory.mktemp("weights")
    return directory, {
        net: _write_weights(directory, net, seed=i) for i, net in enumerate(BACKBONES)
    }


@pytest.fixture
def no_default_weights(tmp_path, monkeypatch):
    """Neither $VP2_WEIGHTS_DIR nor the user's real torch hub cache may leak into a test."""
    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    hub = tmp_path / "hub"
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(hub))
    monkeypatch.setattr("vp2.training.lpips_weights._package_dir", lambda net: None)
    return hub


@pytest.fixture(scope="module")
def alex(weights):
    return LPIPS("alex", weights_dir=weights[0])


def _reference_alex(x, y, trunk, linear):
    """LPIPS-alex written out layer by layer from the raw state dicts."""
    shift = torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1)
    scale = torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1)

    def feats(img):
        h = ((img * 2 - 1) - shift) / scale
        out = []
        layers = [(0, 4, 2, True), (3, 1, 2, True), (6, 1, 1, False), (8, 1, 1, False)]
        for idx, stride, pad, pool in [*layers, (10, 1, 1, False)]:
            h = F.relu(
                F.conv2d(
                    h, trunk[f"features.{idx}.weight"], trunk[f"features.{idx}.bias"], stride, pad
                )
            )
            out.append(h)
            if pool:
                h = F.max_pool2d(h, 3, 2)
        return out

    total = 0
    for k, (fx, fy) in enumerate(zip(feats(x), feats(y), strict=True)):
        fx = fx / (fx.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
        fy = fy / (fy.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
        total = total + F.conv2d((fx - fy) ** 2, linear[f"lin{k}.model.1.weight"]).mean(
            dim=(1, 2, 3)
        )
    return total


def test_loads_the_files_and_matches_a_layer_by_layer_reference(weights, alex):
    directory, saved = weights
    assert alex.trunk_path == directory / "alexnet-owt-7be5be79.pth"
    assert alex.linear_path == directory / "alex.pth"
    trunk, linear = saved["alex"]["trunk"], saved["alex"]["linear"]
    torch.testing.assert_close(
        alex.features[10].weight, trunk["features.10.weight"], rtol=0, atol=0
    )
    torch.testing.assert_close(
        alex.linear[4], linear["lin4.model.1.weight"].flatten(), rtol=0, atol=0
    )
    assert not any(p.requires_grad for p in alex.parameters()) and not alex.training

    g = torch.Generator().manual_seed(0)
    x, y = torch.rand(2, 4, 3, 64, 64, generator=g)
    torch.testing.assert_close(
        alex(x, y), _reference_alex(x, y, trunk, linear), rtol=1e-4, atol=1e-6
    )


@pytest.mark.parametrize("net", sorted(BACKBONES))
def test_distance_properties(weights, net):
    lpips = LPIPS(net, weights_dir=weights[0])
    g = torch.Generator().manual_seed(1)
    x = torch.rand(2, 3, 3, 32, 32, generator=g)  # (B, T, 3, H, W)
    y = torch.rand(2, 3, 3, 32, 32, generator=g)
    d = lpips(x, y)
    assert d.shape == (2, 3) and bool((d > 0).all())
    assert float(lpips(x, x).abs().max()) == 0.0
    torch.testing.assert_close(lpips(y, x), d, rtol=1e-5, atol=1e-7)
    # The distance to a noisy copy grows with the noise (means over 6 images).
    means = [
        float(lpips(x, (x + s * torch.randn(x.shape, generator=g)).clamp(0, 1)).mean())
        for s in (0.01, 0.05, 0.2, 0.5)
    ]
    assert means == sorted(means) and means[0] > 0, means
    # One image at a time gives the same numbers as the batch.
    torch.testing.assert_close(lpips(x[1, 2], y[1, 2]), d[1, 2], rtol=1e-5, atol=1e-7)


def test_gradients_flow_to_the_input(alex):
    g = torch.Generator().manual_seed(2)
    target = torch.rand(3, 3, 32, 32, generator=g)
    target[0] = 0  # black frames: all-zero features must not give NaN gradients
    pred = torch.rand(3, 3, 32, 32, generator=g).requires_grad_(True)
    alex(pred, target).sum().backward()
    assert pred.grad is not None and bool(torch.isfinite(pred.grad).all())
    assert float(pred.grad.abs().sum()) > 0
    assert all(p.grad is None for p in alex.parameters())
    # A gradient step on the input lowers the distance.
    with torch.no_grad():
        before = alex(pred, target).sum()
        after = alex(pred - 1e-2 * pred.grad / pred.grad.norm(), target).sum()
    assert float(after) < float(before)
    # The module stays frozen in eval mode whatever .train() says.
    alex.train()
    assert not alex.training


def test_lookup_order(weights, tmp_path, monkeypatch, no_default_weights):
    directory, _ = weights
    monkeypatch.setenv(WEIGHTS_ENV, str(directory))
    assert LPIPS("alex").trunk_path == directory / "alexnet-owt-7be5be79.pth"

    # The torch hub cache (where torchvision keeps its ImageNet checkpoints) is searched
    # after $VP2_WEIGHTS_DIR, file by file.
    hub = no_default_weights / "checkpoints"
    lin_only = tmp_path / "lin_only"
    _write_weights(hub, "alex")
    (hub / "alex.pth").unlink()
    _write_weights(lin_only, "alex")
    (lin_only / "alexnet-owt-7be5be79.pth").unlink()
    monkeypatch.setenv(WEIGHTS_ENV, str(lin_only))
    trunk, linear = find_weights("alex")
    assert (trunk, linear) == (hub / "alexnet-owt-7be5be79.pth", lin_only / "alex.pth")
    monkeypatch.delenv(WEIGHTS_ENV)
    with pytest.raises(MissingWeightsError, match=r"missing: alex\.pth\."):
        find_weights("alex")
    # Explicit files win over any lookup.
    explicit = LPIPS(
        "alex", trunk_path=hub / "alexnet-owt-7be5be79.pth", linear_path=lin_only / "alex.pth"
    )
    assert explicit.linear_path == lin_only / "alex.pth"


def test_missing_weights_error_says_what_where_and_how(tmp_path, monkeypatch, no_default_weights):
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.setenv(WEIGHTS_ENV, str(empty))
    with pytest.raises(MissingWeightsError) as info:
        LPIPS("vgg")
    message = str(info.value)
    assert isinstance(info.value, FileNotFoundError)
    for part in (
        "vgg16-397923af.pth",
        "vgg.pth",
        f"{empty} (${WEIGHTS_ENV})",
        f"{no_default_weights / 'checkpoints'} (torch hub cache)",
        "https://download.pytorch.org/models/vgg16-397923af.pth",
        "lpips/weights/v0.1/vgg.pth",
        "docs/metrics.md",
    ):
        assert part in message, part
    with pytest.raises(
        MissingWeightsError, match=f"Looked in: {tmp_path} \\(weights_dir argument\\)"
    ):
        LPIPS("alex", weights_dir=tmp_path)
    # The trainer's registered losses go through the same lookup.
    with pytest.raises(MissingWeightsError, match="alexnet-owt-7be5be79.pth"):
        PERCEPTUAL_LOSSES["lpips"](torch.device("cpu"))


def test_wrong_files_are_named(tmp_path):
    _write_weights(tmp_path, "alex")
    torch.save({"lin0.model.1.weight": torch.rand(1, 64, 1, 1)}, tmp_path / "alex.pth")
    with pytest.raises(ValueError, match=r"alex\.pth: not an LPIPS v0.1 alex file: missing lin1"):
        LPIPS("alex", weights_dir=tmp_path)
    torch.save({"classifier.1.weight": torch.zeros(1)}, tmp_path / "alexnet-owt-7be5be79.pth")
    with pytest.raises(
        ValueError, match="not a torchvision alex checkpoint: missing features.0.bias"
    ):
        LPIPS("alex", weights_dir=tmp_path)
    with pytest.raises(ValueError, match="unknown LPIPS network 'squeeze'"):
        LPIPS("squeeze", weights_dir=tmp_path)


def test_input_errors(alex):
    with pytest.raises(ValueError, match="at least 31x31"):
        alex(torch.zeros(1, 3, 16, 16), torch.zeros(1, 3, 16, 16))
    with pytest.raises(ValueError, match="differ in shape"):
        alex(torch.zeros(1, 3, 32, 32), torch.zeros(2, 3, 32, 32))


def test_trainer_uses_lpips_from_the_weights_dir(weights, tmp_path, monkeypatch):
    monkeypatch.setenv(WEIGHTS_ENV, str(weights[0]))
    data = write_moving_square_dataset(tmp_path / "squares", num_trajectories=3, valid_every=3)
    result = train(
        TrainConfig(
            model="fitvid",
            preset="mini",
            dataset=data,
            out_dir=tmp_path / "run",
            steps=2,
            batch_size=2,
            lr=1e-3,
            perceptual="lpips",
            perceptual_weight=10.0,
            eval_interval=0,
            eval_batches=1,
            log_interval=1,
            workers=0,
            progress=False,
            tensorboard=False,
        )
    )
    m = result.train_metrics
    assert result.step == 2 and m["train/perceptual"] > 0
    # The loss is the pixel MSE plus 10 x LPIPS (KL x 1e-4 on top).
    assert m["train/loss"] > m["train/mse"] + 10 * m["train/perceptual"]
    assert result.valid_metrics["valid/perceptual"] > 0
