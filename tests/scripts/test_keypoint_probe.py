"""``benchmarks.studies.keypoint_probe``: where a Struct-VRNN's action signal is lost."""

from __future__ import annotations

import pytest
import torch
from benchmarks.studies.keypoint_probe import probe

from vp2.models.registry import build_model


def _clips(n: int = 3, length: int = 12, size: int = 64) -> tuple[torch.Tensor, torch.Tensor]:
    """A light square sliding right by four pixels per frame, from a different row per clip."""
    frames = torch.full((n, length, 3, size, size), 0.4)
    for i in range(n):
        for t in range(length):
            frames[i, t, :, 8 + 12 * i : 20 + 12 * i, 4 * t : 4 * t + 12] = 0.8
    actions = torch.randn(n, length - 1, 5, generator=torch.Generator().manual_seed(0))
    return frames, actions.clamp(-1, 1)


class SquareTracker(torch.nn.Module):
    """A detector whose every keypoint sits on the light square's centroid."""

    def __init__(self, num_keypoints: int):
        super().__init__()
        self.k = num_keypoints

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mask = (x.mean(1) > 0.6).float()  # (N, H, W)
        lin = (torch.arange(x.shape[-1]) + 0.5) / x.shape[-1] * 2 - 1
        area = mask.sum((1, 2)).clamp(min=1)
        xy = torch.stack([(mask * lin).sum((1, 2)) / area, (mask * lin[:, None]).sum((1, 2)) / area], -1)
        return torch.cat([xy, torch.ones(len(x), 1)], -1)[:, None].expand(-1, self.k, -1)


def _model():
    return build_model(
        "struct_vrnn", "tiny", image_size=64, action_dim=5, num_future=10
    ).eval()


def test_a_decoder_blind_to_its_keypoint_maps_draws_the_same_frames_from_still_keypoints():
    model = _model()
    k = model.config.num_keypoints
    with torch.no_grad():  # the first conv's inputs: [G(k_t) (K), appearance, G(k_0) (K), xy]
        model.decoder.first[0].weight[:, :k] = 0
    frames, actions = _clips()
    out = probe(model, frames, actions)
    assert out["decoder"]["mse_own_keypoints"] == pytest.approx(
        out["decoder"]["mse_keypoints_held_still"], rel=1e-6
    )
    assert out["detector"]["motion_mean_px"] == pytest.approx(out["detector"]["motion_mean"] * 32)
    assert out["clips"] == 3


def test_a_decoder_that_reads_its_keypoints_draws_other_frames_when_they_are_held_still():
    model = _model()
    with torch.no_grad():  # a decoder whose residual is not ~0, as after training
        for p in model.decoder.parameters():
            p.normal_(0, 0.3, generator=torch.Generator().manual_seed(1))
    model.detector = SquareTracker(model.config.num_keypoints)
    frames, actions = _clips()
    out = probe(model, frames, actions)
    assert out["detector"]["motion_max"] == pytest.approx(44 / 32)  # 11 moves of 4 px
    assert out["decoder"]["mse_own_keypoints"] != pytest.approx(
        out["decoder"]["mse_keypoints_held_still"], rel=1e-6
    )


def test_predicted_keypoints_depend_on_the_actions_only_through_the_embedding():
    model = _model()
    frames, actions = _clips()

    def rollout(acts):  # the prior's mean: no sampling noise
        return model.rollout_keypoints(frames[:, :2], acts)[0]

    a = rollout(actions)
    assert a.shape == (3, 10, model.config.num_keypoints, 3)
    assert torch.equal(a, rollout(actions))
    assert not torch.allclose(a, rollout(actions.flip(0)))
    with torch.no_grad():
        model.dynamics.embed.weight[:, -5:] = 0
    assert torch.equal(rollout(actions), rollout(actions.flip(0)))


def test_the_probe_refuses_another_family():
    with pytest.raises(TypeError, match="needs a Struct-VRNN"):
        probe(torch.nn.Identity(), *_clips())
