from __future__ import annotations

import pytest
import torch

from tests.models.common import overfit_ratio
from tests.models.synthetic import moving_square_batch, write_moving_square_dataset
from vp2.models import MaskViT, MaskViTTokenizer, build_model, load_model, model_from_config
from vp2.models.maskvit.transformer import WindowBlock

SMALL = {"action_dim": 4, "image_size": 32}



def test_tokenizer_maps_frames_to_16x16_tokens():
    tokenizer = build_model("maskvit_tokenizer", "tiny", action_dim=4)
    frames = torch.rand(3, 3, 64, 64)
    tokens = tokenizer.tokenize(frames)
    assert tokens.shape == (3, 16, 16) and tokens.dtype == torch.long
    assert 0 <= int(tokens.min()) and int(tokens.max()) < tokenizer.config.codebook_size
    decoded = tokenizer.detokenize(tokens).detach()
    assert decoded.shape == (3, 3, 64, 64)
    assert 0 <= float(decoded.min()) and float(decoded.max()) <= 1
    # A token's code is the codebook entry most similar to the (normalised) encoder output.
    z = torch.nn.functional.normalize(tokenizer.encoder(frames), dim=1)  # (3, D, 16, 16)
    sims = torch.einsum("ndhw,kd->nkhw", z, tokenizer._codes())
    torch.testing.assert_close(tokens, sims.argmax(1), rtol=0, atol=0)


def test_tokenizer_loss_and_adversarial_term():
    frames, actions = moving_square_batch(2, size=32, action_dim=4)
    tokenizer = build_model("maskvit_tokenizer", "tiny", **SMALL)
    out = tokenizer.compute_loss(frames, actions, torch.Generator())
    torch.testing.assert_close(out.loss.detach(), out.metrics["mse"] + out.metrics["vq"])
    assert "d_loss" not in out.metrics  # before adv_start
    out.loss.backward()
    assert float(tokenizer.encoder.net[0].weight.grad.abs().sum()) > 0  # straight-through
    assert tokenizer.discriminator.net[0].weight.grad is None
    gan = build_model("maskvit_tokenizer", "tiny", adv_start=0, **SMALL)
    out = gan.compute_loss(frames, actions, torch.Generator())
    m = out.metrics
    expected = m["mse"] + m["vq"] + 0.1 * m["g_adv"] + m["d_loss"]
    torch.testing.assert_close(out.loss.detach(), expected, rtol=1e-5, atol=1e-6)
    # The generator term reaches the decoder only: with detached discriminator weights it
    # cannot change the discriminator; the hinge loss on detached fakes trains it.
    gan.zero_grad()
    out.loss.backward()
    assert float(gan.discriminator.net[0].weight.grad.abs().sum()) > 0
    # The tokenizer as a predictor: the last context frame through the codec, every step.
    pred = tokenizer.predict(frames[:, :2], actions.clamp(-1, 1))
    assert pred.shape == (2, 10, 3, 32, 32)
    torch.testing.assert_close(pred[:, 0], pred[:, 9], rtol=0, atol=0)
    assert MaskViTTokenizer.stochastic is False


def test_tokenizer_overfits_a_fixed_batch():
    ratio = overfit_ratio(build_model("maskvit_tokenizer", "tiny", **SMALL), steps=60)
    assert ratio >= 10


def _window_members(block, t: int, h: int, w: int) -> list[set[tuple[int, int, int]]]:
    """The ``(frame, row, column)`` tokens each attention window of ``block`` holds, read from
    the block's own windowing of a tensor whose features are the token coordinates."""
    coords = torch.stack(torch.meshgrid(torch.arange(t), torch.arange(h), torch.arange(w),
                                        indexing="ij"), dim=-1).float()[None]  # (1, T, h, w, 3)
    windows, shape = block._windows(coords)  # noqa: SLF001 - the mask is what is tested
    assert torch.equal(block._unwindows(windows, shape), coords)  # noqa: SLF001
    return [{tuple(int(v) for v in token) for token in window} for window in windows]


def test_window_attention_is_local():
    """A spatial block's windows are the frames; a spatiotemporal block's are T x 4 x 4 columns
    of tokens. Asserted on the windows themselves, then on a block's output: a change to one
    token never reaches a token outside its window (exactly zero there on any CPU)."""
    spatial = _window_members(WindowBlock(16, 2, 2.0, spatial=True, window=4), 3, 8, 8)
    assert spatial == [{(f, i, j) for i in range(8) for j in range(8)} for f in range(3)]
    spatiotemporal = _window_members(WindowBlock(16, 2, 2.0, spatial=False, window=4), 3, 8, 8)
    assert spatiotemporal == [
        {(f, i, j) for f in range(3) for i in range(r, r + 4) for j in range(c, c + 4)}
        for r in (0, 4) for c in (0, 4)
    ]
    torch.manual_seed(0)
    x = torch.randn(1, 3, 8, 8, 16)  # (B, T, h, w, D)
    changed = x.clone()
    changed[0, 1, 0, 0] += 3.0  # frame 1, token (0, 0)
    for is_spatial in (True, False):
        block = WindowBlock(16, 2, 2.0, spatial=is_spatial, window=4)
        reached = (block(changed) - block(x)).abs().sum(-1)[0] > 0  # (T, h, w)
        if is_spatial:
            assert not reached[0].any() and not reached[2].any() and reached[1].any()
        else:
            assert not reached[:, 4:].any() and not reached[:, :, 4:].any()
            assert reached[0, :4, :4].any() and reached[2, :4, :4].any()


