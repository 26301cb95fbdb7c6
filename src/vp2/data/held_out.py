"""A default dataset's validation trajectories, collected on their own.

``vp2 diagnose`` measures action conditioning on held-out clips of the environment's default
dataset (the ``valid`` split of what ``vp2 collect ENV`` writes). Where that dataset is absent,
:func:`held_out_dataset` collects its validation trajectories alone, the very ones the whole
collection holds: the same collection settings (those of ``vp2 collect ENV`` with no other
flag), so the same seeds, scripted policies and noise, and the same split (trajectory ``i`` is
held out when ``i % valid_every == valid_every - 1``). Trajectory ``i`` depends only on the
dataset seed, its stream and its index in the stream (:mod:`vp2.data.collect`), so collecting
it alone gives it bit for bit, and the ``valid`` clips of the result, in
:class:`~vp2.data.loader.ClipDataset` order, are the default dataset's.

They are cached under ``$VP2_CACHE_DIR/held-out`` (default ``~/.cache/vp2/held-out``), one
directory per collection, keyed by its settings, the vp2 version and the environment's render
fingerprint; a second diagnosis reads them. The directory is a vp2 dataset holding only the
validation trajectories (its manifest lists them under ``indices``), resumable like any
collection. Not under ``data/``: a partial dataset at the default path would pass for the
whole one with ``vp2 train`` and make ``vp2 collect ENV`` refuse the directory.
"""

from __future__ import annotations

import gc
import hashlib
import json
import logging
import os
import sys
from pathlib import Path

import vp2
from vp2.data import storage
from vp2.data.collect import DEFAULT_TRAJECTORIES, CollectionConfig, collect
from vp2.data.datasets import default_dataset
from vp2.utils.io import cache_dir

log = logging.getLogger(__name__)

#: The cache folder of the held-out collections (:func:`vp2.utils.io.cache_dir`).
HELD_OUT_CACHE = "held-out"
#: A one-geom scene that :func:`rendering_problem` renders.
_PROBE_XML = '<mujoco><worldbody><geom size="1"/></worldbody></mujoco>'


def default_collection(env: str) -> CollectionConfig:
    """The settings of ``vp2 collect ENV`` with no other flag: the default dataset's."""
    if env not in DEFAULT_TRAJECTORIES:
        raise ValueError(f"unknown environment {env!r}; known: {', '.join(DEFAULT_TRAJECTORIES)}")
    return CollectionConfig(env=env, trajectories_per_stream=DEFAULT_TRAJECTORIES[env])


def validation_indices(config: CollectionConfig) -> list[int]:
    """The dataset indices of the collection's ``valid`` split, in order."""
    return [i for i in range(config.total) if storage.is_valid_index(i, config.valid_every)]


def held_out_dir(env: str) -> Path:
    """Where :func:`held_out_dataset` keeps ``env``'s default validation trajectories:
    ``<cache>/held-out/<default dataset name>-valid-<key>``, the key a hash of the collection
    settings, the vp2 version and the render fingerprint (a change of any collects anew)."""
    from vp2.envs.render_specs import render_fingerprint

    config = default_collection(env)
    key = {"config": config.to_json(), "vp2": vp2.__version__, "render": render_fingerprint(env)}
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:12]
    return cache_dir(HELD_OUT_CACHE) / f"{default_dataset(env).name}-valid-{digest}"


def is_complete(root: Path) -> bool:
    """Whether ``root`` holds a finished collection (a complete manifest)."""
    try:
        return bool(storage.load_manifest(root).get("complete", False))
    except storage.DatasetError:
        return False


def rendering_problem() -> str | None:
    """Why MuJoCo cannot render here (a one-line reason), or ``None`` when it can: renders an
    8x8 frame of a one-geom scene with the configured backend (``MUJOCO_GL``)."""
    # A renderer that failed half-built complains again when collected; say it once, here.
    hook, sys.unraisablehook = sys.unraisablehook, lambda _: None
    try:
        return _render_probe()
    finally:
        gc.collect()
        sys.unraisablehook = hook


def _render_probe() -> str | None:
    try:
        import mujoco

        model = mujoco.MjModel.from_xml_string(_PROBE_XML)
        renderer = mujoco.Renderer(model, 8, 8)
        try:
            renderer.update_scene(mujoco.MjData(model))
            renderer.render()
        finally:
            renderer.close()
    except Exception as exc:  # noqa: BLE001  (any failure means: no rendering here)
        try:
            text = str(exc).splitlines()[0] if str(exc) else ""
        except Exception:  # noqa: BLE001  (PyOpenGL's EGLError cannot always print itself)
            text = ""
        return f"{type(exc).__name__}{': ' + text if text else ''}"
    return None


def held_out_dataset(env: str, progress: bool = True, workers: int | None = None) -> Path:
    """The default dataset's validation trajectories of ``env`` (module docstring): read from
    the cache, else collected there first (with a progress bar).

    Raises:
        storage.DatasetError: rendering does not work here, naming the fix.
    """
    root = held_out_dir(env)
    if is_complete(root):
        return root
    config = default_collection(env)
    indices = validation_indices(config)
    problem = rendering_problem()
    if problem is not None:
        raise storage.DatasetError(
            f"no dataset at {default_dataset(env)}, and its {len(indices)} held-out trajectories "
            f"cannot be rendered here (MUJOCO_GL={os.environ.get('MUJOCO_GL', '')}: {problem}); "
            "run with MUJOCO_GL=egl on a machine with EGL (Mesa's libEGL or an NVIDIA driver), "
            f"or pass --data DIR, or --clips 0 to skip the action-conditioning measure"
        )
    log.info(
        "no dataset at %s: collecting its %d held-out trajectories into %s (once; `vp2 collect "
        "%s` makes the whole dataset)", default_dataset(env), len(indices), root, env,
    )
    return collect(config, root, workers=workers, progress=progress, indices=indices)


__all__ = [
    "HELD_OUT_CACHE",
    "default_collection",
    "held_out_dataset",
    "held_out_dir",
    "is_complete",
    "rendering_problem",
    "validation_indices",
]
