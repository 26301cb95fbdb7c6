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
(``gymnasium.make("vp2/RoboDesk-PushRed-v0")``, :mod:`vp2.envs.registration`). The tasks are
registered in :mod:`vp2.envs.tasks` (:data:`TASKS`: one :class:`Task` per category, with its
success rule, planner sample count, cost form, classifier and policy keys and suite share), the
constructors in :mod:`vp2.envs.factory`; this package re-exports both.
"""

from __future__ import annotations

import os

from vp2.envs.base import Env
from vp2.envs.factory import env_class, make_env, make_env_from_metadata
from vp2.envs.registration import GYM_IDS, register_envs
from vp2.envs.tasks import (
    ENV_NAMES,
    ENV_TASKS,
    ROBODESK_TASKS,
    TABLETOP_TASKS,
    TASK_NAMES,
    TASKS,
    Task,
    get_task,
    split_name,
)

# MuJoCo picks its GL backend when it is first imported, which may be by any env module (e.g.
# vp2.envs._ik), not only vp2.envs.rendering: default to EGL here, before any of them loads.
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

register_envs()

__all__ = [
    "ENV_NAMES",
    "GYM_IDS",
    "ENV_TASKS",
    "Env",
    "ROBODESK_TASKS",
    "TABLETOP_TASKS",
    "TASKS",
    "TASK_NAMES",
    "Task",
    "env_class",
    "get_task",
    "make_env",
    "make_env_from_metadata",
    "split_name",
]
