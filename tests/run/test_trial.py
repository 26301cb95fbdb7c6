"""ControlTrial on a tiny hand-made suite with cheap agents and a reduced planner."""

from __future__ import annotations

import numpy as np
import pytest

from tests.benchmark import tiny_suite_path
from vp2.classifiers.registry import ClassifierRegistry
from vp2.data.suite import TaskSuite
from vp2.models.baselines import RepeatLastFrame
from vp2.planning import PlannerConfig, PlanningAgent, RandomActions
from vp2.run.trial import ControlTrial, trial_seed

STEPS = 3


@pytest.fixture(scope="module")
def suite() -> TaskSuite:
    return TaskSuite.load(tiny_suite_path(include_robodesk=True))


@pytest.fixture(scope="module")
def tabletop_env(suite):
    env = suite.get("tabletop/push_sphere", 0).make_env(observation_size=None)
    yield env
    env.close()


def _agent(action_dim: int = 4) -> PlanningAgent:
    return PlanningAgent(RepeatLastFrame(action_dim), PlannerConfig(num_samples=8))


def test_trial_records_the_spec_fields(suite, tabletop_env):
    solved, unsolved = suite.get("tabletop/push_sphere", 0), suite.get("tabletop/push_sphere", 1)
    result = ControlTrial(solved, _agent(), seed=0, num_steps=STEPS, env=tabletop_env).run()
    # The goal of instance 0 is its initial object layout: success from the first step on.
    assert result.success and result.success_steps == [True] * STEPS
    assert result.first_success_step == 0
    assert result.actions.shape == (STEPS, 4)
    np.testing.assert_array_equal(result.actions[0], 0.0)  # SPEC §4: the first step is zero
    assert np.abs(result.actions[1:]).max() > 0 and np.abs(result.actions).max() <= 1
    np.testing.assert_array_equal(result.actions[:, 3], 0.0)  # σ_gripper = 0 on tabletop
    assert result.frames.shape == (STEPS + 1, 64, 64, 3) and result.frames.dtype == np.uint8
    np.testing.assert_array_equal(result.goal_image, solved.goal_image)
    assert len(result.planning_times) == STEPS - 1 and len(result.scores) == STEPS - 1
    assert result.cost_kind == "pixel"
    assert result.agent["planner"]["num_samples"] == 8

    record = ControlTrial(unsolved, _agent(), seed=0, num_steps=STEPS).run().record()
    assert record["success"] is False and record["success_steps"] == [False] * STEPS
    assert record["first_success_step"] is None and record["num_steps"] == STEPS
    assert np.asarray(record["actions"]).shape == (STEPS, 4)
    assert set(record["timings"]) == {"planning_s", "planning_mean_s", "env_s", "total_s"}
    assert len(record["timings"]["planning_s"]) == STEPS - 1


def test_trial_is_a_function_of_its_seed(suite, tabletop_env):
    inst = suite.get("tabletop/push_sphere", 1)
    a = ControlTrial(inst, _agent(), seed=5, num_steps=STEPS, env=tabletop_env).run()
    b = ControlTrial(inst, _agent(), seed=5, num_steps=STEPS, env=tabletop_env).run()
    c = ControlTrial(inst, _agent(), seed=6, num_steps=STEPS, env=tabletop_env).run()
    np.testing.assert_array_equal(a.actions, b.actions)
    np.testing.assert_array_equal(a.frames, b.frames)
    assert not np.array_equal(a.actions, c.actions)
    assert trial_seed("tabletop/push_sphere", 1, 5) != trial_seed("tabletop/push_sphere", 0, 5)


def test_stop_on_success_ends_the_trial_early(suite, tabletop_env):
    inst = suite.get("tabletop/push_sphere", 0)
    result = ControlTrial(
        inst, _agent(), 0, num_steps=STEPS, stop_on_success=True, env=tabletop_env
    ).run()
    assert result.success and result.success_steps == [True] and len(result.actions) == 1


def test_robodesk_cost_kind_follows_the_classifier_registry(suite):
    inst = suite.get("robodesk/push_red", 0)
    # The shipped classifier of push_red is registered by default: the SPEC cost.
    result = ControlTrial(inst, _agent(5), seed=0, num_steps=2).run()
    assert result.cost_kind == "pixel+classifier" and result.record()["cost"] == "pixel+classifier"
    assert result.actions.shape == (2, 5)
    # Without a registered classifier: pixels only, and the record says so.
    bare = PlanningAgent(RepeatLastFrame(5), PlannerConfig(num_samples=8),
                         classifiers=ClassifierRegistry())
    result = ControlTrial(inst, bare, seed=0, num_steps=2).run()
    assert result.cost_kind == "pixel_only" and result.record()["cost"] == "pixel_only"


def test_random_actions_baseline(suite, tabletop_env):
    inst = suite.get("tabletop/push_sphere", 1)
    a = ControlTrial(inst, RandomActions(4), seed=1, num_steps=STEPS, env=tabletop_env).run()
    b = ControlTrial(inst, RandomActions(4), seed=1, num_steps=STEPS, env=tabletop_env).run()
    np.testing.assert_array_equal(a.actions, b.actions)
    np.testing.assert_array_equal(a.actions[0], 0.0)
    assert a.cost_kind == "none" and a.agent == {"agent": "random_actions"}
    rng = np.random.default_rng(trial_seed(inst.task, inst.index, 1))
    np.testing.assert_allclose(a.actions[1:], rng.uniform(-1, 1, (STEPS - 1, 4)))


def test_wrong_action_dim_is_a_clear_error(suite, tabletop_env):
    inst = suite.get("tabletop/push_sphere", 0)
    with pytest.raises(ValueError, match="4-D actions but the planning agent .* action_dim 5"):
        ControlTrial(inst, _agent(5), seed=0, num_steps=STEPS, env=tabletop_env).run()
