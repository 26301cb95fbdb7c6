"""Frustum culling in the renderer: the tabletop camera's frames are the same bit for bit with
and without it, it leaves most of the Panda out, and it stands aside where another pass
(shadows, reflections) could draw what the camera does not see."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from vp2.envs.culling import FrustumCulling
from vp2.envs.tabletop import TabletopEnv


@pytest.fixture(scope="module")
def scene():
    env = TabletopEnv("push_sphere", seed=0, observation_size=None)
    rng = np.random.default_rng(3)
    states = []
    for k in range(24):
        if k % 8 == 0:
            env.reset(seed=k)
        # Full actions: the hand sweeps the table, rises and drops, so links cross the view's
        # edges.
        env.step(rng.uniform(-1, 1, 4))
        states.append(env.get_state())
    env.render(64)
    yield env, states
    env.close()


def _frames(env, states, cull: bool, size: int,
            width: int | None = None) -> tuple[np.ndarray, list[int]]:
    width = size if width is None else width
    env._renderer.cull = cull
    frames, culled = [], []
    try:
        for state in states:
            env.reset_to(state)
            mujoco.mj_kinematics(env._model, env._data)
            mujoco.mj_camlight(env._model, env._data)
            frames.append(env.render(size, width))
            culled.append(env._renderer._culling[(size, width)].culled)
    finally:
        env._renderer.cull = True
    return np.stack(frames), culled


@pytest.mark.parametrize(("size", "width"), [(64, 64), (96, 96), (48, 112), (112, 48)])
def test_culling_changes_no_pixel_and_leaves_most_of_the_arm_out(scene, size, width):
    env, states = scene
    drawn_all, none_culled = _frames(env, states, cull=False, size=size, width=width)
    culled_frames, culled = _frames(env, states, cull=True, size=size, width=width)
    assert none_culled == [0] * len(states)
    assert np.array_equal(drawn_all, culled_frames)
    # The Panda's links above the view (about 40 visual geoms) and its collision geoms.
    assert min(culled) >= 20


def test_a_geom_is_culled_exactly_when_its_sphere_leaves_the_view(scene):
    env, _ = scene
    model = env._renderer._contexts[(64, 64)].model
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    culling = FrustumCulling(model, "agentview_shift_2", aspect=1.0, margin=0.0)
    cam = culling.camera
    forward = -data.cam_xmat[cam].reshape(3, 3)[:, 2]
    right = data.cam_xmat[cam].reshape(3, 3)[:, 0]
    sphere = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "sphere_g0_vis")
    radius = model.geom_rbound[sphere]
    tan = np.tan(np.deg2rad(model.cam_fovy[cam]) / 2)
    depth = 1.0
    # Centre at the right plane's distance: its sphere just touches the plane from outside.
    for offset, expected in ((0.0, False), (-1e-3, False), (1e-3, True)):
        lateral = depth * tan + (radius + offset) * np.sqrt(1 + tan**2)
        data.geom_xpos[sphere] = data.cam_xpos[cam] + depth * forward + lateral * right
        assert culling.outside(data)[sphere] == expected, offset
    # A wide image (aspect 2): twice the tangent sideways, the same one up and down.
    wide = FrustumCulling(model, "agentview_shift_2", aspect=2.0, margin=0.0)
    up = data.cam_xmat[cam].reshape(3, 3)[:, 1]
    for direction, t in ((right, 2 * tan), (up, tan)):
        for offset, expected in ((-1e-3, False), (1e-3, True)):
            lateral = depth * t + (radius + offset) * np.sqrt(1 + t**2)
            data.geom_xpos[sphere] = data.cam_xpos[cam] + depth * forward + lateral * direction
            assert wide.outside(data)[sphere] == expected, (t, offset)
    data.geom_xpos[sphere] = data.cam_xpos[cam] - (radius + 1e-3) * forward  # behind the camera
    assert culling.outside(data)[sphere]
    floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    data.geom_xpos[floor] = data.cam_xpos[cam] - 100 * forward
    assert not culling.outside(data)[floor]  # planes are never culled


def test_culling_stands_aside_for_shadows_and_reflections(scene):
    env, states = scene
    model = env._renderer._contexts[(64, 64)].model
    culling = env._renderer._culling[(64, 64)]
    assert FrustumCulling.applies(model)
    castshadow, reflectance = model.light_castshadow.copy(), model.mat_reflectance.copy()
    try:
        model.light_castshadow[0] = 1
        assert not FrustumCulling.applies(model)
        _, culled = _frames(env, states[:2], cull=True, size=64)
        assert culled == [0, 0] and np.array_equal(model.geom_group, culling._groups)
        model.light_castshadow[:] = castshadow
        model.mat_reflectance[0] = 0.2
        assert not FrustumCulling.applies(model)
    finally:
        model.light_castshadow[:] = castshadow
        model.mat_reflectance[:] = reflectance
    _, culled = _frames(env, states[:2], cull=True, size=64)
    assert min(culled) >= 30


def test_an_unknown_camera_or_one_with_intrinsics_is_refused():
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><camera name="lens" sensorsize="0.01 0.01" focal="0.01 0.01"'
        ' resolution="64 64"/></worldbody></mujoco>')
    with pytest.raises(ValueError, match="camera 'nope' is not in the model"):
        FrustumCulling(model, "nope", aspect=1.0)
    with pytest.raises(ValueError, match="camera 'lens' has a sensor size"):
        FrustumCulling(model, "lens", aspect=1.0)
    # What the renderer asks: no culling for these cameras, nor for a free camera.
    assert FrustumCulling.for_camera(model, "lens", 1.0) is None
    assert FrustumCulling.for_camera(model, "nope", 1.0) is None
    assert FrustumCulling.for_camera(model, mujoco.MjvCamera(), 1.0) is None
