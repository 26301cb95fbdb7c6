"""One contract test over every registered task (dm_control suite_test style)."""

import numpy as np
import pytest

import vp2
from vp2.data.policies import make_task_policy
from vp2.envs import TASK_NAMES, make_env_from_metadata


@pytest.fixture(scope="module", params=TASK_NAMES)
def env(request):
    with vp2.make_env(request.param, seed=0, observation_size=64) as e:
        yield e


def test_registry_has_the_eleven_tasks():
    assert len(TASK_NAMES) == 11
    assert sum(t.startswith("robodesk/") for t in TASK_NAMES) == 7
    with pytest.raises(ValueError, match="registered tasks are"):
        vp2.make_env("robodesk/push_purple")


def test_reset_observation_and_state(env):
    obs, info = env.reset(seed=3)
    assert obs.shape == (64, 64, 3) and obs.dtype == np.uint8
    assert obs.std() > 5, "the observation should show a scene, not a flat colour"
    state = env.get_state()
    assert state.dtype == np.float64 and state.ndim == 1 and np.all(np.isfinite(state))
    assert isinstance(info, dict)
    obs2, _ = env.reset(seed=3)
    np.testing.assert_array_equal(env.get_state(), state)
    np.testing.assert_array_equal(obs2, obs)
    env.reset(seed=4)
    assert not np.array_equal(env.get_state(), state), "different seeds, same initial state"


def test_step_types_and_render_sizes(env):
    env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(np.zeros(env.action_dim))
    assert obs.shape == (64, 64, 3) and obs.dtype == np.uint8
    assert isinstance(reward, float) and reward in (0.0, 1.0)
    assert terminated is False and truncated is False
    assert isinstance(info["success"], bool)
    img = env.render(32, 48)
    assert img.shape == (32, 48, 3) and img.dtype == np.uint8


def test_not_successful_at_reset(env):
    for seed in range(3):
        env.reset(seed=seed)
        policy = make_task_policy(env, np.random.default_rng(seed))
        policy.reset()
        assert not env.is_success(policy.goal_state()), f"{env.name} succeeds at reset (seed {seed})"


def test_determinism_and_metadata_round_trip(env):
    env.reset(seed=1)
    start = env.get_state()
    actions = np.random.default_rng(0).uniform(-1, 1, size=(5, env.action_dim))

    def run(e):
        e.reset_to(start)
        states, images = [], []
        for a in actions:
            obs, *_ = e.step(a)
            states.append(e.get_state())
            images.append(obs)
        return np.array(states), np.array(images)

    s1, i1 = run(env)
    s2, i2 = run(env)
    np.testing.assert_array_equal(s1, s2)
    np.testing.assert_array_equal(i1, i2)
    with make_env_from_metadata(env.serialize(), observation_size=64) as rebuilt:
        s3, i3 = run(rebuilt)
    np.testing.assert_array_equal(s1, s3)
    np.testing.assert_array_equal(i1, i3)


def test_bad_actions_raise_clear_errors(env):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(env.action_dim + 1))
    bad = np.zeros(env.action_dim)
    bad[0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        env.step(bad)
    bad[0] = np.inf
    with pytest.raises(ValueError, match="inf"):
        env.step(bad)
