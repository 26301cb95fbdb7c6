"""The compiled physics loop of a tabletop control step equals stepping through the bindings."""

from __future__ import annotations

import threading

import mujoco
import numpy as np
import pytest

from vp2.envs._osc_kernel import osc_torques
from vp2.envs.tabletop import TabletopEnv


@pytest.fixture(scope="module")
def envs():
    with (
        TabletopEnv("push_sphere", seed=0, observation_size=None) as a,
        TabletopEnv("push_sphere", seed=0, observation_size=None) as b,
    ):
        yield a, b


def _step_through_bindings(env: TabletopEnv, action: np.ndarray) -> None:
    """One control step made of Python calls per physics step (the loop the kernel replaced)."""
    st, m, d = env._stepper, env._model, env._data
    goal_pos, goal_ori, grip = st.begin_step(env.check_action(action))
    for i in range(st.n_substeps):
        if i:
            mujoco.mj_step1(m, d)
        mujoco.mj_jacSite(m, d, st._jacp_c, st._jacr_c, st._center_site)
        mujoco.mj_jacSite(m, d, st._jacp, st._jacr, st._ref_site)
        mujoco.mj_fullM(m, st._full_mass, d.qM)
        osc_torques(
            d.qpos, d.qvel, d.qfrc_bias, st._full_mass, st._jacp_c, st._jacr_c, st._jacp,
            st._jacr, st._qpos_index, st._qvel_index, d.site_xpos[st._center_site],
            d.site_xmat[st._center_site].reshape(3, 3), d.site_xpos[st._ref_site],
            d.site_xmat[st._ref_site].reshape(3, 3), goal_pos, goal_ori, st._kp_pos,
            st._kd_pos, st._kp_ori, st._kd_ori, st._nullspace_kp,
            np.asarray(st.osc.initial_joint, np.float64), st._torques,
        )  # fmt: skip
        d.ctrl[st._arm_actuators] = np.minimum(np.maximum(st._torques, st._arm_low), st._arm_high)
        d.ctrl[st._grip_actuators] = grip
        mujoco.mj_step2(m, d)
    st.end_step()


def test_the_compiled_loop_is_bit_identical_to_python_calls(envs):
    compiled, reference = envs
    compiled.reset(seed=7)
    reference.reset_to(compiled.get_state())
    hand = compiled.end_effector_position().copy()
    actions = np.random.default_rng(3).uniform(-1, 1, (8, 4))
    actions[2:4, 3] = 1.0  # close the gripper: its accumulated command is state too
    for action in actions:
        compiled.step(action)
        _step_through_bindings(reference, action)
        np.testing.assert_array_equal(compiled.get_state(), reference.get_state())
    # The steps did something: the hand travelled (eight moves of up to 5 cm).
    assert np.linalg.norm(compiled.end_effector_position() - hand) > 0.02


def test_threads_step_separate_envs_with_the_gil_released(envs):
    """Two envs stepped in two threads end where they end stepped one after the other."""
    a, b = envs
    a.reset(seed=11)
    start = a.get_state()
    actions = np.random.default_rng(5).uniform(-1, 1, (4, 4))

    def roll(env: TabletopEnv, out: list) -> None:
        env.reset_to(start)
        for action in actions:
            env.step(action)
        out.append(env.get_state())

    sequential: list = []
    roll(a, sequential)
    threaded: list = [], []
    threads = [
        threading.Thread(target=roll, args=(e, o)) for e, o in zip(envs, threaded, strict=True)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    np.testing.assert_array_equal(threaded[0][0], sequential[0])
    np.testing.assert_array_equal(threaded[1][0], sequential[0])
