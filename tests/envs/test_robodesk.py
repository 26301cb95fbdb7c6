"""RoboDesk environment: seeding, state round trips, determinism, success semantics, metadata,
and bit-identity with the ``robodesk`` package's dynamics and IK."""

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
from vp2.envs._ik import SitePositionIK, make_dm_control_ik_deterministic
from vp2.envs._robodesk_model import RENDER_SPEC, load_model
from vp2.envs.rendering import Renderer, mean_abs_error
from vp2.envs.robodesk import IK_JOINTS, OBJECTS, TASKS, RoboDeskEnv

_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION


@pytest.fixture(scope="module")
def env():
    with RoboDeskEnv("push_red", seed=0, observation_size=None) as e:
        yield e


@pytest.fixture
def deterministic_dm_control(monkeypatch):
    """dm_control's IK with its two CPU-dependent pieces replaced by vp2's: the least-squares
    step (numpy.linalg.solve/lstsq on OpenBLAS) and the vector norms (BLAS ddot). Everything
    else -- the package's control loop, its IK iteration, dm_control's physics -- is the
    package's own code, which vp2 must then match bit for bit."""
    inverse_kinematics = pytest.importorskip("dm_control.utils.inverse_kinematics")
    make_dm_control_ik_deterministic(monkeypatch.setattr)
    return inverse_kinematics


def _actions(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, size=(n, 5))


def _rollout(env: RoboDeskEnv, start: np.ndarray, actions: np.ndarray) -> np.ndarray:
    env.reset_to(start)
    states = []
    for a in actions:
        env.step(a)
        states.append(env.get_state())
    return np.array(states)


def _set_joint(env: RoboDeskEnv, joint: str, value: float) -> None:
    env.data.qpos[env.model.jnt_qposadr[env.model.joint(joint).id]] = value
    mujoco.mj_forward(env.model, env.data)


def test_unknown_task_and_bad_observation_size():
    with pytest.raises(ValueError, match="tasks are"):
        RoboDeskEnv("open_fridge")
    with pytest.raises(ValueError, match="observation_size"):
        RoboDeskEnv("push_red", observation_size=0)


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
        RoboDeskEnv("open_slide", seed=5, observation_size=None) as e1,
        RoboDeskEnv("open_slide", seed=5, observation_size=None) as e2,
    ):
        for _ in range(2):
            e1.reset()
            e2.reset()
            np.testing.assert_array_equal(e1.get_state(), e2.get_state())


def test_initial_state_distribution(env):
    """The package's distribution: drawer opened by U(0, 0.1), slide by U(0, 0.2), objects in
    their boxes, at rest, and the original object positions stored as copies."""
    for seed in range(5):
        env.reset(seed=seed)
        assert -0.1 <= env.joint_qpos("drawer_joint")[0] <= 0.0
        assert 0.0 <= env.joint_qpos("slide_joint")[0] <= 0.2
        assert 0.15 <= env.body_pos("flat_block")[0] <= 0.45
        assert 0.2 <= env.body_pos("upright_block")[0] <= 0.5
        assert -0.4 <= env.body_pos("ball")[0] <= 0.08
        np.testing.assert_array_equal(env.data.qvel, 0.0)
        original = env.original_object_positions
        for name in OBJECTS:
            np.testing.assert_array_equal(original[name], env.body_pos(name))
        assert not env.is_success()


def test_state_layout_and_reset_to_round_trip(env):
    env.reset(seed=3)
    for a in _actions(2):
        env.step(a)
    state = env.get_state()
    assert state.shape == (env.state_size,)
    assert env.state_size == mujoco.mj_stateSize(env.model, _INTEGRATION) + 3 * len(OBJECTS)
    env.reset(seed=4)
    env.reset_to(state)
    np.testing.assert_array_equal(env.get_state(), state)
    # The episode memory (original object positions) is part of the state.
    np.testing.assert_array_equal(
        np.concatenate([env.original_object_positions[n] for n in OBJECTS]), state[-9:]
    )
    with pytest.raises(ValueError, match="shape"):
        env.reset_to(state[:-1])
    bad = state.copy()
    bad[5] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        env.reset_to(bad)


def test_replay_is_bit_identical_in_the_same_process(env):
    env.reset(seed=7)
    start = env.get_state()
    actions = _actions(35, seed=1)
    np.testing.assert_array_equal(_rollout(env, start, actions), _rollout(env, start, actions))
    # A different env object of another task replays the same dynamics.
    with RoboDeskEnv("open_drawer", observation_size=None) as other:
        np.testing.assert_array_equal(
            _rollout(other, start, actions), _rollout(env, start, actions)
        )


