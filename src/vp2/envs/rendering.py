"""Rendering: one :class:`RenderSpec` per environment, used for datasets, goals and planning.

Software rendering (MuJoCo's EGL backend on Mesa) is the CPU bottleneck of the benchmark, and
most of its cost is the shadow passes (each shadow-casting light re-draws every mesh into a
shadow map and once more lit) and multisampling; with the robots' original visual meshes the
frame is geometry-bound, so environments render a render-only model with simplified meshes
(:mod:`vp2.envs.meshes`, the ``render_model`` of :class:`Renderer`). A :class:`RenderSpec`
therefore fixes, besides the camera, the quality knobs that trade fidelity for speed; each
environment documents the values it chose and their measured fidelity against
:meth:`RenderSpec.full_quality` (docs/robodesk.md, docs/tabletop.md).

The :class:`Renderer` owns one MuJoCo GL context per (model, size) and is reused for every
frame; creating a context per frame (as the ``robodesk`` package does) costs more than the
rendering itself. Where nothing outside the camera's view can reach the image (no
shadow-casting light, no reflective material: the tabletop's spec), it leaves out of the scene
every geom whose bounding sphere lies outside the view frustum
(:class:`vp2.envs.culling.FrustumCulling`): a software rasteriser transforms and clips every
vertex it is given, and most of the Panda is above the tabletop camera's view. Those geoms
draw no pixel, so the image is the same bit for bit (``tests/envs/test_frustum_culling.py``).
``VP2_RENDER_CULL=0`` in the environment turns it off in every process (for side-by-side
timing: ``benchmarks/speed/bench_oracle.py --cull both``).
"""

from __future__ import annotations

import atexit
import copy
import dataclasses
import os
import weakref
from collections.abc import Sequence
from typing import Any

import numpy as np

# MuJoCo picks its GL backend at import time; default to EGL (works headless on Mesa and NVIDIA).
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import mujoco  # noqa: E402
from PIL import Image  # noqa: E402

from vp2.envs.culling import CULL_ENV_VAR, FrustumCulling  # noqa: E402


@dataclasses.dataclass(frozen=True)
class FreeCamera:
    """A MuJoCo free camera looking at ``lookat`` from ``distance``/``azimuth``/``elevation``."""

    distance: float
    azimuth: float
    elevation: float
    lookat: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class RenderSpec:
    """How an environment turns simulator state into an image.

    Attributes:
        camera: a :class:`FreeCamera` or the name of a camera in the model.
        min_render_size: the scene is rendered at ``max(min_render_size, requested size)``
            before cropping/resizing (RoboDesk renders at 120 and crops).
        crop_box: optional ``(left, upper, right, lower)`` crop in pixels of a
            ``crop_reference``-sized render; scaled to the actual render size.
        crop_reference: the render size the crop box is expressed in.
        shadow_size: shadow-map side in texels (MuJoCo's default is 4096).
        shadow_lights: indices of lights that cast shadows; ``None`` keeps the model's own.
        multisamples: MSAA samples of the offscreen buffer (MuJoCo's default is 4).
        reflection: draw reflective materials' reflections.
        skybox: draw the skybox.
        mesh_reduction: fraction of the triangles removed from the large visual-only meshes
            of the render model (:func:`vp2.envs.meshes.simplified_render_model`; the
            environment builds that model and passes it to :class:`Renderer` as
            ``render_model``; the physics model is never touched). ``0`` draws the original
            meshes; a :class:`Renderer` given no ``render_model`` draws the model's own meshes
            whatever this says.
        plane_spacing: side of the squares MuJoCo tessellates planes into for drawing (the
            third ``size`` of a plane geom; rendering only); ``None`` keeps the model's.
        numslices, numstacks, numquads: tessellation of the built-in primitives (spheres,
            capsules, cylinders; boxes), MuJoCo's ``visual/quality``; ``None`` keeps the
            model's (28, 16, 4 by default).
    """

    camera: FreeCamera | str
    min_render_size: int = 0
    crop_box: tuple[float, float, float, float] | None = None
    crop_reference: int | None = None
    shadow_size: int = 4096
    shadow_lights: tuple[int, ...] | None = None
    multisamples: int = 4
    reflection: bool = True
    skybox: bool = True
    mesh_reduction: float = 0.0
    plane_spacing: float | None = None
    numslices: int | None = None
    numstacks: int | None = None
    numquads: int | None = None

    def full_quality(self) -> RenderSpec:
        """The same camera at MuJoCo's default quality with the original meshes: the fidelity
        reference."""
        return dataclasses.replace(
            self, shadow_size=4096, shadow_lights=None, multisamples=4, reflection=True,
            skybox=True, mesh_reduction=0.0, plane_spacing=None, numslices=None,
            numstacks=None, numquads=None,
        )

    def render_size(self, height: int, width: int) -> tuple[int, int]:
        """Size of the raw render for a requested output size."""
        if self.crop_box is None:
            return height, width
        side = max(self.min_render_size, height, width)
        return side, side


