"""The RoboDesk MuJoCo models: the physics model compiled from the ``robodesk`` package's
``desk.xml``, the render-only model with simplified meshes, and the benchmark camera's
:data:`RENDER_SPEC` that draws it. :class:`vp2.envs.robodesk.RoboDeskEnv` simulates the one
and renders the other.
"""

from __future__ import annotations

import copy
import importlib.util
import os
from pathlib import Path

import mujoco

from vp2.envs.meshes import simplified_render_model
from vp2.envs.rendering import SOFTWARE_RENDERING, FreeCamera, RenderSpec

#: The benchmark camera (SPEC §1.1) and the quality settings chosen for software rendering
#: (``benchmarks/speed/bench_render_floor.py``, docs/robodesk.md "Rendering"). The renderer draws a
#: render-only model whose Panda visual meshes (134k of the scene's 142k triangles) are
#: decimated to 5% (``mesh_reduction=0.95``, :func:`load_render_model`; physics untouched);
#: the floor plane is tessellated into 0.5 m squares instead of 0.1 m (25x fewer quads per
#: pass) and the built-in spheres/cylinders/boxes more coarsely (16 slices, 8 stacks, 1 quad
#: per box face). All three lights still cast shadows (the shadows are large areas of the
#: image: with two shadow lights ~12/255 off, with none ~40/255), 512² shadow maps, no
#: multisampling (the 120 px render is LANCZOS-resized anyway), no reflection pass. Each
#: shadow-casting light costs a depth pass and a lighting pass, so at the geometry floor the
#: shadows are still ~85% of the frame. Measured (2026-11-24, 2-core VM, llvmpipe, load ~4):
#: mean absolute error 6.53/255 (max 7.23) against ``full_quality()`` with the original
#: meshes over 98 varied states (budget 8/255), 18.8 ms per 64x64 frame vs 107.6 ms with the
#: previous settings and original meshes. See docs/robodesk.md.
RENDER_SPEC = RenderSpec(
    camera=FreeCamera(distance=1.8, azimuth=90.0, elevation=-60.0, lookat=(0.0, 0.535, 1.1)),
    min_render_size=120,
    crop_box=(16.75, 25.0, 105.0, 88.75),
    crop_reference=120,
    shadow_size=512,
    shadow_lights=(0, 1, 2),
    skybox=True,
    mesh_reduction=0.95,
    **SOFTWARE_RENDERING,
)


def asset_path() -> Path:
    """Path of the ``robodesk`` package's ``desk.xml``.

    Found without importing ``robodesk`` (which imports gym and dm_control).
    """
    spec = importlib.util.find_spec("robodesk")
    if spec is None or not spec.submodule_search_locations:
        raise ImportError(
            "the `robodesk` package is required for the RoboDesk tasks: pip install robodesk"
        )
    return Path(next(iter(spec.submodule_search_locations))) / "assets" / "desk.xml"


#: The bodies whose visual-only meshes the render model simplifies: the Panda's.
RENDER_MESH_BODIES = ("panda0_",)

_BASE_MODEL: mujoco.MjModel | None = None
_RENDER_MODELS: dict[float, mujoco.MjModel] = {}


def load_model() -> mujoco.MjModel:
    """A fresh copy of the compiled RoboDesk model (compiled once per process)."""
    global _BASE_MODEL
    if _BASE_MODEL is None:
        _BASE_MODEL = mujoco.MjModel.from_xml_path(os.fspath(asset_path()))
    # copy.copy deep-copies the model's arrays: an env may change its own options freely.
    return copy.copy(_BASE_MODEL)


def load_render_model(mesh_reduction: float | None = None) -> mujoco.MjModel:
    """The render-only model: ``desk.xml`` with its large visual-only meshes (the Panda's)
    decimated by ``mesh_reduction`` (default ``RENDER_SPEC.mesh_reduction``).

    Built once per process (about 0.3 s, the decimated meshes cached on disk, see
    :mod:`vp2.envs.meshes`); the caller gets a copy. Never used for physics.
    """
    reduction = RENDER_SPEC.mesh_reduction if mesh_reduction is None else float(mesh_reduction)
    model = _RENDER_MODELS.get(reduction)
    if model is None:
        model = simplified_render_model(
            asset_path(), target_reduction=reduction, body_prefixes=RENDER_MESH_BODIES
        )
        _RENDER_MODELS[reduction] = model
    return copy.copy(model)
