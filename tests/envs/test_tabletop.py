"""Tabletop environment: seeding, state round trips, determinism, textures, success, metadata,
camera framing."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import mujoco
import numpy as np
import pytest

from vp2.envs import make_env_from_metadata
from vp2.envs._tabletop_stepper import LeanStepper
from vp2.envs._tabletop_world import TabletopWorld
from vp2.envs.tabletop import DEFAULT_SCENE, OBJECT_NAMES, SUCCESS_THRESHOLD, TabletopEnv

PLACEMENT_REGION = DEFAULT_SCENE.placement.region
TARGET_REGION = DEFAULT_SCENE.placement.target_region
TEXTURE_NAMES = DEFAULT_SCENE.textures.names

_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION


@pytest.fixture(scope="module")
def env():
    with TabletopEnv("push_cylinder", seed=0, observation_size=32) as e:
        yield e


def _actions(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, size=(n, 4))


def _rollout(env: TabletopEnv, start: np.ndarray, actions: np.ndarray) -> np.ndarray:
    env.reset_to(start)
    states = []
    for a in actions:
        env.step(a)
        states.append(env.get_state())
    return np.array(states)


def test_reset_seeding(env):
    env.reset(seed=11)
    a = env.get_state()
    env.reset(seed=12)
    b = env.get_state()
    env.reset(seed=11)
    np.testing.assert_array_equal(env.get_state(), a)
    assert not np.array_equal(a, b)
    # Without a seed, reset continues the generator seeded at construction.
    with (
        TabletopEnv("push_sphere", seed=5, observation_size=None) as e1,
        TabletopEnv("push_sphere", seed=5, observation_size=None) as e2,
    ):
        for _ in range(2):
            e1.reset()
            e2.reset()
            np.testing.assert_array_equal(e1.get_state(), e2.get_state())


def test_initial_states_are_valid(env):
    (x0, x1), (y0, y1) = PLACEMENT_REGION
    radii = np.array([DEFAULT_SCENE.footprints[n] for n in OBJECT_NAMES])
    rest = np.array([DEFAULT_SCENE.rest_heights[n] for n in OBJECT_NAMES])
    for seed in range(5):
        env.reset(seed=seed)
        pos = env.object_positions()
        assert np.all((pos[:, 0] >= x0) & (pos[:, 0] <= x1) & (pos[:, 1] >= y0) & (pos[:, 1] <= y1))
        gaps = np.linalg.norm(pos[:, None, :2] - pos[None, :, :2], axis=-1)
        off = ~np.eye(4, dtype=bool)
        assert np.all(gaps[off] > (radii[:, None] + radii[None])[off]), "objects overlap at reset"
        # Dropped from 1 cm above the table (the original's placement).
        np.testing.assert_array_equal(pos[:, 2], 0.8 + 0.01 + rest)
        # A zero action lets them fall onto the table, where they stay.
        env.step(np.zeros(4))
        after = env.object_positions()
        np.testing.assert_allclose(after[:, :2], pos[:, :2], atol=1e-3)
        np.testing.assert_allclose(after[:, 2], 0.8 + rest, atol=1e-3)


def test_textures_drawn_and_restored(env):
    seen = set()
    for seed in range(6):
        env.reset(seed=seed)
        names = env.texture_names()
        assert list(names) == list(OBJECT_NAMES)
        # Four draws with replacement, like the original's (two objects may share one).
        assert set(names.values()) <= set(TEXTURE_NAMES)
        seen.update(names.values())
    assert len(seen) > 6, "textures should vary across resets"

    env.reset(seed=1)
    state, image, names = env.get_state(), env.render(32), env.texture_names()
    env.reset(seed=2)
    assert env.texture_names() != names
    obs = env.reset_to(state)
    assert env.texture_names() == names
    np.testing.assert_array_equal(obs, image)
    assert env.serialize()["textures"] == names


def test_reset_to_round_trip_and_render_from_state(env):
    env.reset(seed=3)
    for a in _actions(3):
        obs, *_ = env.step(a)
    state = env.get_state()
    env.reset(seed=4)
    np.testing.assert_array_equal(env.reset_to(state), obs)  # an image is a function of the state
    np.testing.assert_array_equal(env.get_state(), state)
    np.testing.assert_array_equal(
        TabletopEnv.object_positions_from_state(state), env.object_positions()
    )
    with pytest.raises(ValueError, match="shape"):
        env.reset_to(state[:-1])


def test_determinism_same_process(env):
    env.reset(seed=21)
    start = env.get_state()
    actions = _actions(35, seed=1)
    np.testing.assert_array_equal(_rollout(env, start, actions), _rollout(env, start, actions))


def test_determinism_fresh_process(env, tmp_path):
    env.reset(seed=22)
    start = env.get_state()
    actions = _actions(35, seed=2)
    expected = _rollout(env, start, actions)
    np.save(tmp_path / "start.npy", start)
    np.save(tmp_path / "actions.npy", actions)
    script = textwrap.dedent(
        f"""
        import numpy as np
        from vp2.envs.tabletop import TabletopEnv
        env = TabletopEnv("push_cylinder", seed=123, observation_size=None)
        env.reset_to(np.load({str(tmp_path / "start.npy")!r}))
        out = []
        for a in np.load({str(tmp_path / "actions.npy")!r}):
            env.step(a)
            out.append(env.get_state())
        np.save({str(tmp_path / "fresh.npy")!r}, np.array(out))
        """
    )
    subprocess.run(
        [sys.executable, "-c", script], check=True, env=dict(os.environ), capture_output=True
    )
    np.testing.assert_array_equal(np.load(tmp_path / "fresh.npy"), expected)


def test_lean_step_matches_robosuite_step(env):
    """The fast step is robosuite's env.step from the same state, up to rounding: robosuite's
    own result differs by as much between OpenBLAS kernels (docs: 4e-16 after one step)."""
    env.reset(seed=31)
    world = TabletopWorld()
    stepper = LeanStepper(world)
    state = env.get_state()
    n = env._n_integration
    mujoco.mj_setState(world.sim.model._model, world.sim.data._data, state[:n], _INTEGRATION)
    stepper.set_controller_state(state[n + len(OBJECT_NAMES) :])
    # Gripper flips sign to exercise the gripper controller's accumulated command.
    actions = np.array([[0.8, -0.5, -1.0, 1.0], [0.3, 0.9, 0.2, -1.0], [-1.0, 0.1, 0.5, 1.0]])
    for a in actions:
        env.step(a)
        world.step(a.copy())
        ref = np.empty(n)
        mujoco.mj_getState(world.sim.model._model, world.sim.data._data, ref, _INTEGRATION)
        ours = env.get_state()
        # Positions within 1e-12 (relative to 1); velocities and solver state within 1e-9.
        qpos = slice(1, 1 + env._model.nq)
        np.testing.assert_allclose(ours[qpos], ref[qpos], rtol=0, atol=1e-12)
        np.testing.assert_allclose(ours[:n], ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(env.get_state()[n + 4 :], stepper.controller_state())


def test_bad_actions_and_clipping(env):
    env.reset(seed=5)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([0.0, np.nan, 0.0, 0.0]))
    start = env.get_state()
    big = np.array([3.0, -2.0, 1.5, -7.0])
    clipped = np.clip(big, -1, 1)
    np.testing.assert_array_equal(
        _rollout(env, start, big[None]), _rollout(env, start, clipped[None])
    )


def test_is_success_on_hand_made_goals(env):
    env.reset(seed=6)
    state = env.get_state()
    pos = env.object_positions()
    assert env.is_success(state)
    assert not env.is_success(None)
    near, far = pos.copy(), pos.copy()
    near[2, 0] += SUCCESS_THRESHOLD * 0.9
    far[2, 0] += SUCCESS_THRESHOLD * 1.1
    assert env.is_success(TabletopEnv.with_object_positions(state, near))
    assert not env.is_success(TabletopEnv.with_object_positions(state, far))
    # Every object counts, not only the task's own.
    other = pos.copy()
    other[0, 1] -= SUCCESS_THRESHOLD * 1.1
    assert not env.is_success(TabletopEnv.with_object_positions(state, other))

    env.set_goal(TabletopEnv.with_object_positions(state, far))
    *_, info = env.step(np.zeros(4))
    assert info["success"] is False
    assert not env.is_success()  # the goal set above is the far one
    env.set_goal(state)
    _, reward, *_, info = env.step(np.zeros(4))
    assert info["success"] is True and reward == 1.0
    assert env.is_success()  # without an argument: the goal of set_goal
    env.set_goal(None)
    assert not env.is_success()


def test_serialize_round_trip(env):
    env.reset(seed=8)
    meta = env.serialize()
    json.dumps(meta)
    assert meta["name"] == "tabletop/push_cylinder"
    assert meta["texture_set"] == list(TEXTURE_NAMES)
    with make_env_from_metadata(meta) as rebuilt:
        assert isinstance(rebuilt, TabletopEnv) and rebuilt.name == env.name
        assert rebuilt.observation_size == env.observation_size
        rebuilt.reset(seed=8)
        np.testing.assert_array_equal(rebuilt.get_state(), env.get_state())
        assert rebuilt.texture_names() == env.texture_names()


def test_unknown_task_is_rejected():
    with pytest.raises(ValueError, match="unknown tabletop task"):
        TabletopEnv("push_teapot")


def _project(env: TabletopEnv, points: np.ndarray, size: int = 64) -> np.ndarray:
    """Pixel coordinates (u right, v down) of world points in the benchmark camera."""
    m, d = env._model, env._data
    mujoco.mj_kinematics(m, d)
    cam = m.camera(env.scene.render.camera).id
    pos, rot = d.cam_xpos[cam], d.cam_xmat[cam].reshape(3, 3)
    local = (np.asarray(points) - pos) @ rot  # camera frame: x right, y up, looking along -z
    f = size / 2 / np.tan(np.radians(m.cam_fovy[cam]) / 2)
    return np.stack(
        [size / 2 + f * local[:, 0] / -local[:, 2], size / 2 - f * local[:, 1] / -local[:, 2]], 1
    )


def test_camera_is_the_originals_and_sees_every_placement(env):
    m = env._model
    cam = m.camera("agentview_shift_2").id
    assert m.cam_fovy[cam] == 45.0
    np.testing.assert_allclose(m.cam_pos[cam], (0.67589, 0.0, 1.25127), atol=5e-6)
    np.testing.assert_allclose(m.cam_quat[cam], (0.6326, 0.31594, 0.31594, 0.6326), atol=5e-6)
    # Objects anywhere in the placement region are in the 64x64 image, and large: a 12 cm cube
    # is at least 10 pixels wide at the far edge of the region.
    (px0, px1), (py0, py1) = PLACEMENT_REGION
    for x in (px0, px1):
        for y in (py0, py1):
            ends = _project(env, np.array([[x, y - 0.06, 0.86], [x, y + 0.06, 0.86]]))
            assert np.all((ends >= 0) & (ends <= 64)), ends
            assert np.linalg.norm(ends[1] - ends[0]) >= 10


def test_a_full_action_moves_the_hand_5_cm_and_it_rests(env):
    """1 Hz: the hand reaches its goal within the step and stays there under a zero action."""
    env.reset(seed=0)
    start = env.end_effector_position()
    env.step(np.array([0.0, 1.0, 0.0, 0.0]))
    moved = env.end_effector_position()
    assert 0.049 < np.linalg.norm(moved - start) < 0.052
    env.step(np.zeros(4))
    assert np.linalg.norm(env.end_effector_position() - moved) < 0.001
    # The hand is held straight down (robosuite 1.3's fixed orientation goal).
    rot = env._data.site_xmat[env._stepper._ref_site].reshape(3, 3)
    np.testing.assert_allclose(rot, [[0, 1, 0], [1, 0, 0], [0, 0, -1]], atol=0.01)


def test_regions_lie_on_the_table(env):
    (x0, x1), (y0, y1) = env.table_bounds
    for (rx0, rx1), (ry0, ry1) in (PLACEMENT_REGION, TARGET_REGION):
        assert x0 + 0.05 <= rx0 < rx1 <= x1 - 0.05
        assert y0 + 0.05 <= ry0 < ry1 <= y1 - 0.05


def test_import_does_not_log_the_mink_warning():
    out = subprocess.run(
        [sys.executable, "-c", "import vp2.envs._tabletop_world, vp2.envs._tabletop_stepper"],
        env=dict(os.environ),
        capture_output=True,
        text=True,
        check=True,
    )
    assert "mink" not in out.stdout + out.stderr


def test_the_solver_arena_is_small_and_big_enough(env):
    # robosuite's <size nconmax="5000" njmax="5000"/> reserves a 1.26 GB arena per MjData; a
    # process holding a few environments then cannot fork (benchmarks/checks/env_memory.py).
    assert env._model.narena == 16 * 2**20
    assert env._world.compiled_xml.count("njmax") == 0
    env.reset()
    for action in _actions(40, seed=3):
        env.step(action)
    # The most a trajectory used, with room to spare (pushes add a handful of contacts).
    assert 0 < env._data.maxuse_arena < env._model.narena / 20
    assert env._data.maxuse_con < 100


def test_set_arena_size_replaces_the_solver_limits():
    from vp2.envs._tabletop_world import _set_arena_size

    xml = '<mujoco><size nconmax="5000" njmax="5000" nkey="1"/><worldbody/></mujoco>'
    out = _set_arena_size(xml, "8M")
    model = mujoco.MjModel.from_xml_string(out)
    assert model.narena == 8 * 2**20
    assert 'nkey="1"' in out and "njmax" not in out
    assert mujoco.MjModel.from_xml_string(_set_arena_size("<mujoco/>", "4M")).narena == 4 * 2**20