def test_actions_are_embedded_into_their_frame():
    """Frame t's tokens get the action that produced it (a_{t-1})."""
    model = build_model("maskvit", "tiny", depth=1, **SMALL)  # one spatial block: no mixing
    tokens = torch.randint(0, 64, (1, 12, 8, 8))
    actions = torch.zeros(1, 11, 4)
    changed = actions.clone()
    changed[0, 3] = 1.0
    with torch.no_grad():
        diff = (model.logits(tokens, changed) - model.logits(tokens, actions)).abs().sum((2, 3, 4))
    assert diff[0].nonzero().flatten().tolist() == [4]


def test_training_masks_only_future_tokens():
    model = build_model("maskvit", "tiny", **SMALL)
    frames, actions = moving_square_batch(4, size=32, action_dim=4)
    seen = []
    original = model.logits

    def spy(tokens, acts):
        seen.append(tokens.clone())
        return original(tokens, acts)

    model.logits = spy  # type: ignore[method-assign]
    out = model.compute_loss(frames, actions, torch.Generator().manual_seed(0))
    (tokens,) = seen
    masked = tokens == model.mask_id  # (B, T, h, w)
    assert not masked[:, :2].any()
    ratios = masked[:, 2:].flatten(1).float().mean(1)
    assert float(ratios.min()) >= 0.5 and float(ratios.max()) <= 1.0
    assert float(out.metrics["mask_ratio"]) == pytest.approx(float(ratios.mean()))
    assert out.predictions.shape == (4, 11, 3, 32, 32)
    assert float(out.loss.detach()) == pytest.approx(float(out.metrics["ce"]))


def test_iterative_decoding_follows_the_mask_schedule():
    model = build_model("maskvit", "tiny", **SMALL)
    frames = torch.rand(2, 2, 3, 32, 32)
    actions = torch.zeros(2, 11, 4)
    masked_counts = []
    original = model.logits

    def spy(tokens, acts):
        masked_counts.append(int((tokens == model.mask_id).sum()) // 2)
        return original(tokens, acts)

    model.logits = spy  # type: ignore[method-assign]
    out = model.predict(frames, actions)
    n = 10 * 8 * 8
    # cos schedule with 5 iterations: all masked, then floor(n cos(pi/2 i/5)) left masked.
    assert masked_counts == [640, 608, 517, 376, 197]
    assert len(masked_counts) == model.config.decoding_iterations == 5 and masked_counts[0] == n
    assert out.shape == (2, 10, 3, 32, 32)


def test_overfits_a_fixed_batch():
    # ~25 s on one core: the token loss memorises 4 clips once the model has seen enough masks.
    ratio = overfit_ratio(build_model("maskvit", "tiny", **SMALL), steps=200, lr=3e-3)
    assert ratio >= 10


def test_trains_with_a_trained_tokenizer_and_checkpoints_are_self_contained(tmp_path):
    from vp2.training import TrainConfig, train

    data = write_moving_square_dataset(tmp_path / "data", num_trajectories=6, size=32)
    common = dict(dataset=str(data), steps=2, batch_size=2, workers=0, progress=False,
                  tensorboard=False, eval_batches=1, device="cpu")  # fmt: skip
    tok = train(TrainConfig(model="maskvit_tokenizer", preset="tiny",
                            out_dir=str(tmp_path / "tok"), **common))  # fmt: skip
    run = train(
        TrainConfig(
            model="maskvit",
            preset="tiny",
            out_dir=str(tmp_path / "mvit"),
            model_overrides={"tokenizer_checkpoint": str(tmp_path / "tok")},
            **common,
        )
    )
    tokenizer = load_model(tok.checkpoint, device="cpu")
    model = load_model(run.checkpoint, device="cpu")  # no tokenizer file needed
    assert isinstance(model, MaskViT)
    assert model.config.tokenizer_checkpoint is None
    assert model.config.tokenizer_source == str(tmp_path / "tok")
    for k, v in tokenizer.state_dict().items():
        torch.testing.assert_close(model.tokenizer.state_dict()[k], v, rtol=0, atol=0, msg=k)
    # The tokenizer stayed frozen while the transformer trained.
    fresh = model_from_config("maskvit", model.config_dict())
    assert all(not p.requires_grad for p in fresh.tokenizer.parameters())
    with pytest.raises(ValueError, match="not a maskvit_tokenizer"):
        build_model("maskvit", "tiny", tokenizer_checkpoint=str(run.checkpoint), **SMALL)


def test_planning_trial_with_tiny_maskvit():
    from tests.benchmark import tiny_suite_path
    from vp2.data.suite import TaskSuite
    from vp2.planning import PlannerConfig, PlanningAgent
    from vp2.run.trial import ControlTrial

    model = build_model("maskvit", "tiny", action_dim=4)
    instance = TaskSuite.load(tiny_suite_path()).get("tabletop/push_sphere", 1)
    agent = PlanningAgent(model, PlannerConfig(num_samples=8))
    result = ControlTrial(instance, agent, seed=0, num_steps=3).run()
    assert result.actions.shape == (3, 4)
    assert float(abs(result.actions[1:]).max()) > 0
