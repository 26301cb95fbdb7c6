"""Every task is a Gymnasium env: registered ids, spaces, and gymnasium's own env checker."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import vp2
from vp2.envs import GYM_IDS, TASK_NAMES
from vp2.envs.registration import gym_id, make_gym_env

#: One task per environment gets the full check (render modes and close rebuild the env).
FULL_CHECK = {"robodesk/push_red", "tabletop/push_sphere"}


def test_ids_cover_the_eleven_tasks():
    assert list(GYM_IDS) == list(TASK_NAMES)
    assert gym_id("robodesk/push_red") == "vp2/RoboDesk-PushRed-v0"
    assert gym_id("tabletop/push_large_cube") == "vp2/Tabletop-PushLargeCube-v0"
    assert len(set(GYM_IDS.values())) == 11
    assert all(env_id in gymnasium.registry for env_id in GYM_IDS.values())


@pytest.mark.parametrize("task", TASK_NAMES)
def test_gymnasium_make_passes_check_env(task):
    env = gymnasium.make(GYM_IDS[task], seed=0)
    try:
        raw = env.unwrapped
        assert isinstance(raw, vp2.envs.Env) and raw.name == task
        assert raw.action_space == gymnasium.spaces.Box(-1, 1, (raw.action_dim,), np.float32)
        assert raw.observation_space == gymnasium.spaces.Box(0, 255, (64, 64, 3), np.uint8)
        fast = task not in FULL_CHECK
        check_env(raw, skip_render_check=fast, skip_close_check=fast)
    finally:
        env.close()


def test_render_mode_sizes_and_the_vp2_api_on_a_gymnasium_env():
    env = gymnasium.make("vp2/Tabletop-PushSphere-v0", render_mode="rgb_array", observation_size=32)
    try:
        obs, _ = env.reset(seed=1)
        assert obs.shape == (32, 32, 3) and obs in env.observation_space
        assert env.render().shape == (64, 64, 3)
        raw = env.unwrapped
        state = raw.get_state()
        env.step(env.action_space.sample())
        np.testing.assert_array_equal(raw.reset_to(state), obs)
        assert raw.render(48, 24).shape == (48, 24, 3)
    finally:
        env.close()
    with pytest.raises(ValueError, match="render_mode"):
        make_gym_env("tabletop/push_sphere", render_mode="ansi")
    with pytest.raises(ValueError, match="observation_size=None"):
        gymnasium.make("vp2/Tabletop-PushSphere-v0", observation_size=None)
    with vp2.make_env("tabletop/push_sphere", observation_size=None) as states_only:
        assert states_only.observation_space is None
        assert states_only.action_space.shape == (4,)
