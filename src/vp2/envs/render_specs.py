"""Each environment's render specification as data, and its fingerprint.

The render fingerprint names what turns an environment's simulator state into pixels: its
:class:`~vp2.envs.rendering.RenderSpec` (camera, crop, quality knobs), for the tabletop the
benchmark camera's constants in :mod:`vp2.envs._tabletop_world` (its spec names the camera,
the constants place it), and :data:`~vp2.envs.rendering.RENDER_PATH_VERSION`. A shipped oracle
table records the fingerprint of every environment it ran on, and a run is normalised by a
table only where its environment's fingerprint is this package's
(:mod:`vp2.oracle.shipped`): an oracle that planned on other images measured another
benchmark.

Computing it builds no environment: it reads module constants (importing the environment
modules, which for the tabletop imports robosuite).
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import json
from typing import Any

from vp2.envs.tasks import ENV_NAMES

#: Module of each environment's ``RENDER_SPEC``.
_SPEC_MODULES: dict[str, str] = {
    "robodesk": "vp2.envs._robodesk_model",
    "tabletop": "vp2.envs.tabletop",
}
#: Camera constants of the tabletop's named camera, read at call time.
_TABLETOP_CAMERA = ("CAMERA_POS", "CAMERA_LOOKAT", "CAMERA_FOVY")
#: Hex digits of a fingerprint.
FINGERPRINT_LENGTH = 16


def render_description(env: str) -> dict[str, Any]:
    """What the fingerprint of ``env`` hashes, as plain data.

    Raises:
        ValueError: an unknown environment.
    """
    if env not in _SPEC_MODULES:
        raise ValueError(f"unknown environment {env!r}; known: {', '.join(ENV_NAMES)}")
    from vp2.envs import rendering

    spec = importlib.import_module(_SPEC_MODULES[env]).RENDER_SPEC
    out: dict[str, Any] = {
        "env": env,
        "render_path_version": rendering.RENDER_PATH_VERSION,
        "spec": dataclasses.asdict(spec),
    }
    if env == "tabletop":
        from vp2.envs import _tabletop_world

        out["camera"] = {name: getattr(_tabletop_world, name) for name in _TABLETOP_CAMERA}
    return out


def render_fingerprint(env: str) -> str:
    """A short hash (16 hex digits) of ``env``'s render specification
    (:func:`render_description` as canonical JSON: sorted keys, no spaces)."""
    text = json.dumps(render_description(env), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:FINGERPRINT_LENGTH]


def render_fingerprints(envs: Any = None) -> dict[str, str]:
    """``{env: fingerprint}`` for ``envs`` (default: every environment), sorted by name."""
    return {env: render_fingerprint(env) for env in sorted(envs if envs is not None else ENV_NAMES)}


__all__ = ["FINGERPRINT_LENGTH", "render_description", "render_fingerprint", "render_fingerprints"]