#: Version of the render pipeline (this module's code path from simulator state to pixels):
#: part of every environment's render fingerprint (:mod:`vp2.envs.render_specs`), which ties a
#: shipped oracle table to the images it planned on. Bump it when a change of the pipeline moves
#: pixels without changing a :class:`RenderSpec` or a camera constant (e.g. another texture
#: colour space, another resize filter).
RENDER_PATH_VERSION = 1


#: The quality knobs both environments' specs share, chosen by measurement for software
#: rendering (docs/robodesk.md, docs/tabletop.md): no multisampling, no reflection pass, planes
#: tessellated into 0.5 m squares and the built-in primitives into 16 slices, 8 stacks and one
#: quad per box face. An environment adds its camera, shadows, skybox and mesh reduction:
#: ``RenderSpec(camera=..., shadow_size=..., **SOFTWARE_RENDERING)``.
SOFTWARE_RENDERING: dict[str, Any] = {
    "multisamples": 0, "reflection": False, "plane_spacing": 0.5,
    "numslices": 16, "numstacks": 8, "numquads": 1,
}


def configure_model(model: mujoco.MjModel, spec: RenderSpec, height: int, width: int) -> None:
    """Applies a spec's quality settings to a model (before creating a GL context for it)."""
    model.vis.quality.shadowsize = spec.shadow_size
    model.vis.quality.offsamples = spec.multisamples
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, height)
    for knob in ("numslices", "numstacks", "numquads"):
        value = getattr(spec, knob)
        if value is not None:
            setattr(model.vis.quality, knob, value)
    if spec.plane_spacing is not None:
        planes = model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
        model.geom_size[planes, 2] = spec.plane_spacing
    if spec.shadow_lights is not None:
        cast = np.zeros(model.nlight, dtype=model.light_castshadow.dtype)
        for i in spec.shadow_lights:
            if not 0 <= i < model.nlight:
                raise ValueError(f"shadow light index {i} out of range: model has {model.nlight}")
            cast[i] = 1
        model.light_castshadow[:] = cast
    linearize_srgb_textures(model)


def _srgb_to_linear_table() -> np.ndarray:
    # The sRGB transfer function, rounded to 8 bits. Every exact value lies at least 0.0013
    # from a rounding boundary, so the table is the same whatever libm's pow rounds to.
    table = []
    for v in range(256):
        c = v / 255.0
        lin = c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4
        table.append(round(lin * 255.0))
    return np.array(table, np.uint8)


_SRGB_TO_LINEAR = _srgb_to_linear_table()