def test_replay_is_bit_identical_in_a_fresh_process(env, tmp_path):
    env.reset(seed=8)
    start = env.get_state()
    actions = _actions(35, seed=2)
    expected = _rollout(env, start, actions)
    np.save(tmp_path / "start.npy", start)
    np.save(tmp_path / "actions.npy", actions)
    script = textwrap.dedent(
        f"""
        import numpy as np
        from vp2.envs.robodesk import RoboDeskEnv
        env = RoboDeskEnv("push_red", observation_size=None)
        env.reset_to(np.load({str(tmp_path / "start.npy")!r}))
        states = []
        for a in np.load({str(tmp_path / "actions.npy")!r}):
            env.step(a)
            states.append(env.get_state())
        np.save({str(tmp_path / "states.npy")!r}, np.array(states))
        """
    )
    subprocess.run([sys.executable, "-c", script], check=True, env=dict(os.environ), timeout=120)
    np.testing.assert_array_equal(np.load(tmp_path / "states.npy"), expected)


def test_images_replay_identically():
    with RoboDeskEnv("push_blue", seed=0, observation_size=32) as e:
        e.reset(seed=1)
        start = e.get_state()
        actions = _actions(3, seed=3)

        def images():
            frames = [e.reset_to(start)]
            frames += [e.step(a)[0] for a in actions]
            return np.array(frames)

        first = images()
        assert first.shape == (4, 32, 32, 3) and first.dtype == np.uint8
        np.testing.assert_array_equal(first, images())


def test_bad_actions_and_clipping(env):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(4))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((1, 5)))
    for bad_value, message in ((np.nan, "NaN"), (np.inf, "inf"), (-np.inf, "inf")):
        bad = np.zeros(5)
        bad[2] = bad_value
        with pytest.raises(ValueError, match=message):
            env.step(bad)
    # Out-of-range actions are clipped to [-1, 1]: the same as stepping with the clipped action.
    env.reset(seed=0)
    start = env.get_state()
    big = np.array([3.0, -7.0, 0.5, 2.0, -1.5])
    np.testing.assert_array_equal(
        _rollout(env, start, big[None]), _rollout(env, start, np.clip(big, -1, 1)[None])
    )


@pytest.mark.parametrize("task", [t for t in TASKS if t.startswith("push_")])
def test_button_success(task):
    color = task.removeprefix("push_")
    with RoboDeskEnv(task, seed=0, observation_size=None) as e:
        e.reset(seed=0)
        assert not e.is_success()
        _set_joint(e, f"{color}_light", -0.0046)
        assert e.is_success()
        _set_joint(e, f"{color}_light", -0.0045)
        assert not e.is_success()
        other = "red" if color != "red" else "green"
        _set_joint(e, f"{color}_light", 0.0)
        _set_joint(e, f"{other}_light", -0.005)
        assert not e.is_success(), "another button's light must not count"


def test_slide_and_drawer_success():
    with RoboDeskEnv("open_slide", seed=0, observation_size=None) as e:
        e.reset(seed=0)
        _set_joint(e, "slide_joint", 0.55)
        assert not e.is_success()
        _set_joint(e, "slide_joint", 0.56)
        assert e.is_success()
    with RoboDeskEnv("open_drawer", seed=0, observation_size=None) as e:
        e.reset(seed=0)
        _set_joint(e, "drawer_joint", -0.2)
        assert not e.is_success()
        _set_joint(e, "drawer_joint", -0.21)
        assert e.is_success()
        # The goal argument is ignored (the criterion needs none).
        assert e.is_success(np.zeros(e.state_size))


@pytest.mark.parametrize("obj", ["flat_block", "upright_block"])
def test_off_table_success_needs_the_other_objects_in_place(obj):
    with RoboDeskEnv(f"{obj}_off_table", seed=0, observation_size=None) as e:
        e.reset(seed=0)
        adr = e.model.jnt_qposadr[e.model.joint(obj).id]
        e.data.qpos[adr : adr + 3] = (0.4, 0.3, 0.3)  # on the floor in front of the desk
        mujoco.mj_forward(e.model, e.data)
        assert e.is_success()
        # Moving another object by 2 cm (the package's check that its bug disabled) fails it.
        other = next(o for o in OBJECTS if o != obj)
        oadr = e.model.jnt_qposadr[e.model.joint(other).id]
        e.data.qpos[oadr] += 0.02
        mujoco.mj_forward(e.model, e.data)
        assert not e.is_success()
        e.data.qpos[oadr] -= 0.015  # 5 mm: within the 1 cm tolerance
        mujoco.mj_forward(e.model, e.data)
        assert e.is_success()


def test_no_task_is_successful_at_reset():
    for task in TASKS:
        with RoboDeskEnv(task, seed=0, observation_size=None) as e:
            for seed in range(10):
                _, info = e.reset(seed=seed)
                assert info["success"] is False and not e.is_success(), (task, seed)


