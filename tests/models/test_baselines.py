"""Baseline models: repeating the last context frame."""

from __future__ import annotations

import torch

from vp2.models.baselines import RepeatLastFrame
from vp2.models.contract import CheckedModel


def test_repeat_last_frame():
    model = CheckedModel(RepeatLastFrame(action_dim=5))
    context = torch.rand(3, 2, 3, 64, 64)
    out = model.predict(context, torch.zeros(3, 11, 5))
    assert out.shape == (3, 10, 3, 64, 64) and out.dtype == torch.float32
    torch.testing.assert_close(out, context[:, 1:].expand(-1, 10, -1, -1, -1))
    # The interface's keywords are accepted (and ignored) when called directly.
    direct = RepeatLastFrame(action_dim=5).predict(
        context, torch.zeros(3, 11, 5), generator=torch.Generator(), grad=False
    )
    torch.testing.assert_close(direct, out)
