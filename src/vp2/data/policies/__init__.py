"""Scripted policies and the data streams they generate.

A *data stream* is what one scripted policy collects:

* ``robodesk/<task>``: the task's own scripted policy (7 streams). Noise σ = 0.1 on even and
  0.2 on odd trajectories of a stream (SPEC §3: half and half).
* ``tabletop/push_random_object``: push a random object in a random direction (SPEC §3);
  σ = 0.05 on every action dimension but the gripper. The tabletop task categories share
  one scene, so one stream serves all four.

For the task suite, :func:`make_task_policy` gives the noise-free policy that solves one
registered task category (tabletop: pushes that category's object; the suite starts its
instances at most 12 actions before the push succeeds, see :mod:`vp2.data.suite`).
"""

from vp2.data.policies.base import ROBODESK_NOISE, TABLETOP_NOISE, NoisyPolicy, ScriptedPolicy
from vp2.data.policies.registry import (
    TABLETOP_STREAM,
    data_noise_sigma,
    make_data_env,
    make_policy,
    make_task_policy,
    stream_names,
)

__all__ = [
    "NoisyPolicy",
    "ROBODESK_NOISE",
    "ScriptedPolicy",
    "TABLETOP_NOISE",
    "TABLETOP_STREAM",
    "data_noise_sigma",
    "make_data_env",
    "make_policy",
    "make_task_policy",
    "stream_names",
]
