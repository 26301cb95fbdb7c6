"""Per-task planner settings and costs: SPEC defaults, the classifier fallback."""

from __future__ import annotations

import pytest
import torch

from vp2.classifiers.registry import ClassifierRegistry
from vp2.planning.costs import pixel_sse
from vp2.planning.planner import PlannerConfig, build_cost, planner_settings


def test_planner_defaults_follow_the_spec():
    push = planner_settings("robodesk/push_red", PlannerConfig())
    assert push == {
        "optimizer": "mppi",
        "sigma": [0.5, 0.5, 0.5, 0.1, 0.1],
        "num_samples": 200,
        "gamma": 0.05,
    }
    for task in ("robodesk/open_slide", "robodesk/open_drawer"):
        assert planner_settings(task, PlannerConfig())["num_samples"] == 800
    tabletop = planner_settings("tabletop/push_cylinder", PlannerConfig())
    assert tabletop["sigma"] == [0.5, 0.5, 0.5, 0.0] and tabletop["num_samples"] == 200
    # Test-sized overrides apply to every task alike.
    assert planner_settings("robodesk/open_slide", PlannerConfig(num_samples=8))["num_samples"] == 8
    assert (
        planner_settings("tabletop/push_sphere", PlannerConfig(optimizer="cem"))["num_samples"]
        == 200
    )
    with pytest.raises(ValueError, match="unknown optimizer"):
        planner_settings("tabletop/push_sphere", PlannerConfig(optimizer="adam"))
    with pytest.raises(ValueError, match="sigma has 2 entries"):
        planner_settings("tabletop/push_sphere", PlannerConfig(sigma=(0.1, 0.1)))


def _frames(seed: int, n: int = 3) -> torch.Tensor:
    return torch.rand(n, 10, 3, 8, 8, generator=torch.Generator().manual_seed(seed))


def test_tabletop_cost_is_pixel_sse_and_robodesk_falls_back_to_half_of_it():
    goal, frames = torch.rand(3, 8, 8), _frames(0)
    cost, kind = build_cost("tabletop/push_sphere", goal, classifiers=ClassifierRegistry())
    assert kind == "pixel"
    torch.testing.assert_close(cost(frames), pixel_sse(frames, goal))
    cost, kind = build_cost("robodesk/push_red", goal, classifiers=ClassifierRegistry())
    assert kind == "pixel_only"
    torch.testing.assert_close(cost(frames), 0.5 * pixel_sse(frames, goal))


def test_robodesk_cost_uses_the_registered_classifier():
    registry = ClassifierRegistry()
    # A "classifier" whose logit is the mean red value: checkable by hand.
    registry.register("robodesk/push_red", lambda device: lambda x: x[:, 0].mean(dim=(1, 2)))
    goal, frames = torch.rand(3, 8, 8), _frames(1)
    cost, kind = build_cost("robodesk/push_red", goal, classifiers=registry)
    assert kind == "pixel+classifier"
    logits = frames[:, :, 0].mean(dim=(2, 3))  # (N, T)
    expected = 0.5 * pixel_sse(frames, goal) - 10 * logits.sum(dim=1)
    torch.testing.assert_close(cost(frames), expected)
    # Other tasks still have none; "pixel_only" ignores a registered one; "spec" insists.
    assert build_cost("robodesk/push_blue", goal, classifiers=registry)[1] == "pixel_only"
    assert build_cost("robodesk/push_red", goal, "pixel_only", registry)[1] == "pixel_only"
    with pytest.raises(ValueError, match="no success classifier"):
        build_cost("robodesk/push_blue", goal, "spec", registry)


def test_the_cost_choice_lives_with_the_costs():
    """``build_cost`` and its types moved to ``costs.py``; the old import paths still work."""
    import vp2.planning
    from vp2.planning import costs, planner

    for name in ("build_cost", "COST_MODES", "CostKind", "CostMode"):
        assert getattr(planner, name) is getattr(costs, name) is getattr(vp2.planning, name)
