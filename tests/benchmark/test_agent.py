"""The planning agent: planner defaults, costs per task, the objective it hands the optimizer."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vp2.benchmark.agent import (
    ClassifierRegistry,
    Observation,
    PlannerConfig,
    PlanningAgent,
    build_cost,
    planner_settings,
)
from vp2.models.reference import RepeatLastFrame
from vp2.planning import MPPI, shift_plan
from vp2.planning.costs import pixel_sse


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


class RecordingModel(RepeatLastFrame):
    """Records its inputs; predicts uniform frames of brightness ``(mean_t a_t[0] + 1) / 2``,
    so that the objective depends on the candidate actions."""

    def __init__(self, action_dim: int, max_batch_size: int) -> None:
        super().__init__(action_dim, image_size=8, max_batch_size=max_batch_size)
        self.calls: list[tuple[torch.Tensor, torch.Tensor]] = []

    def predict(self, context_frames, actions, *, generator=None, grad=None):
        self.calls.append((context_frames.clone(), actions.clone()))
        level = (actions[:, 1:, 0].mean(dim=1) + 1) / 2  # (B,) in [0, 1]
        return level[:, None, None, None, None].expand(-1, 10, 3, 8, 8).float().contiguous()


def _observation(step: int, last_action: np.ndarray) -> Observation:
    rng = np.random.default_rng(step)
    frames = rng.integers(0, 256, (step + 1, 8, 8, 3), dtype=np.uint8)
    return Observation(step, frames, last_action, env_meta={}, state=np.zeros(3))


def test_objective_feeds_the_model_the_spec_inputs_in_chunks():
    model = RecordingModel(action_dim=4, max_batch_size=3)
    agent = PlanningAgent(model, PlannerConfig(num_samples=8))
    goal = np.full((8, 8, 3), 255, np.uint8)  # white: brighter predictions cost less
    agent.reset("tabletop/push_sphere", goal, seed=0)
    last = np.array([0.1, -0.2, 0.3, 0.0])
    obs = _observation(2, last)
    action, info = agent.act(obs)
    # 8 samples in chunks of at most 3.
    assert [c[0].shape[0] for c in model.calls] == [3, 3, 2]
    context = torch.cat([c[0] for c in model.calls])  # (8, 2, 3, 8, 8)
    actions = torch.cat([c[1] for c in model.calls])  # (8, 11, 4)
    expected_context = torch.from_numpy(obs.frames[-2:]).permute(0, 3, 1, 2).float() / 255
    torch.testing.assert_close(context, expected_context.expand(8, -1, -1, -1, -1))
    assert actions.shape == (8, 11, 4)
    torch.testing.assert_close(actions[:, 0], torch.tensor(last, dtype=torch.float32).expand(8, 4))
    assert info["num_evaluations"] == 8
    torch.testing.assert_close(actions[:, 1:].abs().max() <= 1, torch.tensor(True))
    assert action.shape == (4,) and np.all(np.abs(action) <= 1)


def test_agent_plan_matches_mppi_on_the_same_objective_and_warm_starts():
    model = RecordingModel(action_dim=4, max_batch_size=100)
    agent = PlanningAgent(model, PlannerConfig(num_samples=16))
    goal = np.full((8, 8, 3), 255, np.uint8)
    agent.reset("tabletop/push_sphere", goal, seed=3)
    obs = _observation(1, np.zeros(4))
    generator_state = agent.generator.get_state()
    action, _ = agent.act(obs)
    # Replay with a bare MPPI: same objective, same generator state, zero initial mean.
    replay = PlanningAgent(RecordingModel(4, 100), PlannerConfig(num_samples=16))
    replay.reset("tabletop/push_sphere", goal, seed=3)
    context = torch.from_numpy(obs.frames[-2:]).permute(0, 3, 1, 2).float() / 255
    objective = replay.objective(context, torch.zeros(4))
    gen = torch.Generator().manual_seed(0)
    gen.set_state(generator_state)
    plan, _ = MPPI([0.5, 0.5, 0.5, 0.0], num_samples=16).optimize(
        objective, torch.zeros(10, 4), gen
    )
    np.testing.assert_allclose(action, plan[0].numpy(), rtol=0, atol=1e-6)
    torch.testing.assert_close(agent.plan, shift_plan(plan))
    # The objective rewards bright predictions, i.e. a large first action coordinate.
    assert plan[:, 0].mean() > 0


def test_agent_hands_the_state_only_to_models_that_ask_for_it():
    class StateModel(RepeatLastFrame):
        needs_simulator_state = True

        def __init__(self):
            super().__init__(action_dim=4, image_size=8)
            self.seen = []

        def set_simulator_state(self, env_meta, state):
            self.seen.append((env_meta, state.copy()))

    model = StateModel()
    agent = PlanningAgent(model, PlannerConfig(num_samples=4))
    agent.reset("tabletop/push_sphere", np.zeros((8, 8, 3), np.uint8), seed=0)
    obs = _observation(1, np.zeros(4))
    obs.env_meta, obs.state = {"name": "x"}, np.arange(3.0)
    agent.act(obs)
    assert len(model.seen) == 1 and model.seen[0][0] == {"name": "x"}
    np.testing.assert_array_equal(model.seen[0][1], np.arange(3.0))


def test_agent_checks_the_model_at_the_boundary():
    class Bad(RepeatLastFrame):
        def predict(self, context_frames, actions, *, generator=None, grad=None):
            return super().predict(context_frames, actions)[:, :9]

    agent = PlanningAgent(Bad(action_dim=4, image_size=8), PlannerConfig(num_samples=4))
    agent.reset("tabletop/push_sphere", np.zeros((8, 8, 3), np.uint8), seed=0)
    with pytest.raises(ValueError, match=r"repeat_last_frame\.predict: output: expected shape"):
        agent.act(_observation(1, np.zeros(4)))
