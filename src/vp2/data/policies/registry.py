"""The data streams and the policy of each: which env a stream is collected in, its noise and
its scripted policy (re-exported by :mod:`vp2.data.policies`, whose docstring describes them).

A task's scripted policy is the one its registry entry names (``Task.policy``, looked up in the
table of its environment's policy module). The per-environment policy modules are imported only
when a policy is made: RoboDesk's loads MuJoCo and the tabletop's robosuite.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from vp2.data.policies.base import ROBODESK_NOISE, TABLETOP_NOISE, NoisyPolicy, ScriptedPolicy
from vp2.envs import ROBODESK_TASKS, TABLETOP_TASKS, get_task, make_env, split_name
from vp2.envs.base import Env

TABLETOP_STREAM = "tabletop/push_random_object"
_DATA_STREAMS: dict[str, tuple[str, ...]] = {
    "robodesk": tuple(f"robodesk/{t}" for t in ROBODESK_TASKS),
    "tabletop": (TABLETOP_STREAM,),
}


def stream_names(env: str) -> tuple[str, ...]:
    """The data streams of an environment."""
    if env not in _DATA_STREAMS:
        raise ValueError(f"unknown environment {env!r}; known: {', '.join(_DATA_STREAMS)}")
    return _DATA_STREAMS[env]


def make_data_env(stream: str, **env_kwargs) -> Env:
    """The environment a data stream is collected in."""
    if stream == TABLETOP_STREAM:
        return make_env(f"tabletop/{TABLETOP_TASKS[0]}", **env_kwargs)
    return make_env(stream, **env_kwargs)


def data_noise_sigma(stream: str, stream_index: int) -> tuple[float, ...] | float:
    """Action-noise σ of trajectory ``stream_index`` of a stream (SPEC §3)."""
    if stream == TABLETOP_STREAM:
        return TABLETOP_NOISE
    split_name(stream)
    return ROBODESK_NOISE[stream_index % 2]


#: ``factory(env, rng, target) -> policy``: a task's scripted policy given the task's target.
PolicyFactory = Callable[[Env, np.random.Generator, Any], ScriptedPolicy]


def _robodesk_policies() -> Mapping[str, PolicyFactory]:
    from vp2.data.policies.robodesk import ROBODESK_POLICIES

    return ROBODESK_POLICIES


def _tabletop_policies() -> Mapping[str, PolicyFactory]:
    from vp2.data.policies.tabletop import TABLETOP_POLICIES

    return TABLETOP_POLICIES


#: Per environment, its table of scripted policies by the key a task names (``Task.policy``),
#: loaded on first use.
POLICY_TABLES: dict[str, Callable[[], Mapping[str, PolicyFactory]]] = {
    "robodesk": _robodesk_policies,
    "tabletop": _tabletop_policies,
}


def make_task_policy(env: Env, rng: np.random.Generator) -> ScriptedPolicy:
    """The noise-free scripted policy that solves ``env``'s task category (for the task suite):
    the policy its :class:`~vp2.envs.tasks.Task` names, aimed at the task's target."""
    task = get_task(env.name)
    table = POLICY_TABLES[task.env]()
    if task.policy not in table:
        raise ValueError(f"{task.name}: no scripted policy {task.policy!r} in the {task.env} table")
    return table[task.policy](env, rng, task.target)


def make_policy(
    env: Env,
    stream: str,
    rng: np.random.Generator,
    noise_rng: np.random.Generator,
    sigma: float | Sequence[float],
) -> ScriptedPolicy:
    """The (noisy) data-collection policy of a stream."""
    if stream == TABLETOP_STREAM:
        from vp2.data.policies.tabletop import make_tabletop_policy

        policy = make_tabletop_policy(env, rng, target_object=None)
    else:
        policy = make_task_policy(env, rng)
    if np.all(np.asarray(sigma) == 0):
        return policy
    return NoisyPolicy(policy, sigma, noise_rng)