def linearize_srgb_textures(model: mujoco.MjModel) -> None:
    """Re-encodes the model's sRGB textures as linear ones (in place; a render-only copy).

    MuJoCo uploads a 2D sRGB texture as ``GL_SRGB8`` and has GL build its mipmaps. Mesa's
    llvmpipe encodes each generated mip level back to sRGB with an approximation built on the
    x86 ``rsqrtps`` instruction, whose result differs between CPU vendors (Intel and AMD round
    it differently): the minified texture, and so the image, depended on the CPU. Decoding the
    texels to linear values here (the same decode GL applies when sampling, rounded to 8 bits)
    and uploading them as a linear texture keeps the look and leaves mipmap generation to plain
    averaging.
    """
    srgb = mujoco.mjtColorSpace.mjCOLORSPACE_SRGB
    # MuJoCo honours the colour space for 2D textures only; cube and skybox textures are
    # uploaded as GL_RGB whatever it says, so they are left alone.
    uploaded_as_srgb = (model.tex_colorspace == srgb) & (
        model.tex_type == mujoco.mjtTexture.mjTEXTURE_2D
    )
    for i in np.flatnonzero(uploaded_as_srgb):
        start = int(model.tex_adr[i])
        size = int(model.tex_width[i]) * int(model.tex_height[i]) * int(model.tex_nchannel[i])
        data = model.tex_data[start : start + size]
        if model.tex_nchannel[i] == 4:  # alpha is linear already
            rgb = data.reshape(-1, 4)[:, :3]
            rgb[:] = _SRGB_TO_LINEAR[rgb]
        else:
            data[:] = _SRGB_TO_LINEAR[data]
        model.tex_colorspace[i] = mujoco.mjtColorSpace.mjCOLORSPACE_LINEAR


# GL contexts must be freed before the interpreter tears EGL down, or it prints errors at exit.
_LIVE_RENDERERS: weakref.WeakSet[Renderer] = weakref.WeakSet()


@atexit.register
def _close_all_renderers() -> None:
    for renderer in list(_LIVE_RENDERERS):
        for ctx in list(renderer._contexts.values()):
            try:
                ctx.close()
            except Exception:  # noqa: BLE001
                # EGL is already terminated: another library's exit hook (dm_control's, when
                # the `robodesk` package rendered after us) ran first. The OS reclaims the
                # contexts; drop MuJoCo's handles so that its destructors do not retry and
                # print EGL_NOT_INITIALIZED tracebacks at exit.
                _forget_gl_handles(ctx)
        renderer._contexts.clear()


def _forget_gl_handles(ctx: mujoco.Renderer) -> None:
    gl_context = getattr(ctx, "_gl_context", None)
    if gl_context is not None and hasattr(gl_context, "_context"):
        gl_context._context = None
    for attr in ("_gl_context", "_mjr_context"):
        if hasattr(ctx, attr):
            setattr(ctx, attr, None)


_EXIT_HOOK_AFTER_GL = False


def _register_exit_hook_after_gl() -> None:
    # MuJoCo's EGL backend registers eglTerminate with atexit when it creates its first context,
    # i.e. after this module's hook; atexit runs hooks last-in-first-out, so the contexts would
    # be destroyed after the display is gone (EGL_NOT_INITIALIZED errors at exit). Registering
    # the hook again after the first context makes it run before eglTerminate.
    global _EXIT_HOOK_AFTER_GL
    if not _EXIT_HOOK_AFTER_GL:
        _EXIT_HOOK_AFTER_GL = True
        atexit.register(_close_all_renderers)


_DYNAMIC_VISUAL_FIELDS = ("geom_matid", "geom_rgba", "mat_texid", "mat_rgba")


