"""Render-only models with simplified visual meshes (vp2.envs.meshes) and the Renderer path."""

from __future__ import annotations

import os
import warnings

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco
import numpy as np
import pytest

from vp2.envs import _robodesk_model, meshes, robodesk
from vp2.envs.rendering import Renderer, mean_abs_error


@pytest.fixture(scope="module")
def desk_states():
    env = robodesk.RoboDeskEnv("push_red", seed=0, observation_size=None)
    env.reset(seed=4)
    rng = np.random.default_rng(0)
    states = []
    for _ in range(3):
        env.step(rng.uniform(-1, 1, 5))
        states.append(env.get_state())
    env.close()
    return states


def _posed(env):
    mujoco.mj_kinematics(env.model, env.data)
    mujoco.mj_camlight(env.model, env.data)
    return env.data


def test_physics_model_untouched(desk_states):
    fresh = mujoco.MjModel.from_xml_path(os.fspath(_robodesk_model.asset_path()))
    env = robodesk.RoboDeskEnv("push_red", seed=0, observation_size=64)
    blind = robodesk.RoboDeskEnv("push_red", seed=0, observation_size=None)
    env.reset_to(desk_states[0])
    blind.reset_to(desk_states[0])
    for action in np.random.default_rng(1).uniform(-1, 1, (2, 5)):
        obs, *_ = env.step(action)
        blind.step(action)
        assert obs.shape == (64, 64, 3)
    for field in ("mesh_vert", "mesh_face", "mesh_normal", "mesh_vertadr", "mesh_facenum",
                  "mesh_pos", "mesh_quat", "geom_pos", "geom_quat", "geom_size", "body_mass",
                  "body_inertia", "body_ipos"):
        assert np.array_equal(getattr(env.model, field), getattr(fresh, field)), field
    assert env.model.nmeshface == fresh.nmeshface
    assert np.array_equal(env.get_state(), blind.get_state())  # rendering changes no dynamics
    render_model = env._renderer._render_model
    assert render_model.nmeshface < 0.2 * fresh.nmeshface
    assert (render_model.nbody, render_model.ngeom) == (fresh.nbody, fresh.ngeom)
    env.close()


def test_render_path_equals_direct_render(desk_states):
    """The unsimplified render model posed on a private MjData gives the same image."""
    env = robodesk.RoboDeskEnv("push_red", seed=0, observation_size=None)
    same = meshes.simplified_render_model(_robodesk_model.asset_path(), target_reduction=0.0)
    assert (same.nbody, same.ngeom, same.nmesh) == (env.model.nbody, env.model.ngeom, env.model.nmesh)
    via_copy = Renderer(env.model, _robodesk_model.RENDER_SPEC, render_model=same)
    direct = Renderer(env.model, _robodesk_model.RENDER_SPEC)
    for state in desk_states:
        env.reset_to(state)
        data = _posed(env)
        assert np.array_equal(via_copy.render(data, 64), direct.render(data, 64))
    via_copy.close()
    direct.close()


def test_render_model_structure_is_checked():
    env = robodesk.RoboDeskEnv("push_red", seed=0, observation_size=None)
    other = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='1'/></worldbody></mujoco>")
    with pytest.raises(ValueError, match="render model does not match"):
        Renderer(env.model, _robodesk_model.RENDER_SPEC, render_model=other)


def test_simplified_geometry_stays_in_place():
    """Re-centred meshes compile to other geom frames; posed, they cover the same space."""
    model = _robodesk_model.load_model()
    simple = _robodesk_model.load_render_model()
    ids = meshes.visual_only_meshes(model, body_prefixes=_robodesk_model.RENDER_MESH_BODIES)
    assert len(ids) == 9  # the Panda's visual meshes (link0-7, hand; the fingers are small)
    assert sum(model.mesh_facenum[ids]) > 130_000
    d0, d1 = mujoco.MjData(model), mujoco.MjData(simple)
    d0.qpos[:] = d1.qpos[:] = model.qpos0 + 0.3
    mujoco.mj_kinematics(model, d0)
    mujoco.mj_kinematics(simple, d1)
    for g in np.flatnonzero(np.isin(model.geom_dataid, ids) & (model.geom_type == 7)):
        boxes = []
        for m, d in ((model, d0), (simple, d1)):
            i = m.geom_dataid[g]
            v = m.mesh_vert[m.mesh_vertadr[i] : m.mesh_vertadr[i] + m.mesh_vertnum[i]]
            w = v @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
            boxes.append(np.concatenate([w.min(0), w.max(0)]))
        assert np.abs(boxes[0] - boxes[1]).max() < 0.005  # metres


