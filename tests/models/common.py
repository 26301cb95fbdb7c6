"""Shared checks for the per-model tests: overfitting and action conditioning."""

from __future__ import annotations

import torch

from tests.models.synthetic import moving_square_batch
from vp2.models import VideoPredictor


def overfit_ratio(model: VideoPredictor, steps: int, lr: float = 1e-3, seed: int = 0) -> float:
    """Trains on one fixed batch of 4 synthetic clips; returns first loss / mean of last 10."""
    frames, actions = moving_square_batch(4, size=model.image_size, action_dim=model.action_dim)
    optimizer = torch.optim.Adam(model.parameters(), lr)
    generator = torch.Generator().manual_seed(seed)
    losses = []
    for _ in range(steps):
        out = model.compute_loss(frames, actions, generator)
        out.loss.backward()
        optimizer.step()
        optimizer.zero_grad()
        losses.append(float(out.loss.detach()))
    return losses[0] / (sum(losses[-10:]) / 10)


def action_conditioning_gap(
    model: VideoPredictor, steps: int, lr: float = 1e-3
) -> tuple[float, float]:
    """Trains on 512 synthetic videos, then predicts 64 held-out ones from 2 frames.

    Returns ``(MSE with the true actions, MSE with another video's actions)``: a model that
    uses its actions predicts better with the true ones.
    """
    size, a = model.image_size, model.action_dim
    frames, actions = moving_square_batch(512, size=size, action_dim=a, seed=0)
    test_frames, test_actions = moving_square_batch(64, size=size, action_dim=a, seed=1)
    optimizer = torch.optim.Adam(model.parameters(), lr)
    generator = torch.Generator().manual_seed(0)
    for _ in range(steps):
        idx = torch.randint(0, len(frames), (16,), generator=generator)
        model.compute_loss(frames[idx], actions[idx], generator).loss.backward()
        optimizer.step()
        optimizer.zero_grad()
    context, future = test_frames[:, :2], test_frames[:, 2:]
    # Keep actions[:, 0] (it produced the context frame); swap the candidate actions.
    other = torch.cat([test_actions[:, :1], test_actions.roll(1, 0)[:, 1:]], 1)
    true_mse = float(((model.predict(context, test_actions) - future) ** 2).mean())
    other_mse = float(((model.predict(context, other) - future) ** 2).mean())
    return true_mse, other_mse


def check_loss_composition(model: VideoPredictor, frames_sum_over_time: bool) -> None:
    """The loss is reconstruction + beta * KL, and a perceptual term adds ``weight * d``."""
    frames, actions = moving_square_batch(2, size=model.image_size, action_dim=model.action_dim)
    out = model.compute_loss(frames, actions, torch.Generator().manual_seed(0))
    assert out.predictions.shape == (2, 11, 3, model.image_size, model.image_size)
    preds = out.predictions.detach()
    assert 0 <= float(preds.min()) and float(preds.max()) <= 1
    steps = 11 if frames_sum_over_time else 1
    expected = steps * out.metrics["mse"] + model.config.beta * out.metrics["kl"]
    torch.testing.assert_close(out.loss.detach(), expected, rtol=1e-5, atol=1e-7)
    # Recomputing the MSE from the returned predictions gives the logged value.
    torch.testing.assert_close(((preds - frames[:, 1:]) ** 2).mean(), out.metrics["mse"])

    def l1(pred, target):  # a stand-in for LPIPS: (N, 3, H, W) x 2 -> (N,)
        return (pred - target).abs().mean(dim=(1, 2, 3))

    with_p = model.compute_loss(frames, actions, torch.Generator().manual_seed(0), l1, 10.0)
    d = (preds - frames[:, 1:]).abs().mean()
    torch.testing.assert_close(with_p.metrics["perceptual"], d, rtol=1e-5, atol=1e-7)
    torch.testing.assert_close(
        with_p.loss.detach(), out.loss.detach() + steps * 10.0 * d, rtol=1e-5, atol=1e-6
    )
    with_p.loss.backward()  # differentiable through the perceptual term
