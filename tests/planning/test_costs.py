"""Costs on hand-made images with exact expected values (SPEC §5, §6)."""

from __future__ import annotations

import pytest
import torch

from vp2.planning.costs import (
    ClassifierCost,
    EnsembleCost,
    PerceptualCost,
    PixelSSE,
    WeightedCost,
    choose_members,
    classifier_cost,
    ensemble_disagreement,
    pixel_sse,
    robodesk_cost,
    tabletop_cost,
)

N, T, C, S = 2, 3, 3, 2  # samples, frames, channels, image side
PIXELS = T * C * S * S  # 36 values per sample


def _frames(*values: float) -> torch.Tensor:
    """(N, T, C, S, S) frames; sample n is the constant image values[n] in every frame."""
    return torch.stack([torch.full((T, C, S, S), v) for v in values])


def test_pixel_sse_sums_over_frames_channels_and_pixels() -> None:
    goal = torch.zeros(C, S, S)
    torch.testing.assert_close(
        pixel_sse(_frames(0.5, 0.0), goal), torch.tensor([0.25 * PIXELS, 0.0])
    )

    frames = torch.zeros(1, T, C, S, S)
    frames[0, 1, 2, 0, 1] = 1.0  # one wrong value in one frame
    frames[0, 2, 0, 1, 1] = 0.5
    torch.testing.assert_close(pixel_sse(frames, goal), torch.tensor([1.25]))


def test_pixel_sse_with_a_goal_per_frame() -> None:
    goal = torch.stack([torch.full((C, S, S), v) for v in (0.0, 0.5, 1.0)])  # (T, C, H, W)
    # sample 0 is all 0.5: errors 0.25, 0, 0.25 per value; sample 1 all 1.0: 1, 0.25, 0.
    expected = torch.tensor([0.5 * C * S * S, 1.25 * C * S * S])
    torch.testing.assert_close(pixel_sse(_frames(0.5, 1.0), goal), expected)


def test_pixel_sse_rejects_mismatched_goals() -> None:
    with pytest.raises(ValueError, match="goal"):
        pixel_sse(_frames(0.5, 0.0), torch.zeros(C, S + 1, S))
    with pytest.raises(ValueError, match="frames"):
        pixel_sse(_frames(0.5, 0.0), torch.zeros(T + 1, C, S, S))
    with pytest.raises(ValueError, match=r"\(N, T, C, H, W\)"):
        pixel_sse(torch.zeros(T, C, S, S), torch.zeros(C, S, S))


def test_pixel_sse_is_differentiable() -> None:
    frames = _frames(0.5, 0.0).requires_grad_(True)
    pixel_sse(frames, torch.zeros(C, S, S)).sum().backward()
    torch.testing.assert_close(frames.grad, 2 * frames.detach())


def test_classifier_cost_is_minus_the_summed_logits() -> None:
    logits = torch.tensor([[1.0, 2.0, 3.0], [-1.0, 0.0, 0.5]])
    torch.testing.assert_close(classifier_cost(logits), torch.tensor([-6.0, 0.5]))


def _mean_intensity_classifier(images: torch.Tensor) -> torch.Tensor:
    """A stand-in success classifier: logit = mean pixel value, shape (M, 1) like nn.Linear."""
    return images.mean(dim=(1, 2, 3))[:, None]


@pytest.mark.parametrize("max_batch_size", [None, 2, 4])
def test_classifier_term_runs_the_classifier_on_every_frame(max_batch_size) -> None:
    frames = torch.zeros(N, T, C, S, S)
    for n in range(N):
        for t in range(T):
            frames[n, t] = 0.1 * (3 * n + t)  # distinct per frame: catches ordering mistakes
    cost = ClassifierCost(_mean_intensity_classifier, max_batch_size=max_batch_size)(frames)
    torch.testing.assert_close(cost, -torch.tensor([0.0 + 0.1 + 0.2, 0.3 + 0.4 + 0.5]))


class _Counting:
    """The mean-intensity classifier, counting the images it is shown."""

    def __init__(self) -> None:
        self.images = 0

    def __call__(self, images: torch.Tensor) -> torch.Tensor:
        self.images += images.shape[0]
        return _mean_intensity_classifier(images)


def test_one_image_in_every_frame_is_classified_once() -> None:
    # The repeat-last-frame baseline's predictions: one image for every sample and step.
    frames = torch.rand(1, 1, C, S, S).expand(5, T, C, S, S).contiguous()
    counting = _Counting()
    cost = ClassifierCost(counting, max_batch_size=4)(frames)
    assert counting.images == 1
    logit = _mean_intensity_classifier(frames[0, :1]).reshape(())
    assert torch.equal(cost, classifier_cost(logit.repeat(5, T))) and cost.is_contiguous()
    # One value off in one frame, or a gradient to carry: every frame goes through, as before.
    for changed in (frames.clone(), frames.clone().requires_grad_(True)):
        if not changed.requires_grad:
            changed[4, T - 1, 2, S - 1, S - 1] += 1e-6
        counting = _Counting()
        ClassifierCost(counting)(changed)
        assert counting.images == 5 * T
    # A goal per predicted frame makes the perceptual term's pairs differ: all go through.
    seen = []
    distance = lambda x, y: seen.append(x.shape[0]) or (x - y).abs().flatten(1).sum(1)  # noqa: E731
    same = PerceptualCost(distance, torch.zeros(C, S, S))(frames)
    per_step = PerceptualCost(distance, torch.rand(T, C, S, S))(frames)
    assert seen == [1, 5 * T] and per_step.shape == (5,)
    torch.testing.assert_close(same, frames[:, 0].flatten(1).sum(1) * T)


