from __future__ import annotations

import pytest
import torch

from tests.models.common import action_conditioning_gap, check_loss_composition, overfit_ratio
from vp2.models import SVGPrime, build_model

# Smaller than the smallest preset (M = K = 1/8) so that a few hundred CPU steps take seconds.
TINY = {"m": 0.125, "k": 0.125, "action_dim": 4, "image_size": 32}


def test_architecture_follows_model_specs():
    model = build_model("svg_prime", "m0.5k0.5", action_dim=5)
    assert isinstance(model, SVGPrime)
    h, skips = model.encoder(torch.rand(3, 3, 64, 64))
    assert h.shape == (3, 128, 8, 8)  # g_dim channels at 8x8
    assert [s.shape[1:] for s in skips] == [(32, 64, 64), (64, 32, 32), (128, 16, 16)]  # 64K..256K
    # ConvLSTMs of rnn_size * M = 256 channels; predictor input [h, tiled action, z].
    assert model.predictor.embed.in_channels == 128 + 5 + 10
    assert all(
        c.hidden == 256 for m in (model.predictor, model.prior, model.posterior) for c in m.cells
    )
    assert (len(model.predictor.cells), len(model.prior.cells), len(model.posterior.cells)) == (
        2,
        1,
        1,
    )
    assert model.prior.mu.out_channels == 10  # z is a 10-channel 8x8 map
    # Fractional multipliers round channel counts.
    odd = build_model("svg_prime", "m0.25k0.25", m=0.3, k=0.3)
    assert odd.config.hidden == 154 and odd.encoder.block1[0][0].out_channels == 19


def test_init_is_normal_0_02():
    model = build_model("svg_prime", "m0.25k0.25")
    w = model.predictor.cells[0].gates.weight
    assert float(w.detach().std()) == pytest.approx(0.02, rel=0.05)
    assert float(model.predictor.cells[0].gates.bias.detach().abs().max()) == 0
    assert float(model.encoder.block1[0][1].weight.detach().mean()) == pytest.approx(1.0, abs=0.01)


def test_loss_is_sum_over_time_of_mse_plus_beta_kl():
    check_loss_composition(
        build_model("svg_prime", "m0.25k0.25", **TINY), frames_sum_over_time=True
    )


def test_the_last_executed_action_matters():
    """actions[:, 0] produced the last context frame; it drives the predictor's context step."""
    model = build_model("svg_prime", "m0.25k0.25", **TINY)
    frames = torch.rand(2, 2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    actions = torch.zeros(2, 11, 4)
    changed = actions.clone()
    changed[:, 0] = 1.0
    # At initialisation the effect is small (FitVid's decoder blocks start near identity), but
    # a model that ignored the action would give exactly the same frames.
    assert not torch.equal(model.predict(frames, actions), model.predict(frames, changed))


def test_overfits_a_fixed_batch():
    model = build_model("svg_prime", "m0.25k0.25", **TINY)
    assert overfit_ratio(model, steps=100) >= 10


@pytest.mark.slow
def test_overfits_a_fixed_batch_smallest_preset():
    model = build_model("svg_prime", "m0.25k0.25", action_dim=4, image_size=64)
    ratio = overfit_ratio(model, steps=150)
    print(f"loss ratio {ratio:.1f}")
    assert ratio >= 10


@pytest.mark.slow
def test_uses_its_actions():
    true_mse, other_mse = action_conditioning_gap(
        build_model("svg_prime", "m0.25k0.25", **TINY), steps=800
    )
    print(f"MSE with true actions {true_mse:.5f}, with other actions {other_mse:.5f}")
    assert true_mse < 0.8 * other_mse, (true_mse, other_mse)
