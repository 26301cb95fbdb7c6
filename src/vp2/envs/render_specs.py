"""Each environment's render specification as data, and its fingerprint.

The render fingerprint names what turns an environment's simulator state into pixels: its
:class:`~vp2.envs.rendering.RenderSpec` (camera, crop, quality knobs), for the tabletop the
benchmark camera's placement (the spec names the camera, the scene places it; both are read
from the :class:`~vp2.envs.tabletop_scene.TabletopScene`, the default scene unless one is
given), and :data:`~vp2.envs.rendering.RENDER_PATH_VERSION`. A shipped oracle
table records the fingerprint of every environment it ran on, and a run is normalised by a
table only where its environment's fingerprint is this package's
(:mod:`vp2.oracle.shipped`): an oracle that planned on other images measured another
benchmark.

Computing it builds no environment: it reads the RoboDesk module's constant (importing it) and
the tabletop scene value (no simulator).
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import json
from typing import TYPE_CHECKING, Any

from vp2.envs.tasks import ENV_NAMES

if TYPE_CHECKING:
    from vp2.envs.tabletop_scene import TabletopScene

#: Module of the RoboDesk ``RENDER_SPEC`` (the tabletop's is its scene's ``render``).
_ROBODESK_SPEC_MODULE = "vp2.envs._robodesk_model"
#: Hex digits of a fingerprint.
FINGERPRINT_LENGTH = 16


def render_description(env: str, scene: TabletopScene | None = None) -> dict[str, Any]:
    """What the fingerprint of ``env`` hashes, as plain data.

    Args:
        env: ``"robodesk"`` or ``"tabletop"``.
        scene: the tabletop scene (default: :data:`~vp2.envs.tabletop_scene.DEFAULT_SCENE`);
            only for the tabletop.

    Raises:
        ValueError: an unknown environment, or a scene for another environment.
    """
    if env not in ENV_NAMES:
        raise ValueError(f"unknown environment {env!r}; known: {', '.join(ENV_NAMES)}")
    if scene is not None and env != "tabletop":
        raise ValueError(f"a scene describes the tabletop only; {env!r} has none")
    from vp2.envs import rendering

    out: dict[str, Any] = {"env": env, "render_path_version": rendering.RENDER_PATH_VERSION}
    if env == "tabletop":
        from vp2.envs.tabletop_scene import resolve_scene

        out.update(resolve_scene(scene).render_description())
    else:
        out["spec"] = dataclasses.asdict(importlib.import_module(_ROBODESK_SPEC_MODULE).RENDER_SPEC)
    return out


def render_fingerprint(env: str, scene: TabletopScene | None = None) -> str:
    """A short hash (16 hex digits) of ``env``'s render specification
    (:func:`render_description` as canonical JSON: sorted keys, no spaces); ``scene``: the
    tabletop scene (default: the benchmark's)."""
    text = json.dumps(render_description(env, scene), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:FINGERPRINT_LENGTH]


def render_fingerprints(envs: Any = None) -> dict[str, str]:
    """``{env: fingerprint}`` for ``envs`` (default: every environment), sorted by name."""
    return {env: render_fingerprint(env) for env in sorted(envs if envs is not None else ENV_NAMES)}


__all__ = ["FINGERPRINT_LENGTH", "render_description", "render_fingerprint", "render_fingerprints"]
