"""Scripted policies: privileged controllers that solve a task from the simulator state.

They generate the training data (with noise, :class:`NoisyPolicy`) and the goals of the task
suite (without noise). A policy reads the environment's simulator state directly; it never
looks at images.

Life cycle, driven by the collector::

    obs, _ = env.reset(seed=s)
    policy = make_policy(env, rng)   # or policy.reset() after a new env.reset()
    for _ in range(35):
        env.step(policy.act())
"""

from __future__ import annotations

import abc
from collections.abc import Sequence

import numpy as np

from vp2.envs.base import Env


class ScriptedPolicy(abc.ABC):
    """A deterministic-given-its-generator controller for one task.

    Args:
        env: the environment it acts in (it reads the env's simulator state).
        rng: the generator for every random choice the policy makes (target object,
            direction, ...). Policies never touch global random state.
    """

    def __init__(self, env: Env, rng: np.random.Generator):
        self.env = env
        self.rng = rng

    @abc.abstractmethod
    def reset(self) -> None:
        """Called after every ``env.reset``/``reset_to``: draw this episode's plan."""

    @abc.abstractmethod
    def act(self) -> np.ndarray:
        """The noise-free action for the env's current state, shape ``(action_dim,)``, in [-1, 1]."""

    def goal_state(self) -> np.ndarray | None:
        """The state this episode aims for, for goal-relative success criteria (tabletop
        pushing: the pushed object at its target, the others in place). ``None`` for tasks
        whose criterion needs no goal. Valid after :meth:`reset`."""
        return None

    def bound(self, action: np.ndarray) -> np.ndarray:
        """Applied to the final action, after any noise (default: unchanged). A policy whose
        script limits where the hand may go (the tabletop's) overrides it."""
        return action

    def keeps(self, states: np.ndarray) -> bool:
        """Whether the data collection keeps an episode that went through ``states`` (``(T+1,
        S)``; default: always). The tabletop's script keeps only the pushes its original kept."""
        return True


#: Action-noise σ of the training data (SPEC §3). Tabletop: 0.05 on every action dimension but
#: the gripper. RoboDesk: 0.1 on even and 0.2 on odd trajectories of a stream (half and half).
TABLETOP_NOISE = (0.05, 0.05, 0.05, 0.0)
ROBODESK_NOISE = (0.1, 0.2)


class NoisyPolicy(ScriptedPolicy):
    """Adds independent Gaussian noise to a scripted policy's actions, then clips to [-1, 1].

    Args:
        policy: the noise-free policy.
        sigma: noise standard deviation per action dimension (a scalar applies to all);
            a zero entry leaves that dimension untouched (e.g. the tabletop gripper).
        rng: the generator of the noise (separate from the policy's so noise level changes
            do not change the policy's plan).
    """

    def __init__(self, policy: ScriptedPolicy, sigma: float | Sequence[float], rng: np.random.Generator):
        super().__init__(policy.env, rng)
        self.policy = policy
        sigma_arr = np.broadcast_to(np.asarray(sigma, np.float64), (policy.env.action_dim,))
        if np.any(sigma_arr < 0) or not np.all(np.isfinite(sigma_arr)):
            raise ValueError(f"noise sigma must be finite and >= 0, got {sigma_arr.tolist()}")
        self.sigma = sigma_arr.copy()

    def reset(self) -> None:
        self.policy.reset()

    def goal_state(self) -> np.ndarray | None:
        return self.policy.goal_state()

    def keeps(self, states: np.ndarray) -> bool:
        return self.policy.keeps(states)

    def act(self) -> np.ndarray:
        action = self.policy.act()
        noise = self.rng.standard_normal(action.shape) * self.sigma
        return self.policy.bound(np.clip(action + noise, -1.0, 1.0))