def test_fidelity_against_full_quality_original_meshes(desk_states):
    env = robodesk.RoboDeskEnv("push_red", seed=0, observation_size=None)
    full = Renderer(env.model, _robodesk_model.RENDER_SPEC.full_quality())
    for state in desk_states:
        env.reset_to(state)
        image = env.render(64)
        reference = full.render(_posed(env), 64)
        assert mean_abs_error(image, reference) <= 8.0
    full.close()
    env.close()


def _one_mesh():
    model = _robodesk_model.load_model()
    return meshes._source_mesh(model, meshes.visual_only_meshes(model, body_prefixes=('panda0_',))[0])


def test_cache_is_deterministic_and_used(tmp_path):
    vert, face = _one_mesh()
    blobs = []
    for name in ("a", "b"):
        directory = tmp_path / name
        v, f = meshes._cached_simplify(vert, face, 0.9, directory)
        (path,) = directory.iterdir()
        blobs.append(path.read_bytes())
        assert len(f) < 0.15 * len(face)
        # A second call reads the file back: the same arrays.
        v2, f2 = meshes._cached_simplify(vert, face, 0.9, directory)
        assert np.array_equal(v, v2) and np.array_equal(f, f2)
        assert not list(directory.glob("*.tmp"))
    assert blobs[0] == blobs[1]
    # Other settings, other file.
    meshes._cached_simplify(vert, face, 0.8, tmp_path / "a")
    assert len(list((tmp_path / "a").iterdir())) == 2


def test_cache_dir_from_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("VP2_CACHE_DIR", str(tmp_path))
    assert meshes.cache_dir() == tmp_path / "meshes"


def test_unwritable_cache_falls_back_to_memory(tmp_path):
    blocker = tmp_path / "not_a_directory"
    blocker.write_text("")
    vert, face = _one_mesh()
    with pytest.warns(RuntimeWarning, match="VP2_CACHE_DIR"):
        v, f = meshes._cached_simplify(vert, face, 0.9, blocker / "meshes")
    expected = meshes.simplify_mesh(vert, face, 0.9)
    assert np.array_equal(v, expected[0]) and np.array_equal(f, expected[1])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        meshes._cached_simplify(vert, face, 0.9, None)  # in memory: no warning


def test_tabletop_render_model():
    """The tabletop's robosuite Panda: same path equivalence, fidelity, physics untouched."""
    from vp2.envs.tabletop import DEFAULT_SCENE, TabletopEnv

    spec = DEFAULT_SCENE.render

    env = TabletopEnv("push_sphere", seed=0, observation_size=None)
    env.reset(seed=3)
    for action in np.random.default_rng(0).uniform(-1, 1, (3, 4)):
        env.step(action)
    model, data = env._model, env._data
    faces = model.nmeshface
    same = meshes.simplified_render_model(
        mujoco.MjSpec.from_string(env._world.compiled_xml), target_reduction=0.0
    )
    via_copy = Renderer(model, spec, render_model=same)
    direct = Renderer(model, spec)
    image = env.render(64)  # through the simplified render model
    mujoco.mj_kinematics(model, data)
    mujoco.mj_camlight(model, data)
    assert np.array_equal(via_copy.render(data, 64), direct.render(data, 64))
    full = Renderer(model, spec.full_quality())
    assert mean_abs_error(image, full.render(data, 64)) <= 8.0
    assert model.nmeshface == faces
    simple = env._renderer._render_model
    assert simple.nmeshface < 0.5 * faces and simple.ngeom == model.ngeom
    for r in (via_copy, direct, full):
        r.close()
    env.close()


def test_bad_reduction():
    with pytest.raises(ValueError, match="target_reduction"):
        meshes.simplified_render_model(_robodesk_model.asset_path(), target_reduction=1.0)
