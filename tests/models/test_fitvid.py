from __future__ import annotations

import pytest
import torch

from tests.models.common import action_conditioning_gap, check_loss_composition, overfit_ratio
from tests.models.synthetic import moving_square_batch
from vp2.models import FitVid, build_model

SMALL = {"action_dim": 4, "image_size": 32}


def test_architecture_follows_model_specs():
    model = build_model("fitvid", "default", action_dim=5)
    assert isinstance(model, FitVid)
    h, skips = model.encoder(torch.rand(2, 3, 64, 64))
    assert h.shape == (2, 128)
    assert [s.shape[1:] for s in skips] == [(32, 64, 64), (64, 32, 32), (128, 16, 16), (256, 8, 8)]
    assert model.decoder.dense.out_features == 8 * 8 * 512
    assert model.predictor.lstm.num_layers == 2 and model.prior.lstm.num_layers == 1
    assert model.predictor.embed.in_features == 128 + 5 + 10
    assert model.predictor.lstm.hidden_size == 256
    # Bias-free convs; the last BN of each decoder block starts at gamma = 0.
    assert all(m.bias is None for m in model.modules() if isinstance(m, torch.nn.Conv2d))
    for block in model.decoder.blocks:
        assert float(block.body[-2].weight.detach().abs().max()) == 0
    mini = build_model("fitvid", "mini")
    assert [b.body[2].out_channels for b in mini.encoder.blocks] == [8, 16, 32, 64]  # filters / 4
    assert (mini.config.g_dim, mini.config.rnn_size) == (32, 64)


def test_training_defaults_clip_gradients_at_100():
    assert FitVid.training_defaults.grad_clip == 100.0
    assert FitVid.training_defaults.lr == 3e-4 and FitVid.training_defaults.eps == 1e-8


def test_loss_is_mse_plus_beta_kl():
    check_loss_composition(build_model("fitvid", "mini", **SMALL), frames_sum_over_time=False)


def test_the_last_executed_action_matters():
    model = build_model("fitvid", "mini", **SMALL)
    frames = torch.rand(2, 2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    actions = torch.zeros(2, 11, 4)
    changed = actions.clone()
    changed[:, 0] = 1.0
    # At initialisation the effect is small (FitVid's decoder blocks start near identity), but
    # a model that ignored the action would give exactly the same frames.
    assert not torch.equal(model.predict(frames, actions), model.predict(frames, changed))


def test_overfits_a_fixed_batch():
    assert overfit_ratio(build_model("fitvid", "mini", **SMALL), steps=120) >= 10


def test_memory_layout_does_not_matter():
    """Permuted (channels-last) clips, as a DataLoader collates them, give the same loss; they
    used to crash oneDNN's backward in the encoder (torch 2.13 CPU)."""
    model = build_model("fitvid", "mini", action_dim=4)
    frames, actions = moving_square_batch(4, size=64, action_dim=4)
    permuted = frames.permute(0, 1, 3, 4, 2).contiguous().permute(0, 1, 4, 2, 3)
    assert frames.is_contiguous() and not permuted.is_contiguous()
    losses = []
    for x in (frames, permuted):
        out = model.compute_loss(x, actions, torch.Generator().manual_seed(0))
        out.loss.backward()
        losses.append(float(out.loss.detach()))
    assert losses[0] == losses[1]


@pytest.mark.slow
def test_overfits_a_fixed_batch_at_64px():
    ratio = overfit_ratio(build_model("fitvid", "mini", action_dim=4), steps=150)
    print(f"loss ratio {ratio:.1f}")
    assert ratio >= 10


@pytest.mark.slow
def test_uses_its_actions():
    true_mse, other_mse = action_conditioning_gap(build_model("fitvid", "mini", **SMALL), steps=800)
    print(f"MSE with true actions {true_mse:.5f}, with other actions {other_mse:.5f}")
    assert true_mse < 0.8 * other_mse, (true_mse, other_mse)
