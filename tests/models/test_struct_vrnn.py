from __future__ import annotations

import math

import pytest
import torch

from tests.models.common import action_conditioning_gap, overfit_ratio
from tests.models.synthetic import moving_square_batch
from vp2.models import StructVRNN, build_model
from vp2.models.struct_vrnn import KeypointDetector, gaussian_maps

SMALL = {"action_dim": 4, "image_size": 32}



def test_architecture_follows_model_specs():
    model = build_model("struct_vrnn", "default", action_dim=4)
    assert isinstance(model, StructVRNN)
    convs = [m for m in model.detector.features.net.modules() if isinstance(m, torch.nn.Conv2d)]
    assert [(c.in_channels, c.out_channels, c.stride[0]) for c in convs] == [
        (5, 32, 1), (32, 32, 1), (32, 32, 1),
        (32, 64, 2), (64, 64, 1), (64, 64, 1),
        (64, 128, 2), (128, 128, 1), (128, 128, 1),
    ]  # fmt: skip
    assert model.detector.heatmaps.out_channels == 64  # K = 64
    assert model.dynamics.core.hidden_size == 512 and model.dynamics.core.num_layers == 2
    assert model.dynamics.z_dim == 16
    assert model.dynamics.head[-1].out_features == 3 * 64
    # Decoder input: G(k_t), appearance(x0) (128 channels), G(k_0), 2 coordinate channels.
    assert model.decoder.first[0].in_channels == 64 + 128 + 64 + 2
    assert model.decoder.first[0].out_channels == 256
    with torch.no_grad():
        keypoints = model._detect(torch.rand(2, 3, 3, 64, 64))
    assert keypoints.shape == (2, 3, 64, 3)
    assert float(keypoints[..., :2].abs().max()) <= 1
    # Intensity = mean activation relative to the strongest keypoint of the frame.
    torch.testing.assert_close(keypoints[..., 2].amax(-1), torch.ones(2, 3), atol=1e-5, rtol=0)


def test_keypoints_are_expected_coordinates_of_the_heatmaps():
    detector = KeypointDetector(filters=4, num_keypoints=1)
    side = 16
    # A heatmap that is large in one pixel only: the keypoint sits at that pixel's centre.
    logits = torch.full((1, 1, side, side), -30.0)
    logits[0, 0, 4, 12] = 30.0
    detector.heatmaps.forward = lambda _: logits  # type: ignore[method-assign]
    kp = detector(torch.rand(1, 3, 4 * side, 4 * side))
    x, y = (12 + 0.5) / side * 2 - 1, (4 + 0.5) / side * 2 - 1
    torch.testing.assert_close(kp[0, 0], torch.tensor([x, y, 1.0]), atol=1e-4, rtol=0)


def test_gaussian_maps():
    kp = torch.tensor([[[0.0, 0.0, 1.0], [0.5, -0.5, 0.5], [0.0, 0.0, -0.3]]])  # (1, 3, 3)
    maps = gaussian_maps(kp, 16, sigma=0.1)  # (1, 3, 16, 16)
    assert maps.shape == (1, 3, 16, 16)
    # Pixel (7, 7) has centre (-1/16, -1/16): distance² = 2/256 from (0, 0).
    assert float(maps[0, 0, 7, 7]) == pytest.approx(math.exp(-(2 / 256) / 0.02), rel=1e-5)
    assert float(maps[0, 1].max()) <= 0.5 + 1e-6  # scaled by the intensity
    assert float(maps[0, 2].abs().max()) == 0  # negative intensities are clamped to 0


def test_loss_composition():
    model = build_model("struct_vrnn", "tiny", **SMALL)
    frames, actions = moving_square_batch(2, size=32, action_dim=4)
    out = model.compute_loss(frames, actions, torch.Generator().manual_seed(0))
    c = model.config
    expected = (
        c.recon_weight * out.metrics["mse"]
        + c.coord_weight * out.metrics["coord"]
        + c.kl_weight * out.metrics["kl"]
    )
    torch.testing.assert_close(out.loss.detach(), expected, rtol=1e-5, atol=1e-7)
    assert (c.recon_weight, c.coord_weight, c.kl_weight) == (10.0, 1.0, 1e-3)
    assert out.predictions.shape == (2, 11, 3, 32, 32)
    out.loss.backward()
    assert float(model.detector.heatmaps.weight.grad.abs().sum()) > 0
    # The dynamics learn from detached keypoints: only the reconstruction shapes the detector.
    dynamics_only = build_model("struct_vrnn", "tiny", recon_weight=0.0, **SMALL)
    dynamics_only.compute_loss(frames, actions, torch.Generator().manual_seed(0)).loss.backward()
    grad = dynamics_only.detector.heatmaps.weight.grad
    assert grad is None or float(grad.abs().sum()) == 0
    assert float(dynamics_only.dynamics.head[-1].weight.grad.abs().sum()) > 0


def test_actions_are_aligned_as_in_training():
    """Predicted frame ``t`` depends on ``a_{t-1}`` (which produced it) and earlier actions
    only -- not on later ones (the original's inference was one step late)."""
    model = build_model("struct_vrnn", "tiny", **SMALL)
    frames = torch.rand(2, 2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    actions = torch.zeros(2, 11, 4)
    base = model.predict(frames, actions)
    for k in (1, 5):  # actions[:, k] produces frame k + 1 = output index k - 1
        changed = actions.clone()
        changed[:, k] = 1.0
        out = model.predict(frames, changed)
        torch.testing.assert_close(out[:, : k - 1], base[:, : k - 1], rtol=0, atol=0)
        assert not torch.equal(out[:, k - 1], base[:, k - 1])


def test_gradients_reach_the_actions():
    model = build_model("struct_vrnn", "tiny", **SMALL)
    frames = torch.rand(2, 2, 3, 32, 32)
    leaf = torch.zeros(2, 11, 4, requires_grad=True)
    (grad,) = torch.autograd.grad(model.predict(frames, leaf).square().sum(), leaf)
    assert float(grad[:, 1:].abs().sum()) > 0


def test_overfits_a_fixed_batch_quickly():
    # 100 steps (~20 s on one core): the loss is already down several times.
    assert overfit_ratio(build_model("struct_vrnn", "tiny", **SMALL), steps=100, lr=2e-3) >= 3


@pytest.mark.slow
def test_overfits_a_fixed_batch():
    ratio = overfit_ratio(build_model("struct_vrnn", "tiny", **SMALL), steps=200, lr=2e-3)
    print(f"loss ratio {ratio:.1f}")
    assert ratio >= 10


@pytest.mark.slow
def test_uses_its_actions():
    true_mse, other_mse = action_conditioning_gap(
        build_model("struct_vrnn", "small", **SMALL), steps=600
    )
    print(f"true {true_mse:.4f} other {other_mse:.4f}")
    assert true_mse < 0.9 * other_mse
