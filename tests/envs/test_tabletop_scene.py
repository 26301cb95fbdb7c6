"""The tabletop scene value: the default is the benchmark's scene, variants are consistent, and
environments built from different scenes in one process stay apart."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math

import numpy as np
import pytest

from vp2.data.policies.tabletop import make_tabletop_policy
from vp2.data.suite import TaskSuite
from vp2.envs import make_env_from_metadata
from vp2.envs.render_specs import render_fingerprint
from vp2.envs.tabletop import TabletopEnv
from vp2.envs.tabletop_scene import DEFAULT_SCENE, OBJECT_NAMES, TabletopScene, resolve_scene


def scaled(scene: TabletopScene, factor: float) -> TabletopScene:
    objects = tuple(
        dataclasses.replace(o, size=tuple(factor * s for s in o.size)) for o in scene.objects
    )
    return dataclasses.replace(scene, objects=objects)


BIG = scaled(DEFAULT_SCENE, 1.25)


def test_the_default_scene_is_the_benchmarks_scene():
    """SPEC §1.2's scene (the original release's), number for number."""
    s = DEFAULT_SCENE
    assert OBJECT_NAMES == ("large_cube", "small_cube", "cylinder", "sphere")
    assert [(o.name, o.shape, o.size) for o in s.objects] == [
        ("large_cube", "box", (0.06, 0.06, 0.06)),
        ("small_cube", "box", (0.04, 0.04, 0.04)),
        ("cylinder", "cylinder", (0.06, 0.06)),
        ("sphere", "ball", (0.07,)),
    ]
    assert s.rest_heights == {
        "large_cube": 0.06, "small_cube": 0.04, "cylinder": 0.06, "sphere": 0.07,
    }  # fmt: skip
    assert s.footprints == pytest.approx(
        {
            "large_cube": 0.06 * float(np.sqrt(2.0)),
            "small_cube": 0.04 * float(np.sqrt(2.0)),
            "cylinder": 0.06,
            "sphere": 0.07,
        },
        rel=1e-15,
    )
    assert [o.friction for o in s.objects] == [(0.7, 0.005, 0.0001)] * 3 + [(0.5, 0.005, 0.0001)]
    assert [o.condim for o in s.objects] == [None] * 4  # MuJoCo's 3: no rolling resistance
    assert [o.priority for o in s.objects] == [1] * 4
    assert {o.density for o in s.objects} == {1000}
    assert {o.rgba for o in s.objects} == {(0.5, 0.5, 0.5, 1.0)}
    assert s.table.full_size == (0.8, 0.8, 0.05) and s.table.center_x == 0.0
    assert s.table.top_z == 0.8 and s.table.friction == (1.0, 0.005, 0.0001)
    assert s.table.bounds == ((-0.4, 0.4), (-0.4, 0.4))
    assert s.robot.base_pos == (-0.56, 0.0, 0.0)
    np.testing.assert_array_equal(
        s.robot.init_qpos,
        np.array([0.0, np.pi / 16.0, 0.0, -np.pi / 2.0 - np.pi / 3.0, 0.0, np.pi - 0.2, np.pi / 4]),
    )
    assert s.robot.init_noise == 0.02 and s.robot.gripper_qpos == (0.020833, -0.020833)
    p = s.placement
    assert p.region == ((-0.1, 0.3), (-0.15, 0.15)) and p.drop_height == 0.01
    assert p.yaw_range == (0.0, 2.0 * np.pi) and p.max_draws == 5000
    assert p.target_region == ((-0.35, 0.35), (-0.35, 0.35))
    assert p.initial_layout == ((0.0, -0.1), (0.0, 0.1), (0.2, -0.1), (0.2, 0.1))
    c = s.controller
    assert (c.control_freq, c.output_max, c.input_max, c.kp, c.damping_ratio, c.nullspace_kp) == (
        1,
        0.05,
        1,
        150,
        1,
        10.0,
    )
    assert c.hand_orientation == ((0, 1, 0), (1, 0, 0), (0, 0, -1))
    assert s.camera.name == "agentview_shift_2" and s.camera.fovy == 45.0
    assert s.camera.pos == (0.6758858572576728, -4.76e-08, 1.251269639768581)
    assert s.camera.quat == (
        0.6325998902320862, 0.31593844294548035, 0.31593817472457886, 0.6326003670692444
    )  # fmt: skip
    assert s.textures.names == (
        "Can", "BricksWhite", "WoodRed", "WoodGreen", "WoodBlue", "PlasterYellow", "Brass",
        "PlasterPink", "Dirt", "Bread", "FeltGray", "Clay", "Lemon",
    )  # fmt: skip
    assert (s.textures.specular, s.textures.shininess) == (0.5, 0.5)
    a = s.arena
    assert (a.floor_texture, a.wall_texture) == ("WoodTiles", "PlasterCream")
    assert a.lights == (((1, 1, 4), (0, -0.15, -1)), ((-3, -3, 4), (0, -0.15, -1)))
    assert (a.light_diffuse, a.light_specular) == (0.8, 0.3)
    r = s.render
    assert (r.camera, r.shadow_size, r.shadow_lights, r.skybox, r.mesh_reduction) == (
        "agentview_shift_2",
        256,
        (),
        False,
        0.7,
    )
    assert (r.multisamples, r.reflection, r.plane_spacing) == (0, False, 0.5)
    assert (r.numslices, r.numstacks, r.numquads) == (16, 8, 4)
    assert s.solver_arena == "16M"
    assert render_fingerprint("tabletop") == render_fingerprint("tabletop", s) == "cbf9214bbc293f3b"


def test_a_variant_moves_rest_heights_and_footprints_together():
    for default, big in zip(DEFAULT_SCENE.objects, BIG.objects, strict=True):
        assert big.rest_height == pytest.approx(1.25 * default.rest_height, rel=1e-15)
        assert big.footprint == pytest.approx(1.25 * default.footprint, rel=1e-15)
        assert big.height == 2 * big.rest_height
    assert BIG.rest_heights["small_cube"] == pytest.approx(0.05)
    assert BIG.footprints["large_cube"] == pytest.approx(0.075 * math.sqrt(2.0))
    # A box's footprint is its base's circumradius, whatever its proportions.
    flat = dataclasses.replace(DEFAULT_SCENE.objects[0], size=(0.03, 0.04, 0.01))
    assert flat.footprint == pytest.approx(0.05) and flat.rest_height == 0.01
    # Only the objects changed; the default is untouched.
    assert BIG.table == DEFAULT_SCENE.table and BIG.camera == DEFAULT_SCENE.camera
    assert DEFAULT_SCENE.objects[0].size == (0.06, 0.06, 0.06)
    # The render fingerprint follows the camera and the render spec, not the objects.
    assert render_fingerprint("tabletop", BIG) == render_fingerprint("tabletop", DEFAULT_SCENE)
    far = dataclasses.replace(
        DEFAULT_SCENE, camera=dataclasses.replace(DEFAULT_SCENE.camera, fovy=12.0)
    )
    assert render_fingerprint("tabletop", far) != render_fingerprint("tabletop", DEFAULT_SCENE)


def test_bad_scenes_say_what_is_wrong():
    with pytest.raises(ValueError, match="a ball needs 1 positive size"):
        dataclasses.replace(DEFAULT_SCENE.objects[3], size=(0.02, 0.02))
    with pytest.raises(ValueError, match="unknown shape 'cone'"):
        dataclasses.replace(DEFAULT_SCENE.objects[3], shape="cone")
    with pytest.raises(ValueError, match="objects large_cube, small_cube, cylinder, sphere"):
        dataclasses.replace(DEFAULT_SCENE, objects=DEFAULT_SCENE.objects[::-1])
    with pytest.raises(ValueError, match="render spec draws camera 'agentview_shift_2'"):
        dataclasses.replace(
            DEFAULT_SCENE, camera=dataclasses.replace(DEFAULT_SCENE.camera, name="other")
        )
    with pytest.raises(ValueError, match="unknown tabletop scene field 'lights'"):
        TabletopScene.from_dict({"lights": 3})
    with pytest.raises(ValueError, match=r"unknown field\(s\) top in tabletop scene 'table'"):
        TabletopScene.from_dict({"table": {"top": 0.8}})


def test_a_scene_round_trips_through_json():
    for scene in (DEFAULT_SCENE, BIG):
        data = json.loads(json.dumps(scene.to_dict()))
        assert TabletopScene.from_dict(data) == scene
        assert resolve_scene(data) == scene
    assert resolve_scene(None) is DEFAULT_SCENE


def _states(env: TabletopEnv, seed: int, steps: int = 4) -> np.ndarray:
    env.reset(seed=seed)
    out = [env.get_state()]
    for action in np.random.default_rng(seed).uniform(-1, 1, (steps, 4)):
        env.step(action)
        out.append(env.get_state())
    return np.stack(out)


def test_a_default_env_steps_as_recorded():
    """States of the first steps, digested: recorded when the scene became the original's (a
    state is the same bits on every CPU, tests/envs/test_cross_cpu.py)."""
    with TabletopEnv("push_sphere", seed=0, observation_size=None) as env:
        h = hashlib.sha256(env.get_state().tobytes())
        env.reset(seed=3)
        h.update(env.get_state().tobytes())
        for action in np.random.default_rng(0).uniform(-1, 1, (5, 4)):
            env.step(action)
            h.update(env.get_state().tobytes())
        assert h.hexdigest()[:32] == "619e27bc66a91ffc2af03dc6dcab59f0"
        assert "scene" not in env.serialize()["kwargs"]


def test_a_default_env_replays_and_renders_a_shipped_instance_bit_for_bit():
    inst = TaskSuite.load().for_task("tabletop/push_cylinder")[0]
    with TabletopEnv("push_cylinder", observation_size=None) as env:
        env.reset_to(inst.init_state)
        for action in inst.actions:
            env.step(action)
        np.testing.assert_array_equal(env.get_state(), inst.goal_state)
        np.testing.assert_array_equal(env.render(64), inst.goal_image)


def test_envs_of_different_scenes_in_one_process_stay_apart():
    first = TabletopEnv("push_large_cube", seed=1, observation_size=None)
    big = TabletopEnv("push_large_cube", seed=1, observation_size=None, scene=BIG)
    second = TabletopEnv("push_large_cube", seed=1, observation_size=None)
    try:
        assert first.scene is DEFAULT_SCENE and second.scene is DEFAULT_SCENE and big.scene == BIG
        assert first._world.compiled_xml == second._world.compiled_xml != big._world.compiled_xml
        geoms = first._world.object_visual_geoms
        np.testing.assert_allclose(
            big._model.geom_size[geoms], 1.25 * first._model.geom_size[geoms], rtol=1e-6
        )
        np.testing.assert_array_equal(_states(first, 5), _states(second, 5))
        # The big objects start 1 cm above their own rest height, placed by their footprints.
        big.reset(seed=5)
        pos = big.object_positions()
        np.testing.assert_array_equal(
            pos[:, 2], [BIG.table.top_z + 0.01 + BIG.rest_heights[n] for n in OBJECT_NAMES]
        )
        radii = np.array([BIG.footprints[n] for n in OBJECT_NAMES])
        gaps = np.linalg.norm(pos[:, None, :2] - pos[None, :, :2], axis=-1)
        need = radii[:, None] + radii[None]
        assert np.all(gaps[~np.eye(4, dtype=bool)] > need[~np.eye(4, dtype=bool)])
        # Building the variant changed nothing of the default.
        assert render_fingerprint("tabletop") == render_fingerprint("tabletop", DEFAULT_SCENE)
        np.testing.assert_array_equal(_states(first, 6), _states(second, 6))
        # The scripted policy reads its env's scene.
        assert make_tabletop_policy(big, np.random.default_rng(0), 0).scene == BIG
    finally:
        for env in (first, big, second):
            env.close()


def test_a_variant_env_is_rebuilt_from_its_metadata():
    with TabletopEnv("push_sphere", seed=2, observation_size=None, scene=BIG) as env:
        meta = env.serialize()
        assert TabletopScene.from_dict(meta["kwargs"]["scene"]) == BIG
        json.dumps(meta)
        with make_env_from_metadata(meta) as rebuilt:
            assert rebuilt.scene == BIG
            np.testing.assert_array_equal(_states(rebuilt, 4), _states(env, 4))
