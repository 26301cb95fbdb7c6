"""The compiled RoboDesk step (IK + physics) equals the step through MuJoCo's Python bindings."""

from __future__ import annotations

import numpy as np
import pytest

from vp2.envs._robodesk_kernel import ik_solve
from vp2.envs.robodesk import RoboDeskEnv


@pytest.fixture(scope="module")
def envs():
    a = RoboDeskEnv("push_red", seed=0, observation_size=None)
    b = RoboDeskEnv("push_red", seed=0, observation_size=None)
    yield a, b


def test_the_compiled_step_is_bit_identical_to_python_calls(envs):
    compiled, reference = envs
    rng = np.random.default_rng(11)
    hand_travel = 0.0
    for episode in range(3):
        compiled.reset(seed=episode)
        reference.reset_to(compiled.get_state())
        start = compiled.end_effector_pos
        for t in range(8):
            # In the box, beyond it (clipped), and the wrist and gripper at their limits.
            action = rng.uniform(-1.5, 1.5, 5) if t % 2 else rng.uniform(-0.4, 0.4, 5)
            if t == 3:
                action[3:] = (-1.0, 1.0)
            action = compiled.check_action(action)
            compiled._simulate(action)
            reference._simulate_python(action, None)
            np.testing.assert_array_equal(compiled.get_state(), reference.get_state())
            assert compiled._ik.last_steps == reference._ik.last_steps
        hand_travel = max(hand_travel, float(np.linalg.norm(compiled.end_effector_pos - start)))
    # The steps did something: the hand travelled (each repeat moves its target up to 1 cm).
    assert hand_travel > 0.05


def test_the_dense_reward_path_steps_the_same(envs):
    compiled, reference = envs
    compiled.reset(seed=5)
    reference.reset_to(compiled.get_state())
    reference.track_dense_reward = True
    try:
        for action in np.random.default_rng(2).uniform(-1, 1, (4, 5)):
            compiled.step(action)
            _, _, _, _, info = reference.step(action)
            assert np.isfinite(info["dense_reward"])
            np.testing.assert_array_equal(compiled.get_state(), reference.get_state())
    finally:
        reference.track_dense_reward = False


@pytest.mark.parametrize("distance", [0.003, 0.05, 0.2, 0.6, 3.0])
def test_the_compiled_ik_equals_the_python_ik(envs, distance):
    """Far targets take the regularised branch (error above 0.1 m) and unreachable ones end on
    the progress test or the iteration limit: the same solution and iterations either way."""
    env, _ = envs
    env.reset(seed=9)
    ik = env._ik
    k = env._kernel
    rng = np.random.default_rng(int(distance * 1000))
    for _ in range(4):
        direction = rng.normal(size=3)
        target = env.end_effector_pos + distance * direction / np.linalg.norm(direction)
        expected = ik.solve(env.data, target).copy()
        expected_steps = ik.last_steps
        ik.data.qpos[:] = 0.0
        steps = ik_solve(*k[:8], target, *k[8:23])
        np.testing.assert_array_equal(ik.data.qpos, expected)
        assert steps == expected_steps
        assert steps >= 1
