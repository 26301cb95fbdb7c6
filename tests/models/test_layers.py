"""Pieces the models share: per-frame application, the skip rule, the reconstruction loss."""

from __future__ import annotations

import pytest
import torch

from vp2.models.layers import FrameLoss, context_skips, group_norm, per_frame


def test_per_frame_folds_time_into_the_batch_and_back():
    frames = torch.arange(2 * 3 * 4, dtype=torch.float32).view(2, 3, 4)  # (B, T, D)
    seen = []

    def fn(x):
        seen.append(tuple(x.shape))
        return x.sum(-1), [x * 2, x[:, :1]]

    total, (double, first) = per_frame(fn, frames)
    assert seen == [(6, 4)]
    assert total.shape == (2, 3) and torch.equal(total, frames.sum(-1))
    assert torch.equal(double, frames * 2) and first.shape == (2, 3, 1)


def test_context_skips_never_show_a_frame_its_own_target():
    # Frame t's skip holds the value t; reconstructing frames 1 .. 5 with 2 context frames
    # uses frame 0, then frame 1 (the last context frame) for every later step.
    skip = torch.arange(6, dtype=torch.float32).view(1, 6, 1, 1, 1).expand(2, 6, 1, 1, 1)
    (out,) = context_skips([skip], num_context=2)
    assert out.shape == (2 * 5, 1, 1, 1)
    assert out.view(2, 5).tolist() == [[0, 1, 1, 1, 1]] * 2


def test_frame_loss_terms_and_metric_order():
    pred, target = torch.zeros(2, 3, 3, 4, 4), torch.full((2, 3, 3, 4, 4), 0.5)
    plain = FrameLoss()(pred, target)
    assert plain.perceptual is None and torch.equal(plain.total, plain.mse)
    torch.testing.assert_close(plain.mse, torch.full((3,), 0.25))
    assert list(plain.metrics(kl=torch.tensor(1.0))) == ["mse", "kl"]

    def l1(p, t):
        return (p - t).abs().mean(dim=(1, 2, 3))

    weighted = FrameLoss(l1, 10.0)(pred, target)
    torch.testing.assert_close(weighted.total, torch.full((3,), 0.25 + 10 * 0.5))
    assert list(weighted.metrics(kl=torch.tensor(1.0))) == ["mse", "kl", "perceptual"]
    with pytest.raises(ValueError, match=r"expected shape \(6,\) for 6 frames"):
        FrameLoss(lambda p, t: p.mean(), 1.0)(pred, target)


def test_group_norm_groups_divide_the_channels():
    assert group_norm(64).num_groups == 32 and group_norm(48).num_groups == 16
    assert group_norm(30, affine=False).num_groups == 2 and not group_norm(30, affine=False).affine
