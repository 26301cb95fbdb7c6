"""The benchmark's environments and the registry of its 11 task categories.

Names are ``"<env>/<task>"``::

    import vp2
    env = vp2.make_env("robodesk/push_red", seed=0)
    obs, info = env.reset(seed=1)

========  =================================================================================
env       tasks
========  =================================================================================
robodesk  push_red, push_green, push_blue, open_slide, open_drawer, flat_block_off_table,
          upright_block_off_table
tabletop  push_large_cube, push_small_cube, push_cylinder, push_sphere
========  =================================================================================

Every environment is also a Gymnasium environment, registered as ``vp2/<Env>-<Task>-v0``
(``gymnasium.make("vp2/RoboDesk-PushRed-v0")``, :mod:`vp2.envs.registration`).
"""

from __future__ import annotations

import importlib
import os
from typing import Any

from vp2.envs.base import Env

# MuJoCo picks its GL backend when it is first imported, which may be by any env module (e.g.
# vp2.envs._ik), not only vp2.envs.rendering: default to EGL here, before any of them loads.
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

ROBODESK_TASKS: tuple[str, ...] = (
    "push_red",
    "push_green",
    "push_blue",
    "open_slide",
    "open_drawer",
    "flat_block_off_table",
    "upright_block_off_table",
)
TABLETOP_TASKS: tuple[str, ...] = (
    "push_large_cube",
    "push_small_cube",
    "push_cylinder",
    "push_sphere",
)
_ENV_CLASSES: dict[str, str] = {
    "robodesk": "vp2.envs.robodesk:RoboDeskEnv",
    "tabletop": "vp2.envs.tabletop:TabletopEnv",
}
ENV_TASKS: dict[str, tuple[str, ...]] = {"robodesk": ROBODESK_TASKS, "tabletop": TABLETOP_TASKS}
ENV_NAMES: tuple[str, ...] = tuple(ENV_TASKS)
#: All 11 registered task categories, ``"<env>/<task>"``.
TASK_NAMES: tuple[str, ...] = tuple(f"{e}/{t}" for e, tasks in ENV_TASKS.items() for t in tasks)


def split_name(name: str) -> tuple[str, str]:
    """``"robodesk/push_red"`` -> ``("robodesk", "push_red")``, with a helpful error."""
    env, sep, task = name.partition("/")
    if not sep or env not in ENV_TASKS or task not in ENV_TASKS[env]:
        raise ValueError(
            f"unknown task {name!r}; registered tasks are: {', '.join(TASK_NAMES)}"
        )
    return env, task


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


from vp2.envs.registration import GYM_IDS, register_envs  # noqa: E402 (needs the names above)

register_envs()

__all__ = [
    "ENV_NAMES",
    "GYM_IDS",
    "ENV_TASKS",
    "Env",
    "ROBODESK_TASKS",
    "TABLETOP_TASKS",
    "TASK_NAMES",
    "env_class",
    "make_env",
    "make_env_from_metadata",
    "split_name",
]