class Renderer:
    """Renders one model's benchmark camera with a :class:`RenderSpec`.

    The renderer works on its own copy of the model (quality settings must not leak into the
    physics model) and keeps one GL context per raw render size.

    With ``render_model`` (the same MJCF compiled with simplified visual meshes, see
    :func:`vp2.envs.meshes.simplified_render_model`) the renderer draws that model instead,
    posed from the physics state on a private ``MjData``: before each frame it copies
    ``qpos`` and ``mocap_pos``/``mocap_quat`` from the given data and runs ``mj_kinematics``
    and ``mj_camlight`` (microseconds). It does not read the physics data's kinematics at
    all, so a frame is a function of the state. The visual fields an environment may change
    on its physics model (geom groups, colours and materials, material reflectance, lights,
    the model statistics that scale the camera's clipping and shadow frusta) are copied from
    ``model`` when the renderer is created, and the per-instance ones
    (``_DYNAMIC_VISUAL_FIELDS``) before every frame.

    Args:
        model: the simulation model. Only its visual fields are copied and modified.
        spec: the render specification.
        render_model: optional render-only model with the same bodies, joints and geoms.
        cull: leave geoms outside a named camera's view out of the scene where that changes no
            pixel (:class:`vp2.envs.culling.FrustumCulling`); ``False`` draws every geom (for
            comparison); ``None``: on unless the environment variable ``VP2_RENDER_CULL`` is ``0``.
    """

    def __init__(
        self, model: mujoco.MjModel, spec: RenderSpec, render_model: mujoco.MjModel | None = None,
        cull: bool | None = None,
    ):
        self.spec = spec
        self.cull = os.environ.get(CULL_ENV_VAR, "1") != "0" if cull is None else cull
        self._culling: dict[tuple[int, int], FrustumCulling] = {}
        self._model = model
        self._render_model = None
        self._render_data: mujoco.MjData | None = None
        if render_model is not None:
            _check_compatible(model, render_model)
            self._render_model = copy.copy(render_model)
            _copy_visual_fields(model, self._render_model)
            self._render_data = mujoco.MjData(self._render_model)
        self._contexts: dict[tuple[int, int], mujoco.Renderer] = {}
        _LIVE_RENDERERS.add(self)
        self._camera: mujoco.MjvCamera | str
        if isinstance(spec.camera, FreeCamera):
            cam = mujoco.MjvCamera()
            cam.type = mujoco.mjtCamera.mjCAMERA_FREE
            cam.distance = spec.camera.distance
            cam.azimuth = spec.camera.azimuth
            cam.elevation = spec.camera.elevation
            cam.lookat[:] = spec.camera.lookat
            self._camera = cam
        else:
            if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, spec.camera) < 0:
                raise ValueError(f"camera {spec.camera!r} is not in the model")
            self._camera = spec.camera

    def _context(self, height: int, width: int) -> mujoco.Renderer:
        key = (height, width)
        ctx = self._contexts.get(key)
        if ctx is None:
            # A private copy so that the quality knobs never touch the physics model.
            source = self._model if self._render_model is None else self._render_model
            model = copy.copy(source)  # a deep copy of the model's arrays
            configure_model(model, self.spec, height, width)
            ctx = mujoco.Renderer(model, height=height, width=width)
            _register_exit_hook_after_gl()
            ctx.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = int(self.spec.reflection)
            ctx.scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = int(self.spec.skybox)
            self._contexts[key] = ctx
            culling = FrustumCulling.for_camera(ctx.model, self._camera, width / height)
            if culling is not None:
                self._culling[key] = culling
        return ctx

    def render(self, data: mujoco.MjData, height: int = 64, width: int | None = None) -> np.ndarray:
        """Renders ``data`` (whose kinematics must be current) as ``uint8 (height, width, 3)``."""
        width = height if width is None else width
        if height <= 0 or width <= 0:
            raise ValueError(f"render size must be positive, got {height}x{width}")
        rh, rw = self.spec.render_size(height, width)
        ctx = self._context(rh, rw)
        self._sync_visuals(ctx.model)
        if self._render_data is not None:
            data = self._pose(data)
        culling = self._culling.get((rh, rw))
        if culling is not None:
            if self.cull:
                culling.apply(ctx.model, data)
            else:
                culling.restore(ctx.model)
        ctx.update_scene(data, camera=self._camera)
        image = ctx.render()
        if self.spec.crop_box is None:
            return image.copy() if image.shape[:2] == (height, width) else _resize(image, height, width)
        scale = rh / float(self.spec.crop_reference or rh)
        box = tuple(c * scale for c in self.spec.crop_box)
        pil = Image.fromarray(image).crop(box)
        return np.asarray(pil.resize((width, height), resample=Image.Resampling.LANCZOS))

    def _pose(self, data: mujoco.MjData) -> mujoco.MjData:
        pose = self._render_data
        pose.qpos[:] = data.qpos
        if self._render_model.nmocap:
            pose.mocap_pos[:] = data.mocap_pos
            pose.mocap_quat[:] = data.mocap_quat
        mujoco.mj_kinematics(self._render_model, pose)
        mujoco.mj_camlight(self._render_model, pose)
        return pose

    def _sync_visuals(self, render_model: mujoco.MjModel) -> None:
        # Environments may re-texture objects per instance by switching materials at run time;
        # the GL context already holds every texture, so only these small arrays need copying.
        for field in _DYNAMIC_VISUAL_FIELDS:
            getattr(render_model, field)[:] = getattr(self._model, field)

    def close(self) -> None:
        for ctx in self._contexts.values():
            ctx.close()
        self._contexts.clear()
        self._culling.clear()


