"""The data streams and the policy of each: which env a stream is collected in, its noise and
its scripted policy (re-exported by :mod:`vp2.data.policies`, whose docstring describes them).

The per-environment policy modules are imported only when a policy is made: RoboDesk's loads
MuJoCo and the tabletop's robosuite.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vp2.data.policies.base import ROBODESK_NOISE, TABLETOP_NOISE, NoisyPolicy, ScriptedPolicy
from vp2.envs import ROBODESK_TASKS, TABLETOP_TASKS, make_env, split_name
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


def make_task_policy(env: Env, rng: np.random.Generator) -> ScriptedPolicy:
    """The noise-free scripted policy that solves ``env``'s task category (for the task suite)."""
    env_name, task = split_name(env.name)
    if env_name == "robodesk":
        from vp2.data.policies.robodesk import make_robodesk_policy

        return make_robodesk_policy(env, rng)
    from vp2.data.policies.tabletop import make_tabletop_policy

    return make_tabletop_policy(env, rng, target_object=task.removeprefix("push_"))


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

