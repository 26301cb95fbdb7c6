"""The benchmark's 11 task categories, ``"<env>/<task>"``: names only, no simulator.

The environment modules (:mod:`vp2.envs.robodesk`, :mod:`vp2.envs.tabletop`) take their task
lists from here, and :mod:`vp2.envs.factory` builds an environment from a name.
"""

from __future__ import annotations

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


__all__ = [
    "ENV_NAMES",
    "ENV_TASKS",
    "ROBODESK_TASKS",
    "TABLETOP_TASKS",
    "TASK_NAMES",
    "split_name",
]