_STRUCTURE_COUNTS = ("nq", "nbody", "njnt", "ngeom", "nsite", "nmat", "ntex", "nlight", "ncam",
                     "nmocap")
_STRUCTURE_FIELDS = ("geom_type", "geom_bodyid", "body_parentid", "jnt_type", "jnt_qposadr")
#: Visual fields copied from the physics model into a separate render model at creation:
#: everything an environment may have changed on its compiled model, and the statistics from
#: which MuJoCo scales the near/far clipping planes and the directional lights' shadow frusta.
_STATIC_VISUAL_FIELDS = (
    "geom_group", "geom_rgba", "geom_matid", "site_group", "site_rgba", "mat_rgba", "mat_texid",
    "mat_reflectance", "mat_emission", "mat_specular", "mat_shininess", "light_castshadow",
    "light_active", "light_ambient", "light_diffuse", "light_specular", "cam_fovy",
)
_STAT_FIELDS = ("extent", "center", "meansize")


def _check_compatible(model: mujoco.MjModel, render_model: mujoco.MjModel) -> None:
    for n in _STRUCTURE_COUNTS:
        if getattr(model, n) != getattr(render_model, n):
            raise ValueError(
                f"render model does not match the physics model: {n} {getattr(render_model, n)}"
                f" != {getattr(model, n)}"
            )
    for field in _STRUCTURE_FIELDS:
        if not np.array_equal(getattr(model, field), getattr(render_model, field)):
            raise ValueError(f"render model does not match the physics model in {field}")


def _copy_visual_fields(model: mujoco.MjModel, render_model: mujoco.MjModel) -> None:
    for field in _STATIC_VISUAL_FIELDS + _DYNAMIC_VISUAL_FIELDS:
        getattr(render_model, field)[:] = getattr(model, field)
    for field in _STAT_FIELDS:
        setattr(render_model.stat, field, getattr(model.stat, field))


def _resize(image: np.ndarray, height: int, width: int) -> np.ndarray:
    pil = Image.fromarray(image)
    return np.asarray(pil.resize((width, height), resample=Image.Resampling.LANCZOS))


def antialiased_bilinear(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """``image`` (``uint8`` RGB) resized to ``height`` x ``width`` as the original VP2 release
    resized its 256x256 renders: torchvision's ``Resize(BILINEAR, antialias=True)``. PIL's
    bilinear filter widens its support by the downscaling factor, which is what torchvision's
    anti-aliasing ports from it (the two differ by at most 1/255 per pixel, 0.09/255 on average,
    on a 256x256 tabletop frame)."""
    pil = Image.fromarray(np.ascontiguousarray(image))
    return np.asarray(pil.resize((width, height), resample=Image.Resampling.BILINEAR))


def mean_abs_error(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute pixel error of two uint8 images, in units of 1/255."""
    return float(np.abs(a.astype(np.float64) - b.astype(np.float64)).mean())


def contact_sheet(
    images: Sequence[np.ndarray], labels: Sequence[str], columns: int = 4, scale: int = 3
) -> np.ndarray:
    """Tiles labelled images into one ``uint8`` RGB image (for looking at, not for data)."""
    from PIL import ImageDraw

    if len(images) != len(labels):
        raise ValueError(f"{len(images)} images but {len(labels)} labels")
    h, w = images[0].shape[:2]
    cell_w, cell_h, pad = w * scale, h * scale, 14
    rows = (len(images) + columns - 1) // columns
    sheet = Image.new("RGB", (columns * cell_w, rows * (cell_h + pad)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for i, (img, label) in enumerate(zip(images, labels, strict=True)):
        r, c = divmod(i, columns)
        x, y = c * cell_w, r * (cell_h + pad)
        tile = Image.fromarray(img).resize((cell_w, cell_h), resample=Image.Resampling.NEAREST)
        sheet.paste(tile, (x, y + pad))
        draw.text((x + 2, y + 1), label, fill=(0, 0, 0))
    return np.asarray(sheet)
