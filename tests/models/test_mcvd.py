from __future__ import annotations

import contextlib

import pytest
import torch

from tests.models.synthetic import moving_square_batch
from vp2.models import MCVD, build_model
from vp2.models.mcvd import AttnBlock, ResBlock, SPADENorm, UNet

SMALL = {"action_dim": 4, "image_size": 32}



def test_architecture_follows_model_specs():
    with torch.device("meta"):
        model = build_model("mcvd", "default", action_dim=4)
    assert isinstance(model, MCVD)
    c = model.config
    assert (c.window, c.base_channels, c.channel_mult, c.num_res_blocks) == (5, 64, (1, 2, 3, 4), 2)
    assert c.cond_channels == 6 + 6 * 4  # 2 context frames + 6 tiled actions
    assert model.unet.stem.in_channels == 15 and model.unet.out.out_channels == 15
    down = [b[0] for b in model.unet.down if isinstance(b[0], ResBlock)]
    up = [b[0] for b in model.unet.up if isinstance(b[0], ResBlock)]
    assert [b.conv1.out_channels for b in down] == [64, 64, 128, 128, 192, 192, 256, 256]
    assert len(up) == 4 * 3  # 3 residual blocks per level on the way up
    attn = sum(isinstance(m, AttnBlock) for m in model.unet.modules())
    assert attn == 3 * 2 + 3 * 3 + 1  # at 32, 16, 8 down and up, plus the middle
    # Conditioning enters through SPADE (the noisy input has only the 15 frame channels).
    assert down[0].norm1.shared[0].in_channels == 30
    assert model.unet.time_mlp[0].in_features == 64 and model.unet.time_mlp[2].out_features == 256
    assert MCVD.training_defaults.lr == 2e-4 and MCVD.training_defaults.grad_clip == 1.0
    assert model.num_parameters() == pytest.approx(45.0e6, rel=0.02)


