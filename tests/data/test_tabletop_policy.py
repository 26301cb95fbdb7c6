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
        np.testing.assert_allclose(np.linalg.norm(goal[k, :2] - start[k, :2]), PUSH_DISTANCE)
        np.testing.assert_allclose(
            goal[k, :2] - start[k, :2],
            PUSH_DISTANCE * np.array([np.cos(policy.theta), np.sin(policy.theta)]),
        )
        assert x0 <= goal[k, 0] <= x1 and y0 <= goal[k, 1] <= y1
        others = [j for j in range(4) if j != k]
        np.testing.assert_array_equal(goal[others], start[others])
        goal_state = policy.goal_state()
        np.testing.assert_array_equal(TabletopEnv.object_positions_from_state(goal_state), goal)
        assert not env.is_success(goal_state)
    assert len(objects) > 1, "the random-object policy should pick different objects"


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
    assert dirty[3] == clean[3] == 1.0
    assert not np.array_equal(dirty[:3], clean[:3])
    np.testing.assert_array_equal(noisy.goal_state(), policy.goal_state())


#: Why the policy's success checks fail for now: its heights, gains and regions were tuned for
#: the earlier scene (5 cm objects, 5 Hz); the paper's scene gets the original's policy next.
POLICY_PREDATES_SCENE = "the scripted policy's numbers predate the paper's scene; retuned next"


# Seeds whose noise-free push succeeds (a regression check; the rate is measured by the slow
# test and by benchmarks/speed/bench_tabletop.py).
@pytest.mark.xfail(reason=POLICY_PREDATES_SCENE, strict=True)
@pytest.mark.parametrize("obj", range(len(OBJECT_NAMES)))
def test_noise_free_push_succeeds(env, obj):
    for seed in (0, 3):
        env.reset(seed=100_000 + seed)
        policy = make_tabletop_policy(env, np.random.default_rng(seed), target_object=obj)
        goal = policy.goal_state()
        reached = False
        for _ in range(35):
            env.step(policy.act())
            reached = reached or env.is_success(goal)
        assert reached, f"push_{OBJECT_NAMES[obj]} seed {seed} did not reach its goal"


@pytest.mark.slow
@pytest.mark.xfail(reason=POLICY_PREDATES_SCENE, strict=True)
@pytest.mark.parametrize("obj", range(len(OBJECT_NAMES)))
def test_noise_free_success_rate(obj):
    """SPEC §3 target: >= 80% of random initial states per category within 35 steps."""
    with TabletopEnv(f"push_{OBJECT_NAMES[obj]}", seed=0, observation_size=None) as e:
        wins = 0
        for episode in range(50):
            e.reset(seed=100_000 + episode)
            policy = make_tabletop_policy(e, np.random.default_rng(episode), target_object=obj)
            goal = policy.goal_state()
            reached = False
            for _ in range(35):
                e.step(policy.act())
                reached = reached or e.is_success(goal)
            wins += reached
    assert wins / 50 >= 0.8
