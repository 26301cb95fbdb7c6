"""The 11 tasks as Gymnasium environments: ``gymnasium.make("vp2/RoboDesk-PushRed-v0")``.

Ids are ``vp2/<Env>-<Task>-v0``, the task name in CamelCase (docs/envs.md lists them all)::

    import gymnasium
    import vp2  # registers the ids (importing vp2.envs is enough)

    env = gymnasium.make("vp2/Tabletop-PushSphere-v0", seed=0, observation_size=64)
    obs, info = env.reset(seed=1)  # obs: uint8 (64, 64, 3)

Keyword arguments go to the environment class as with :func:`vp2.envs.make_env` (``seed``,
``observation_size``); ``render_mode`` may be ``None`` or ``"rgb_array"``. There is no time
limit (the benchmark's trials are 15 steps; ``gymnasium.make(..., max_episode_steps=15)``
adds one). ``observation_size=None`` is refused here: without observations the env is not a
Gymnasium env (use :func:`vp2.envs.make_env` for state-only work).
"""

from __future__ import annotations

from typing import Any

import gymnasium

from vp2.envs.base import Env
from vp2.envs.factory import make_env
from vp2.envs.tasks import TASK_NAMES, split_name

#: Gymnasium namespace of the vp2 ids.
NAMESPACE = "vp2"
#: Version suffix of every id; bumped when an environment's behaviour changes.
VERSION = 0
_ENV_TITLES: dict[str, str] = {"robodesk": "RoboDesk", "tabletop": "Tabletop"}


def gym_id(task: str) -> str:
    """``"robodesk/push_red"`` -> ``"vp2/RoboDesk-PushRed-v0"``."""
    env, name = split_name(task)
    camel = "".join(part.capitalize() for part in name.split("_"))
    return f"{NAMESPACE}/{_ENV_TITLES[env]}-{camel}-v{VERSION}"


#: Gymnasium id of every task, by vp2 task name.
GYM_IDS: dict[str, str] = {task: gym_id(task) for task in TASK_NAMES}


def make_gym_env(task: str, render_mode: str | None = None, **kwargs: Any) -> Env:
    """Gymnasium's entry point of every vp2 id: :func:`vp2.envs.make_env` plus ``render_mode``.

    Raises:
        ValueError: an unknown render mode, or ``observation_size=None``.
    """
    if render_mode not in (None, *Env.metadata["render_modes"]):
        raise ValueError(
            f"render_mode must be None or one of {Env.metadata['render_modes']}, got {render_mode!r}"
        )
    if "observation_size" in kwargs and kwargs["observation_size"] is None:
        raise ValueError(
            "observation_size=None gives no observations, which no Gymnasium space holds; "
            "use vp2.make_env(task, observation_size=None) for state-only work"
        )
    env = make_env(task, **kwargs)
    env.render_mode = render_mode
    return env


# gymnasium.make reads the render modes from the entry point.
make_gym_env.metadata = Env.metadata  # type: ignore[attr-defined]


def register_envs() -> None:
    """Registers the 11 ids with Gymnasium (idempotent; done when :mod:`vp2.envs` is imported)."""
    for task, env_id in GYM_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point=make_gym_env,
                kwargs={"task": task},
                disable_env_checker=False,
            )


__all__ = ["GYM_IDS", "NAMESPACE", "gym_id", "make_gym_env", "register_envs"]