def test_presets_leave_the_output_head_room_for_the_noise(caplog):
    # The head conv(SiLU(GroupNorm(h))) must reproduce 3W = 15 noise channels; with one
    # channel each, SiLU explains only corr(x, SiLU(x))^2 of their variance.
    x = torch.randn(1_000_000, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    corr = torch.corrcoef(torch.stack([x, torch.nn.functional.silu(x)]))[0, 1]
    assert float(1 - corr**2) == pytest.approx(0.20, abs=0.005)  # the floor measured at base 16
    for preset in ("default", "small", "tiny"):
        with torch.device("meta"):
            model = build_model("mcvd", preset, action_dim=4)
        assert model.config.base_channels >= 2 * 3 * model.config.window, preset
        assert model.unet.out_norm.num_channels >= 30, preset
    assert not [r for r in caplog.records if "base_channels" in r.getMessage()]
    with caplog.at_level("WARNING", logger="vp2.models.mcvd"):
        build_model("mcvd", "tiny", base_channels=16, **SMALL)
    assert any("base_channels=16 < 30" in r.getMessage() for r in caplog.records)


def test_noise_schedule_and_sampling_steps():
    model = build_model("mcvd", "tiny", **SMALL)
    ab = model.alphas_cumprod
    assert ab.shape == (1000,)
    assert float(ab[0]) == pytest.approx(1 - 1e-4)
    betas = torch.linspace(1e-4, 0.02, 1000, dtype=torch.float64)
    assert float(ab[-1]) == pytest.approx(float(torch.prod(1 - betas)), rel=1e-4)
    assert model.sampling_timesteps() == [999, 888, 777, 666, 555, 444, 333, 222, 111, 0]
    assert build_model("mcvd", "tiny", sampling_steps=2).sampling_timesteps() == [999, 0]
    assert len(build_model("mcvd", "tiny", sampling_steps=100).sampling_timesteps()) == 100
    with pytest.raises(ValueError, match="sampling_steps"):
        build_model("mcvd", "tiny", sampling_steps=0)


def test_loss_is_half_the_summed_squared_noise_error():
    model = build_model("mcvd", "tiny", **SMALL)
    frames, actions = moving_square_batch(2, size=32, action_dim=4)
    out = model.compute_loss(frames, actions, torch.Generator().manual_seed(0))
    per_sample = 5 * 3 * 32 * 32
    torch.testing.assert_close(
        out.loss.detach(), 0.5 * per_sample * out.metrics["eps_mse"], rtol=1e-5, atol=1e-3
    )
    assert out.predictions.shape == (2, 11, 3, 32, 32)
    # 6 of the 11 returned frames are the true ones, 5 are x0 estimates of the window.
    same = (out.predictions == frames[:, 1:]).flatten(2).all(-1).sum(1)
    assert same.tolist() == [6, 6]


def test_ema_follows_training_and_is_used_for_prediction():
    model = build_model("mcvd", "tiny", **SMALL)
    frames, actions = moving_square_batch(2, size=32, action_dim=4)
    name = "stem.weight"
    ema = lambda: model.ema_parameters()[name].clone()  # noqa: E731
    start = ema()
    torch.testing.assert_close(start, model.unet.stem.weight.detach())
    optimizer = torch.optim.Adam(model.parameters(), 1e-2)
    g = torch.Generator().manual_seed(0)
    for _ in range(3):
        model.compute_loss(frames, actions, g).loss.backward()
        optimizer.step()
        optimizer.zero_grad()
    # 3 updates, each before the step: the EMA saw the weights after steps 0, 1 and 2.
    assert int(model.ema_updates) == 3
    before = ema()
    with torch.no_grad():  # validation: no update
        model.eval()
        model.compute_loss(frames, actions, g)
        model.train()
    torch.testing.assert_close(ema(), before, rtol=0, atol=0)
    decay = min(0.999, (1 + 3) / (10 + 3))
    model.compute_loss(frames, actions, g)
    expected = decay * before + (1 - decay) * model.unet.stem.weight.detach()
    torch.testing.assert_close(ema(), expected)
    # The EMA is in the state dict (checkpoints, resume) and drives predict.
    assert "ema_stem__weight" in model.state_dict() and "ema_updates" in model.state_dict()
    ctx, acts = frames[:, :2], actions.clamp(-1, 1)
    with_ema = model.predict(ctx, acts)
    model.config.use_ema = False
    assert not torch.equal(with_ema, model.predict(ctx, acts))


def test_windows_and_actions():
    """Frames 2-6 come from window 1 (actions 0-5), frames 7-11 from window 2 (actions 5-10)."""
    model = build_model("mcvd", "tiny", sampling_steps=2, **SMALL)
    frames = torch.rand(2, 2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    actions = torch.zeros(2, 11, 4)
    base = model.predict(frames, actions)
    for k, first_changed in ((0, 0), (5, 0), (6, 5), (10, 5)):
        changed = actions.clone()
        changed[:, k] = 0.8
        out = model.predict(frames, changed)
        torch.testing.assert_close(out[:, :first_changed], base[:, :first_changed], rtol=0, atol=0)
        assert not torch.equal(out[:, first_changed], base[:, first_changed]), k


def test_gradients_reach_the_actions():
    model = build_model("mcvd", "tiny", sampling_steps=2, **SMALL)
    leaf = torch.zeros(1, 11, 4, requires_grad=True)
    out = model.predict(torch.rand(1, 2, 3, 32, 32), leaf)
    (grad,) = torch.autograd.grad(out.square().sum(), leaf)
    assert float(grad[:, 1:].abs().sum()) > 0


@pytest.mark.parametrize("steps", [2, 8])
def test_sampling_steps_set_the_denoiser_calls(steps, monkeypatch):
    """The cost of a prediction: one U-Net call per sampling step per window (2 windows of 5
    frames), each on the whole batch."""
    model = build_model("mcvd", "tiny", sampling_steps=steps, **SMALL)
    denoiser, batches = model._denoiser, []

    def counting(x, t, cond):
        batches.append(x.shape[0])
        return denoiser(x, t, cond)

    monkeypatch.setattr(model, "_denoiser", counting)
    model.predict(torch.rand(3, 2, 3, 32, 32), torch.zeros(3, 11, 4))
    assert len(model.sampling_timesteps()) == steps
    assert batches == [3] * (2 * steps)


def test_conditioning_is_computed_once_per_window_with_the_same_samples(monkeypatch):
    """The SPADE modulation depends on the conditioning map alone, so sampling computes it
    once per window and norm, and the frames are bit-identical to recomputing it per step."""
    model = build_model("mcvd", "tiny", sampling_steps=4, **SMALL)
    # Perturbed weights, so that the modulation visibly shapes the output.
    with torch.no_grad():
        for name in model._ema_names.values():
            buf = getattr(model, name)
            buf.add_(0.05 * torch.randn(buf.shape, generator=torch.Generator().manual_seed(1)))
    context, actions = torch.rand(3, 2, 3, 32, 32), torch.rand(3, 11, 4) * 2 - 1
    norms = [m for m in model.unet.modules() if isinstance(m, SPADENorm)]
    calls = []
    modulation = SPADENorm.modulation

    def counting(self, cond, size):
        calls.append(id(self))
        return modulation(self, cond, size)

    monkeypatch.setattr(SPADENorm, "modulation", counting)
    reused = model.predict(context, actions, generator=torch.Generator().manual_seed(0))
    assert len(calls) == 2 * len(norms)  # 2 windows, once per norm (not 4 steps × 2 windows)
    assert not any(m.reusing or m.cached is not None for m in norms)  # off, freed after

    calls.clear()
    monkeypatch.setattr(UNet, "reusing_conditioning", lambda self: contextlib.nullcontext())
    recomputed = model.predict(context, actions, generator=torch.Generator().manual_seed(0))
    assert len(calls) == 2 * 4 * len(norms)
    assert torch.equal(reused, recomputed)
    assert reused.std() > 0.01


def _overfit(model: MCVD, steps: int, lr: float) -> float:
    """Like ``common.overfit_ratio`` but with the model's gradient clipping (1.0)."""
    frames, actions = moving_square_batch(4, size=model.image_size, action_dim=4)
    optimizer = torch.optim.Adam(model.parameters(), lr)
    generator = torch.Generator().manual_seed(0)
    losses = []
    for _ in range(steps):
        out = model.compute_loss(frames, actions, generator)
        out.loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
        optimizer.zero_grad()
        losses.append(float(out.loss.detach()))
    # Diffusion losses are noisy (random timestep and noise per step): compare means.
    return (sum(losses[:10]) / 10) / (sum(losses[-20:]) / 20)


def test_overfits_a_fixed_batch_quickly():
    assert _overfit(build_model("mcvd", "tiny", **SMALL), steps=120, lr=2e-3) >= 2.5


@pytest.mark.slow
def test_overfits_a_fixed_batch():
    ratio = _overfit(build_model("mcvd", "tiny", **SMALL), steps=500, lr=2e-3)
    print(f"loss ratio {ratio:.1f}")
    assert ratio >= 10


def test_planning_trial_with_two_sampling_steps():
    from tests.benchmark import tiny_suite_path
    from vp2.data.suite import TaskSuite
    from vp2.planning import PlannerConfig, PlanningAgent
    from vp2.run.trial import ControlTrial

    model = build_model("mcvd", "tiny", action_dim=4, sampling_steps=2)
    instance = TaskSuite.load(tiny_suite_path()).get("tabletop/push_sphere", 1)
    agent = PlanningAgent(model, PlannerConfig(num_samples=8))
    result = ControlTrial(instance, agent, seed=0, num_steps=3).run()
    assert result.actions.shape == (3, 4)
    assert float(abs(result.actions[1:]).max()) > 0


@pytest.mark.parametrize("steps", [1, 10, 100])
def test_sampler_recovers_the_frames_from_an_exact_noise_predictor(steps, monkeypatch):
    """With the true noise at every timestep the strided chain must stay on the forward
    process's marginals -- x_t = sqrt(ab_t) x_0 + sqrt(1 - ab_t) * unit noise at every visited
    t -- and end on the clean frames."""
    model = build_model("mcvd", "tiny", sampling_steps=steps, **SMALL)
    size = model.image_size
    gen = torch.Generator().manual_seed(0)
    clean = torch.rand(2, 3 * model.config.window, size, size, generator=gen) * 2 - 1

    noise_std = []

    def exact_eps(x, t, cond):
        ab = model.alphas_cumprod[t][:, None, None, None]
        eps = (x - ab.sqrt() * clean) / (1 - ab).sqrt()
        noise_std.append(float(eps.std()))
        return eps

    monkeypatch.setattr(model, "_denoiser", exact_eps)
    context = torch.rand(2, model.config.num_context, 3, size, size, generator=gen) * 2 - 1
    actions = torch.zeros(2, model.config.window + 1, 4)
    out = model.sample_window(context, actions, torch.Generator().manual_seed(1))
    torch.testing.assert_close(out.flatten(1, 2), clean, atol=1e-4, rtol=0)
    assert len(noise_std) == len(model.sampling_timesteps())
    assert all(abs(v - 1) < 0.03 for v in noise_std), noise_std