def test_robodesk_score_is_half_pixel_sse_and_ten_times_the_logits() -> None:
    goal = torch.zeros(C, S, S)
    frames = _frames(0.5, 1.0)
    cost = robodesk_cost(goal, _mean_intensity_classifier)
    sse = torch.tensor([0.25 * PIXELS, 1.0 * PIXELS])
    logit_sums = torch.tensor([3 * 0.5, 3 * 1.0])
    torch.testing.assert_close(cost.score(frames), -0.5 * sse + 10 * logit_sums)
    torch.testing.assert_close(cost(frames), 0.5 * sse - 10 * logit_sums)
    pixel_part, classifier_part = cost.breakdown(frames)
    torch.testing.assert_close(pixel_part, 0.5 * sse)
    torch.testing.assert_close(classifier_part, -10 * logit_sums)


def test_tabletop_cost_is_the_pixel_sse() -> None:
    goal = torch.full((C, S, S), 0.25)
    frames = _frames(0.5, 0.0)
    torch.testing.assert_close(tabletop_cost(goal)(frames), pixel_sse(frames, goal))


def test_weighted_cost_composes_arbitrary_terms() -> None:
    frames = _frames(0.5, 1.0)
    constant = lambda f: torch.ones(f.shape[0])  # noqa: E731
    cost = WeightedCost([(2.0, PixelSSE(torch.zeros(C, S, S))), (-3.0, constant)])
    torch.testing.assert_close(cost(frames), torch.tensor([2 * 9.0 - 3, 2 * 36.0 - 3]))
    with pytest.raises(ValueError):
        WeightedCost([])


def test_perceptual_term_sums_a_per_image_distance_over_frames() -> None:
    def mean_abs(images: torch.Tensor, goals: torch.Tensor) -> torch.Tensor:
        assert images.shape == goals.shape == (images.shape[0], C, S, S)
        return (images - goals).abs().mean(dim=(1, 2, 3))

    goal = torch.full((C, S, S), 0.25)
    cost = PerceptualCost(mean_abs, goal, max_batch_size=4)
    torch.testing.assert_close(cost(_frames(0.5, 0.0)), torch.tensor([3 * 0.25, 3 * 0.25]))

    bad = PerceptualCost(lambda x, y: torch.zeros(1), goal)
    with pytest.raises(ValueError, match="one value per image"):
        bad(_frames(0.5, 0.0))


def _ensemble() -> torch.Tensor:
    """(M=3, N=2, T, C, S, S): sample 0 disagrees (members 0, 0.3, 0.9), sample 1 agrees (0.5)."""
    members = []
    for value in (0.0, 0.3, 0.9):
        members.append(
            torch.stack([torch.full((T, C, S, S), value), torch.full((T, C, S, S), 0.5)])
        )
    return torch.stack(members)


def test_ensemble_disagreement_is_the_largest_l1_deviation_from_the_mean() -> None:
    # Mean 0.4: deviations 0.4, 0.1, 0.5 per value; the largest is 0.5 * 36.
    torch.testing.assert_close(
        ensemble_disagreement(_ensemble()), torch.tensor([0.5 * PIXELS, 0.0])
    )


def test_ensemble_cost_is_a_random_members_cost_plus_the_penalty() -> None:
    predictions = _ensemble()
    goal = torch.zeros(C, S, S)
    cost = EnsembleCost(PixelSSE(goal), torch.Generator().manual_seed(0), lam=0.01)(predictions)
    member_costs = torch.stack([pixel_sse(p, goal) for p in predictions])  # (M, N)
    penalty = 0.01 * torch.tensor([0.5 * PIXELS, 0.0])
    assert any(torch.isclose(cost[0], c + penalty[0]) for c in member_costs[:, 0])
    torch.testing.assert_close(cost[1], member_costs[0, 1])  # members agree: no penalty


def test_ensemble_member_choice_comes_from_the_generator() -> None:
    predictions = _ensemble().repeat(1, 32, 1, 1, 1, 1)  # N = 64
    term = PixelSSE(torch.zeros(C, S, S))
    cost = lambda seed, **kw: EnsembleCost(term, torch.Generator().manual_seed(seed), **kw)(  # noqa: E731
        predictions
    )
    assert torch.equal(cost(3), cost(3))
    assert not torch.equal(cost(3), cost(4))
    assert len(set(cost(3)[0::2].tolist())) == 3  # per-sample choice: every member shows up
    assert len(set(cost(3, per_sample=False)[0::2].tolist())) == 1

    members = choose_members(3, 1000, torch.Generator().manual_seed(0))
    assert members.min() == 0 and members.max() == 2
    assert abs(float((members == 1).float().mean()) - 1 / 3) < 0.05
