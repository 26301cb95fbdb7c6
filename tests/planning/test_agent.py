"""The planning agent: the objective it hands the optimizer; the random-action baseline."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vp2.models.baselines import RepeatLastFrame
from vp2.planning import MPPI, shift_plan
from vp2.planning.agent import Observation, PlanningAgent, RandomActions
from vp2.planning.planner import PlannerConfig


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


def test_random_actions_are_seeded_and_uniform():
    agent = RandomActions(action_dim=5)
    agent.reset("robodesk/push_red", np.zeros((64, 64, 3), np.uint8), seed=3)
    a = np.stack([agent.act(None)[0] for _ in range(2000)])
    agent.reset("robodesk/push_red", np.zeros((64, 64, 3), np.uint8), seed=3)
    b = np.stack([agent.act(None)[0] for _ in range(2000)])
    np.testing.assert_array_equal(a, b)
    assert a.shape == (2000, 5) and a.min() >= -1 and a.max() <= 1
    np.testing.assert_allclose(a.mean(axis=0), 0, atol=0.06)
    np.testing.assert_allclose(a.var(axis=0), 1 / 3, atol=0.03)


def test_trial_records_name_the_classifier_file_they_planned_with(tmp_path):
    import hashlib

    from vp2.classifiers.checkpoint import load_classifier, save_classifier
    from vp2.classifiers.networks import build_classifier
    from vp2.classifiers.registry import ClassifierRegistry

    meta = {"arch": "ours", "task": "robodesk/push_red", "image_size": 64,
            "data": {"dataset": "data/x"}, "heldout": {"accuracy": 0.98765}}
    path = save_classifier(tmp_path / "push_red.pt", build_classifier("ours"), meta)
    registry = ClassifierRegistry()
    registry.register("robodesk/push_red", lambda device: load_classifier(path, device))
    model = RepeatLastFrame(action_dim=5, image_size=64)
    agent = PlanningAgent(model, PlannerConfig(num_samples=4), classifiers=registry)
    agent.reset("robodesk/push_red", np.zeros((64, 64, 3), np.uint8), seed=0)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    assert agent.describe()["cost"] == "pixel+classifier"
    assert agent.describe()["classifier"] == {
        "sha256": digest[:16], "dataset": "data/x", "heldout_accuracy": 0.9877, "weight": 10.0}
    agent.reset("robodesk/push_green", np.zeros((64, 64, 3), np.uint8), seed=0)
    assert agent.describe()["cost"] == "pixel_only" and "classifier" not in agent.describe()
