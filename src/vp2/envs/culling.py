"""Frustum culling for the renderer (:class:`vp2.envs.rendering.Renderer`).

A software rasteriser transforms and clips every vertex it is given, whether or not it lands
in the image. Where nothing outside the camera's view can reach the image (no shadow-casting
light, no reflective material: the tabletop's render spec), the renderer leaves out of each
frame every geom whose bounding sphere lies outside the camera's view frustum; those geoms
draw no pixel, so the image is the same bit for bit (``tests/envs/test_frustum_culling.py``).
"""

from __future__ import annotations

import os
from typing import Any

# As in vp2.envs.rendering: MuJoCo picks its GL backend at import time.
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

#: Environment variable that turns frustum culling off (``0``) in every renderer made after.
CULL_ENV_VAR = "VP2_RENDER_CULL"

#: The geom group culled geoms are moved to for one frame: one that MuJoCo's default
#: visualisation options (``mjvOption.geomgroup``: groups 0-2 drawn) leave out.
_CULLED_GROUP = 5


class FrustumCulling:
    """Leaves geoms outside a named camera's view frustum out of the next frame.

    A geom is culled when its bounding sphere (``geom_rbound``, grown by ``margin`` for the
    float32 arithmetic of the GL pipeline) lies wholly behind the camera or beyond one of the
    frustum's four side planes. It then yields no fragment, so leaving it out changes no pixel,
    provided no pass other than the camera's draws it: culling is skipped for a frame whose
    model has an active shadow-casting light or a reflective material (:meth:`applies`).
    Planes (bounding radius 0) are never culled.

    Args:
        model: the GL context's model (its ``geom_group`` is switched per frame).
        camera: the camera's name.
        aspect: the render's width / height.
        margin: relative growth of every bounding radius.
    """

    def __init__(self, model: mujoco.MjModel, camera: str, aspect: float, margin: float = 0.01):
        self.camera = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        if self.camera < 0:
            raise ValueError(f"camera {camera!r} is not in the model")
        if (model.cam_sensorsize[self.camera] > 0).any():
            # MuJoCo then derives the frustum from the camera's intrinsics, not its fovy.
            raise ValueError(f"camera {camera!r} has a sensor size: frustum culling needs fovy")
        option = mujoco.MjvOption()
        if option.geomgroup[_CULLED_GROUP]:
            raise RuntimeError(f"MuJoCo's default options draw geom group {_CULLED_GROUP}")
        tan_y = np.tan(np.deg2rad(model.cam_fovy[self.camera]) / 2)
        self._tan = np.array([tan_y * aspect, tan_y])
        # Distance from the centre to a side plane, per unit of radius: sqrt(1 + tan^2).
        self._radius = model.geom_rbound * (1 + margin)
        self._slack = self._radius[:, None] * np.sqrt(1 + self._tan**2)[None, :]
        self._cullable = model.geom_rbound > 0
        self._groups = model.geom_group.copy()
        self.culled = 0

    @classmethod
    def for_camera(cls, model: mujoco.MjModel, camera: Any,
                   aspect: float) -> FrustumCulling | None:
        """Culling for ``camera`` if it is a named camera of ``model`` with a field of view
        (``fovy``, no intrinsics); ``None`` for any other camera (e.g. a free camera)."""
        if not isinstance(camera, str):
            return None
        cam = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        if cam < 0 or model.cam_sensorsize[cam].any():
            return None
        return cls(model, camera, aspect)

    @staticmethod
    def applies(model: mujoco.MjModel) -> bool:
        """Whether only the camera's own pass draws geoms (no shadows, no reflections)."""
        shadows = (model.light_castshadow.astype(bool) & model.light_active.astype(bool)).any()
        return not shadows and not (model.mat_reflectance > 0).any()

    def outside(self, data: mujoco.MjData) -> np.ndarray:
        """Mask of the geoms wholly outside the frustum (``data``'s kinematics current)."""
        rel = data.geom_xpos - data.cam_xpos[self.camera]
        local = rel @ data.cam_xmat[self.camera].reshape(3, 3)  # camera frame: looks along -z
        depth = -local[:, 2]
        beyond = np.abs(local[:, :2]) - depth[:, None] * self._tan[None, :] > self._slack
        return self._cullable & ((depth < -self._radius) | beyond.any(axis=1))

    def apply(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Moves the geoms outside the frustum to a hidden group, the rest back to their own."""
        if self.applies(model):
            out = self.outside(data)
            model.geom_group[:] = np.where(out, _CULLED_GROUP, self._groups)
            self.culled = int(out.sum())
        else:
            self.restore(model)

    def restore(self, model: mujoco.MjModel) -> None:
        """Every geom back in its own group (the next frame draws them all)."""
        model.geom_group[:] = self._groups
        self.culled = 0