def test_serialize_round_trip():
    with RoboDeskEnv("flat_block_off_table", seed=9, observation_size=None) as e:
        meta = e.serialize()
        assert json.loads(json.dumps(meta)) == meta
        assert meta["name"] == "robodesk/flat_block_off_table"
        with make_env_from_metadata(meta) as rebuilt:
            assert isinstance(rebuilt, RoboDeskEnv) and rebuilt.task == e.task
            assert rebuilt.observation_size is None
            e.reset()
            rebuilt.reset()
            np.testing.assert_array_equal(rebuilt.get_state(), e.get_state())


def test_render_sizes_and_spec():
    with RoboDeskEnv("open_slide", seed=0, observation_size=None) as e:
        e.reset(seed=0)
        for h, w in ((64, 64), (32, 48), (128, 128)):
            img = e.render(h, w)
            assert img.shape == (h, w, 3) and img.dtype == np.uint8
        assert e.render(64).std() > 5
        # The benchmark camera with the chosen quality knobs stays close to full quality.
        full = Renderer(e.model, RENDER_SPEC.full_quality())
        try:
            assert mean_abs_error(e.render(64), full.render(e.data, 64)) < 12.0
        finally:
            full.close()


def test_ik_matches_dm_control_bit_for_bit(deterministic_dm_control):
    """The IK is dm_control's qpos_from_site_pose (position, joints 1-6), to the last bit
    (with its linear algebra made CPU-independent the same way)."""
    inverse_kinematics = deterministic_dm_control
    from dm_control import mujoco as dm_mujoco

    with RoboDeskEnv("push_red", seed=0, observation_size=None) as e:
        physics = dm_mujoco.Physics.from_xml_path(os.fspath(_desk_xml()))
        ik = SitePositionIK(load_model(), "end_effector", IK_JOINTS)
        rng = np.random.default_rng(0)
        for seed in range(5):
            e.reset(seed=seed)
            target = e.end_effector_pos + rng.uniform(-0.01, 0.01, size=3)
            physics.data.qpos[:] = e.data.qpos
            expected = inverse_kinematics.qpos_from_site_pose(
                physics, "end_effector", target, joint_names=IK_JOINTS, inplace=True
            ).qpos
            np.testing.assert_array_equal(ik.solve(e.data, target), expected)


def _desk_xml():
    from vp2.envs._robodesk_model import asset_path

    return asset_path()


def test_dynamics_match_the_robodesk_package_bit_for_bit(deterministic_dm_control):
    """A short version of benchmarks/fidelity/robodesk_equivalence.py: same state, same actions."""
    robodesk = pytest.importorskip("robodesk")
    package = robodesk.RoboDesk(task="push_red", action_repeat=50)
    package._get_obs = lambda: None  # its renderer is the bottleneck and not compared here
    with RoboDeskEnv("push_red", seed=0, observation_size=None) as e:
        e.reset(seed=5)
        n = mujoco.mj_stateSize(e.model, _INTEGRATION)
        package.physics.set_state(e.get_state()[:n], _INTEGRATION)
        package.physics.forward()
        package.physics_copy.data.qpos[:] = package.physics.data.qpos
        for a in _actions(4, seed=4):
            e.step(a)
            package.step(a)
            np.testing.assert_array_equal(
                e.get_state()[:n], package.physics.get_state(_INTEGRATION)
            )


@pytest.mark.parametrize("task", TASKS)
def test_dense_reward_matches_the_package_summed_over_the_repeats(
    task, deterministic_dm_control
):
    """The classifiers' paper label (SPEC §6) sums the package's dense reward over a step."""
    robodesk = pytest.importorskip("robodesk")
    package = robodesk.RoboDesk(task=task, reward="dense", action_repeat=50)
    package._get_obs = lambda: None
    with RoboDeskEnv(task, seed=0, observation_size=None) as e:
        e.reset(seed=3)
        e.track_dense_reward = True
        n = mujoco.mj_stateSize(e.model, _INTEGRATION)
        package.physics.set_state(e.get_state()[:n], _INTEGRATION)
        package.physics.forward()
        package.physics_copy.data.qpos[:] = package.physics.data.qpos
        # The package keeps views of live positions (its bug, SPEC §1.1); give it copies.
        package.original_pos = {k: v.copy() for k, v in e.original_object_positions.items()}
        for a in _actions(3, seed=7):
            _, _, _, _, info = e.step(a)
            _, reward, _, _ = package.step(a)
            assert info["dense_reward"] == pytest.approx(reward, abs=1e-9)
        assert 0 < info["dense_reward"] <= 50
        e.track_dense_reward = False
        assert "dense_reward" not in e.step(np.zeros(5))[4]
