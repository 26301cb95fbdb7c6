"""The scripted tabletop pushing policy: its plan, its goal, determinism and success."""

from __future__ import annotations

import numpy as np
import pytest

from vp2.data.policies import TABLETOP_NOISE, make_task_policy
from vp2.data.policies.base import NoisyPolicy
from vp2.data.policies.tabletop import PUSH_DISTANCE, make_tabletop_policy
from vp2.envs.tabletop import DEFAULT_SCENE, OBJECT_NAMES, TabletopEnv


@pytest.fixture(scope="module")
def env():
    with TabletopEnv("push_large_cube", seed=0, observation_size=None) as e:
        yield e


def test_plan_and_goal(env):
    (x0, x1), (y0, y1) = DEFAULT_SCENE.placement.target_region
    objects = set()
    for seed in range(8):
        env.reset(seed=seed)
        start = env.object_positions()
        policy = make_tabletop_policy(env, np.random.default_rng(seed))
        k = policy.object_index
        objects.add(k)
        assert 0.0 <= policy.theta <= np.pi
        goal = policy.goal_positions()
        # 0.3 m along (sin theta, cos theta), each coordinate clamped to +-0.35 m (SPEC 3).
        aim = start[k, :2] + PUSH_DISTANCE * np.array([np.sin(policy.theta), np.cos(policy.theta)])
        np.testing.assert_allclose(goal[k, :2], np.clip(aim, [x0, y0], [x1, y1]))
        assert goal[k, 0] >= start[k, 0]  # never towards the robot
        others = [j for j in range(4) if j != k]
        np.testing.assert_array_equal(goal[others], start[others])
        goal_state = policy.goal_state()
        np.testing.assert_array_equal(TabletopEnv.object_positions_from_state(goal_state), goal)
    assert len(objects) > 1, "the random-object policy should pick different objects"


def test_script_steps(env):
    """The original's schedule: approach 5 (P - hand) at step 1, lower at step 2, push
    3 (target - object) from step 10 (here: at once, with the hand inside the square), no
    gripper action."""
    env.reset(seed=5)
    policy = make_tabletop_policy(env, np.random.default_rng(5), target_object=1)
    obj = env.object_positions()[1, :2]
    hand = env.end_effector_position()
    away = obj - policy.target_xy
    behind = obj + 0.22 * away / np.linalg.norm(away)
    first = policy.act()
    np.testing.assert_allclose(first[:2], np.clip(5 * (behind - hand[:2]), -1, 1))
    assert first[2] == first[3] == 0.0
    env.step(first)
    assert env.end_effector_position()[2] > 0.85
    np.testing.assert_array_equal(policy.act(), [0.0, 0.0, -0.75, 0.0])
    policy.step_count = 9  # the next action is step 10's
    obj = env.object_positions()[1, :2]
    np.testing.assert_allclose(policy.act()[:2], np.clip(3 * (policy.target_xy - obj), -1, 1))


def test_bound_zeroes_outward_components(env):
    env.reset(seed=0)
    policy = make_tabletop_policy(env, np.random.default_rng(0))
    inside = policy.bound(np.array([1.0, -1.0, 0.5, 0.0]))
    np.testing.assert_array_equal(inside, [1.0, -1.0, 0.5, 0.0])
    state = env.get_state()
    hand = env.end_effector_position()
    policy._x1 = hand[0]  # a bound the hand is at: outward x is zeroed, inward kept
    np.testing.assert_array_equal(policy.bound(np.array([0.3, 0.2, 0.0, 0.0])), [0.0, 0.2, 0, 0])
    np.testing.assert_array_equal(policy.bound(np.array([-0.3, 0.2, 0.0, 0.0])), [-0.3, 0.2, 0, 0])
    env.reset_to(state)


def test_target_object_by_name_and_task_policy(env):
    env.reset(seed=0)
    assert (
        make_tabletop_policy(env, np.random.default_rng(0), target_object="sphere").object_index
        == 3
    )
    assert make_task_policy(env, np.random.default_rng(0)).object_index == OBJECT_NAMES.index(
        "large_cube"
    )
    with pytest.raises(ValueError, match="unknown object"):
        make_tabletop_policy(env, np.random.default_rng(0), target_object="teapot")


def test_policy_is_deterministic_given_its_generator(env):
    def run():
        env.reset(seed=4)
        policy = make_tabletop_policy(env, np.random.default_rng(9))
        actions = []
        for _ in range(6):
            actions.append(policy.act())
            env.step(actions[-1])
        return np.array(actions)

    np.testing.assert_array_equal(run(), run())


def test_noise_spares_the_gripper(env):
    env.reset(seed=2)
    policy = make_tabletop_policy(env, np.random.default_rng(0))
    noisy = NoisyPolicy(policy, TABLETOP_NOISE, np.random.default_rng(1))
    clean, dirty = policy.act(), noisy.act()
    assert dirty[3] == clean[3] == 0.0
    assert not np.array_equal(dirty[:3], clean[:3])
    np.testing.assert_array_equal(noisy.goal_state(), policy.goal_state())


# The noise-free push moves its object by more than the original's 0.08 m keep threshold in at
# least one of three seeds (a regression check; a pushed object often sends the ball, which
# has no rolling resistance, off the table, which the keep filter then rejects). The original's goals are the
# states its pushes end in, not its aims, and its script does not steer a drifting object, so
# SPEC 3 asks for no rate of reaching the aim; the rates are in docs/data.md.
@pytest.mark.parametrize("obj", range(len(OBJECT_NAMES)))
def test_noise_free_push_moves_its_object(env, obj):
    kept = []
    for seed in range(3):
        env.reset(seed=100_000 + seed)
        policy = make_tabletop_policy(env, np.random.default_rng(seed), target_object=obj)
        start = env.object_positions()
        for _ in range(35):
            env.step(policy.act())
        end = env.object_positions()
        fell = np.abs(end[:, 2] - start[:, 2]).max() > 0.5
        moved = float(np.linalg.norm(end[obj, :2] - start[obj, :2]))
        kept.append((moved, bool(fell)))
    assert any(m > 0.08 for m, _ in kept), f"push_{OBJECT_NAMES[obj]}: (moved, fell) {kept}"
