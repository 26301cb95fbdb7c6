"""Simplified visual meshes for the renderer (the physics model is never touched).

Software rendering (EGL on Mesa llvmpipe) is geometry-bound here: most of a RoboDesk frame's
141,680 mesh triangles are the Panda's *visual* meshes (geoms with ``contype = conaffinity =
0``), and every shadow-casting light draws them once more. At 64x64 almost none of those
triangles cover a pixel of their own, so :func:`simplified_render_model` builds a second,
render-only model of the same XML in which each large visual-only mesh is replaced by a
quadric-decimated copy (``fast-simplification``).

Reproducibility:

* the input of the decimation is the mesh as the physics model compiled it (MuJoCo's
  vertices, mapped back to the frame of the mesh file with the compiled ``mesh_pos`` /
  ``mesh_quat``), so nothing depends on how the file was read;
* the decimation is deterministic; its result is cached on disk under
  ``$VP2_CACHE_DIR/meshes/`` (default ``~/.cache/vp2/meshes/``), one file per mesh named by
  the SHA-256 of the source vertices and faces, the settings and the library versions, and
  written atomically (temporary file + ``os.replace``), so concurrent workers are safe;
* where the cache directory is not writable the meshes are simplified in memory (a few
  tenths of a second per model) and a :class:`RuntimeWarning` says how to fix it.

MuJoCo's compiler re-centres every mesh on its own centroid and principal axes and folds
that offset into the geom's ``pos``/``quat``; a decimated mesh has a (slightly) different
centroid, so the render model's geom frames differ from the physics model's. The render
model therefore needs its own ``MjData`` posed from the physics state
(:class:`vp2.envs.rendering.Renderer` does this: it copies ``qpos``/``mocap_*`` and runs
``mj_kinematics`` + ``mj_camlight``); bodies, geoms, materials, lights and cameras keep
their indices.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np

from vp2.utils.io import atomic_path
from vp2.utils.io import cache_dir as io_cache_dir

__all__ = [
    "DEFAULT_MIN_FACES",
    "DEFAULT_TARGET_REDUCTION",
    "cache_dir",
    "simplified_render_model",
    "simplify_mesh",
    "visual_only_meshes",
]

#: Fraction of the triangles removed from each simplified mesh when not given (each
#: environment's render spec's ``mesh_reduction`` is chosen by measurement, see
#: ``benchmarks/speed/bench_render_floor.py``).
DEFAULT_TARGET_REDUCTION = 0.9
#: Meshes with fewer triangles than this are left as they are (not worth it).
DEFAULT_MIN_FACES = 1000
#: Aggressiveness of fast-simplification's quadric decimation (its default).
_AGG = 7
_FORMAT = b"VP2MESH1"


def cache_dir() -> Path:
    """``$VP2_CACHE_DIR/meshes`` if set, else ``~/.cache/vp2/meshes``."""
    return io_cache_dir("meshes")


def visual_only_meshes(
    model: mujoco.MjModel,
    min_faces: int = DEFAULT_MIN_FACES,
    body_prefixes: tuple[str, ...] | None = None,
) -> list[int]:
    """Ids of meshes with at least ``min_faces`` triangles used only by visual-only geoms.

    A geom is visual-only when it collides with nothing (``contype == conaffinity == 0``);
    meshes not used by any geom are left alone. With ``body_prefixes``, only meshes whose
    geoms all belong to bodies named with one of the prefixes (e.g. the robot's, ``panda0_``).
    """
    out = []
    is_mesh = model.geom_type == mujoco.mjtGeom.mjGEOM_MESH
    for i in range(model.nmesh):
        users = np.flatnonzero(is_mesh & (model.geom_dataid == i))
        if len(users) == 0 or model.mesh_facenum[i] < min_faces:
            continue
        if np.any(model.geom_contype[users] != 0) or np.any(model.geom_conaffinity[users] != 0):
            continue
        if body_prefixes is not None and not all(
            model.body(model.geom_bodyid[g]).name.startswith(body_prefixes) for g in users
        ):
            continue
        out.append(i)
    return out


def _source_mesh(model: mujoco.MjModel, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Mesh ``i``'s vertices in its file's frame (scale applied) and its triangles.

    Vertices at the same position are welded into one first: OBJ files (robosuite's Panda)
    repeat a vertex for every normal/texture coordinate it has, which leaves the surface in
    disconnected triangles that a decimation cannot collapse sensibly. MuJoCo recomputes the
    normals of the simplified mesh (keeping sharp edges sharp, ``smoothnormal="false"``).
    """
    va, vn = model.mesh_vertadr[i], model.mesh_vertnum[i]
    fa, fn = model.mesh_faceadr[i], model.mesh_facenum[i]
    vert, inverse = np.unique(model.mesh_vert[va : va + vn], axis=0, return_inverse=True)
    vert = vert.astype(np.float64)
    face = inverse.reshape(-1)[model.mesh_face[fa : fa + fn]].astype(np.int32)
    keep = (face[:, 0] != face[:, 1]) & (face[:, 1] != face[:, 2]) & (face[:, 0] != face[:, 2])
    face = np.ascontiguousarray(face[keep])
    # The compiler stores vert_compiled = R(quat)^T (vert_file * scale - pos).
    rot = np.empty(9)
    mujoco.mju_quat2Mat(rot, model.mesh_quat[i])
    # vert @ R' + pos with the three terms added in order (a BLAS matrix product rounds
    # differently per CPU kernel, and the vertices name the cache file and feed the decimation).
    rot = rot.reshape(3, 3)
    vert = (
        vert[:, 0:1] * rot[:, 0] + vert[:, 1:2] * rot[:, 1] + vert[:, 2:3] * rot[:, 2]
    ) + model.mesh_pos[i]
    return vert, face


def _key(vert: np.ndarray, face: np.ndarray, target_reduction: float) -> str:
    import fast_simplification

    h = hashlib.sha256()
    h.update(_FORMAT)
    h.update(np.ascontiguousarray(vert, "<f8").tobytes())
    h.update(np.ascontiguousarray(face, "<i4").tobytes())
    version = getattr(fast_simplification, "__version__", "?")
    h.update(f"r={target_reduction!r} agg={_AGG} fs={version}".encode())
    return h.hexdigest()


def simplify_mesh(
    vert: np.ndarray, face: np.ndarray, target_reduction: float
) -> tuple[np.ndarray, np.ndarray]:
    """Quadric decimation (fast-simplification), deterministic: ``(vert float64, face int32)``."""
    import fast_simplification

    v, f = fast_simplification.simplify(
        np.ascontiguousarray(vert, np.float64), np.ascontiguousarray(face, np.int32),
        target_reduction=target_reduction, agg=_AGG,
    )
    return np.ascontiguousarray(v, np.float64), np.ascontiguousarray(f, np.int32)


def _encode(vert: np.ndarray, face: np.ndarray) -> bytes:
    head = np.array([len(vert), len(face)], "<i8").tobytes()
    return _FORMAT + head + vert.astype("<f8").tobytes() + face.astype("<i4").tobytes()


def _decode(blob: bytes) -> tuple[np.ndarray, np.ndarray]:
    if blob[:8] != _FORMAT:
        raise ValueError("not a vp2 mesh cache file")
    nv, nf = np.frombuffer(blob[8:24], "<i8")
    v_end = 24 + 24 * int(nv)
    if len(blob) != v_end + 12 * int(nf):
        raise ValueError("truncated vp2 mesh cache file")
    vert = np.frombuffer(blob[24:v_end], "<f8").reshape(-1, 3).copy()
    face = np.frombuffer(blob[v_end:], "<i4").reshape(-1, 3).copy()
    return vert, face


def _cached_simplify(
    vert: np.ndarray, face: np.ndarray, target_reduction: float, directory: Path | None
) -> tuple[np.ndarray, np.ndarray]:
    if directory is None:
        return simplify_mesh(vert, face, target_reduction)
    path = directory / f"{_key(vert, face, target_reduction)}.bin"
    try:
        return _decode(path.read_bytes())
    except (OSError, ValueError):
        pass
    v, f = simplify_mesh(vert, face, target_reduction)
    try:
        with atomic_path(path) as tmp:
            tmp.write_bytes(_encode(v, f))
    except OSError as err:
        warnings.warn(
            f"vp2: cannot write the simplified-mesh cache {directory} ({err}); simplifying in "
            "memory instead (slower start). Fix: make it writable, or set VP2_CACHE_DIR to a "
            "writable directory.",
            RuntimeWarning,
            stacklevel=3,
        )
    return v, f


def simplified_render_model(
    source: str | os.PathLike | mujoco.MjSpec,
    *,
    target_reduction: float = DEFAULT_TARGET_REDUCTION,
    min_faces: int = DEFAULT_MIN_FACES,
    body_prefixes: tuple[str, ...] | None = None,
    select: Callable[[mujoco.MjModel], list[int]] | None = None,
    cache: bool | str | os.PathLike = True,
) -> mujoco.MjModel:
    """The render model of an MJCF: its large visual-only meshes decimated.

    Args:
        source: path of an MJCF file, or an :class:`mujoco.MjSpec` of it (not modified; e.g.
            ``mujoco.MjSpec.from_string(xml)`` for a model built in memory).
        target_reduction: fraction of each selected mesh's triangles to remove; ``0`` keeps
            the model exactly as compiled from ``source``.
        min_faces: meshes with fewer triangles are kept (see :func:`visual_only_meshes`).
        body_prefixes: only meshes of bodies named with these prefixes (the robot's).
        select: overrides the mesh selection: ``select(model) -> mesh ids``.
        cache: ``True`` for :func:`cache_dir`, a directory, or ``False`` (in memory).

    Returns:
        A compiled model with the same bodies, joints, geoms, materials, lights and cameras
        (same indices) as ``source`` compiles to. Only for rendering: pose it from the
        physics state with ``mj_kinematics`` on its own ``MjData``.
    """
    if not 0.0 <= target_reduction < 1.0:
        raise ValueError(f"target_reduction must be in [0, 1), got {target_reduction}")
    if isinstance(source, mujoco.MjSpec):
        spec = source.copy()
    else:
        spec = mujoco.MjSpec.from_file(os.fspath(source))
    if target_reduction == 0.0:
        return spec.compile()
    original = spec.copy().compile()
    if select is not None:
        ids = select(original)
    else:
        ids = visual_only_meshes(original, min_faces, body_prefixes)
    directory = None if cache is False else (cache_dir() if cache is True else Path(cache))
    for i in ids:
        vert, face = _source_mesh(original, i)
        v, f = _cached_simplify(vert, face, target_reduction, directory)
        mesh = spec.meshes[i]
        mesh.file = ""
        mesh.content_type = ""
        mesh.scale = [1.0, 1.0, 1.0]
        mesh.refpos = [0.0, 0.0, 0.0]
        mesh.refquat = [1.0, 0.0, 0.0, 0.0]
        mesh.uservert = v.reshape(-1).tolist()
        mesh.userface = f.reshape(-1).tolist()
        mesh.usernormal = []
        mesh.usertexcoord = []
        mesh.userfacenormal = []
        mesh.userfacetexcoord = []
    model = spec.compile()
    _check_same_structure(original, model)
    return model


_STRUCTURE = ("nq", "nbody", "njnt", "ngeom", "nsite", "nmesh", "nmat", "ntex", "nlight", "ncam",
              "nmocap")


def _check_same_structure(a: mujoco.MjModel, b: mujoco.MjModel) -> None:
    for n in _STRUCTURE:
        if getattr(a, n) != getattr(b, n):
            raise RuntimeError(f"render model differs from the source model in {n}")
    for field in ("geom_type", "geom_bodyid", "geom_dataid", "body_parentid", "jnt_type"):
        if not np.array_equal(getattr(a, field), getattr(b, field)):
            raise RuntimeError(f"render model differs from the source model in {field}")

