"""Building environments: by task name (:func:`make_env`) or from metadata
(:func:`make_env_from_metadata`, robomimic's ``create_env_from_metadata``)."""

from __future__ import annotations

import importlib
from typing import Any

from vp2.envs.base import Env
from vp2.envs.tasks import ENV_NAMES, split_name

_ENV_CLASSES: dict[str, str] = {
    "robodesk": "vp2.envs.robodesk:RoboDeskEnv",
    "tabletop": "vp2.envs.tabletop:TabletopEnv",
}


def env_class(env: str) -> type[Env]:
    """The class implementing one environment (imported lazily: simulators are heavy)."""
    if env not in _ENV_CLASSES:
        raise ValueError(f"unknown environment {env!r}; known: {', '.join(ENV_NAMES)}")
    module, cls = _ENV_CLASSES[env].split(":")
    return getattr(importlib.import_module(module), cls)


def make_env(name: str, **kwargs: Any) -> Env:
    """Builds a registered task, e.g. ``make_env("tabletop/push_sphere", seed=0)``.

    Keyword arguments go to the environment class (``seed``, ``observation_size``, ...).
    """
    env, task = split_name(name)
    return env_class(env)(task=task, **kwargs)


def make_env_from_metadata(meta: dict[str, Any], **overrides: Any) -> Env:
    """Rebuilds an environment from :meth:`Env.serialize` output (datasets, task suites)."""
    try:
        name, kwargs = meta["name"], dict(meta.get("kwargs", {}))
    except (KeyError, TypeError) as exc:
        raise ValueError(
            f"env metadata must be a dict with 'name' and 'kwargs' (from Env.serialize()); got {meta!r}"
        ) from exc
    kwargs.update(overrides)
    return make_env(name, **kwargs)


__all__ = ["env_class", "make_env", "make_env_from_metadata"]
