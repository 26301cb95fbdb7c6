"""The scripted pushing policy of the tabletop environment (SPEC §3): the original's.

The original release collected its tabletop data with a short open-loop-in-time script
(``collect_scripted_robosuite_trajectories.py`` of its robosuite fork); this is that script,
number for number, on our scene. Each episode it picks an object (at random, or the one it is
given: the task suite pushes the task's own object), ``theta`` uniform in ``[0, pi]`` and the
direction ``u = (sin theta, cos theta)`` in the table plane (world x points away from the robot,
so a push never comes towards it), and the target ``start + 0.3 u``, each coordinate clamped to
the scene's ``placement.target_region`` (±0.35 m). Then, at step ``k = 1, 2, ...`` of the
episode (one :meth:`~TabletopPushPolicy.act` per step):

* ``k <= 9``, approach: xy action ``5 (P - hand)``, with ``P`` the point 0.22 m behind the
  object on the line from the target through the object;
* ``k >= 10``, push: xy action ``3 (target - object)`` while the hand is strictly inside the
  ±0.35 m square (the action is otherwise zero; the noise remains);
* ``k = 2`` and ``k = 11 ... 15``, lowering: while the hand is above z = 0.85 the action is
  ``(0, 0, -0.75)`` instead (the original drew fresh noise for x and y there, which is what
  the data-collection noise adds to these zeros);
* z is otherwise 0 and the gripper action always 0;
* clipped to [-1, 1]; then an x or y component is zeroed when the hand already is at or beyond
  +0.35 m (-0.35 m) on that axis and the component is positive (negative) -- :meth:`bound`,
  which :class:`~vp2.data.policies.base.NoisyPolicy` applies after its noise, as the original
  did.

Object positions are the bodies' current positions, the hand the grip site, both in the world
frame; the robot's base is unrotated, so world deltas are base-frame actions.

Goal API: :meth:`TabletopPushPolicy.goal_positions` gives the object positions the episode aims
for (the pushed object at its target, the others where they started), and
:meth:`TabletopPushPolicy.goal_state` the same as a state vector (the episode's initial state
with those positions) that :meth:`vp2.envs.tabletop.TabletopEnv.is_success` and
:meth:`~vp2.envs.base.Env.set_goal` accept. The original used no such goal: its task goals are
the states its pushes ended in.

Training data adds Gaussian noise (σ = 0.05 on x, y, z; none on the gripper) by wrapping the
policy in :class:`~vp2.data.policies.base.NoisyPolicy` (``vp2.data.policies.make_policy`` with
``TABLETOP_NOISE``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from vp2.data.policies.base import ScriptedPolicy
from vp2.envs.tabletop import OBJECT_NAMES, TabletopEnv
from vp2.utils.fixedmath import norm

__all__ = [
    "APPROACH_STEPS",
    "LOWER_STEPS",
    "PUSH_DISTANCE",
    "TABLETOP_POLICIES",
    "TabletopPushPolicy",
    "make_tabletop_policy",
]

#: Distance from the object's start to its target (metres), SPEC §3.
PUSH_DISTANCE = 0.3
#: Steps ``1 .. APPROACH_STEPS`` approach the point behind the object; later steps push.
APPROACH_STEPS = 9
#: Steps at which the hand is lowered while above :data:`_LOWER_ABOVE_Z`.
LOWER_STEPS = (2, 11, 12, 13, 14, 15)
# The original's gains and distances.
_BEHIND = 0.22  # P lies this far behind the object (metres)
_APPROACH_GAIN = 5.0
_PUSH_GAIN = 3.0
_LOWER_ACTION = -0.75
_LOWER_ABOVE_Z = 0.85  # world z of the grip site above which the hand is lowered


#: The original's keep filter (SPEC §3, its ``filter_object_motion``): an episode is kept when
#: an object moved more than this in the table plane between its first and last state (metres;
#: the sphere counts only when it is the pushed object) ...
KEEP_MOTION = 0.08
#: ... and no object fell off the table (its height changed by more than this, metres).
FELL_OFF = 0.5


def keeps_push(start: np.ndarray, end: np.ndarray, pushed: int) -> bool:
    """The original's keep filter on an episode's first and last object positions ``(4, 3)``."""
    if np.abs(end[:, 2] - start[:, 2]).max() > FELL_OFF:
        return False
    counted = [k for k in range(len(OBJECT_NAMES)) if OBJECT_NAMES[k] != "sphere" or k == pushed]
    return max(norm(end[k, :2] - start[k, :2]) for k in counted) > KEEP_MOTION


class TabletopPushPolicy(ScriptedPolicy):
    """The original's pushing script (module docstring).

    Args:
        env: the tabletop environment (the policy reads its simulator state).
        rng: generator of the policy's choices (object and direction).
        target_object: index into :data:`~vp2.envs.tabletop.OBJECT_NAMES`, an object name, or
            ``None`` to draw one per episode.
    """

    def __init__(
        self, env: TabletopEnv, rng: np.random.Generator, target_object: int | str | None = None
    ):
        super().__init__(env, rng)
        self.scene = env.scene
        (self._x0, self._x1), (self._y0, self._y1) = self.scene.placement.target_region
        if isinstance(target_object, str):
            if target_object not in OBJECT_NAMES:
                raise ValueError(f"unknown object {target_object!r}; objects: {OBJECT_NAMES}")
            target_object = OBJECT_NAMES.index(target_object)
        if target_object is not None and not 0 <= int(target_object) < len(OBJECT_NAMES):
            raise ValueError(
                f"target_object must be in [0, {len(OBJECT_NAMES)}), got {target_object}"
            )
        self.fixed_object = None if target_object is None else int(target_object)
        self.reset()

    # ---- episode plan ------------------------------------------------------------------------
    def reset(self) -> None:
        """Draws this episode's object, direction and target from the env's current state."""
        self.initial_state = self.env.get_state()
        self.initial_positions = self.env.object_positions()
        if self.fixed_object is None:
            self.object_index = int(self.rng.integers(len(OBJECT_NAMES)))
        else:
            self.object_index = self.fixed_object
        self.theta = float(self.rng.uniform(0.0, np.pi))
        self.push_direction = np.array([math.sin(self.theta), math.cos(self.theta)])
        start = self.initial_positions[self.object_index, :2]
        self.target_xy = np.clip(
            start + PUSH_DISTANCE * self.push_direction, [self._x0, self._y0], [self._x1, self._y1]
        )
        self.step_count = 0

    # ---- goal --------------------------------------------------------------------------------
    def goal_positions(self) -> np.ndarray:
        """Object positions ``(4, 3)`` the episode aims for: the pushed one on its target."""
        goal = self.initial_positions.copy()
        goal[self.object_index, :2] = self.target_xy
        return goal

    def goal_state(self) -> np.ndarray:
        """:meth:`goal_positions` as a state vector for ``env.is_success`` / ``env.set_goal``."""
        return TabletopEnv.with_object_positions(self.initial_state, self.goal_positions())

    def keeps(self, states: np.ndarray) -> bool:
        """The original's keep filter (:func:`keeps_push`) on the episode's first and last state."""
        positions = TabletopEnv.object_positions_from_state
        return keeps_push(positions(states[0]), positions(states[-1]), self.object_index)

    # ---- control -----------------------------------------------------------------------------
    def act(self) -> np.ndarray:
        """The noise-free action of the episode's next step: ``(dx, dy, dz, gripper)``."""
        env: TabletopEnv = self.env  # type: ignore[assignment]
        self.step_count += 1
        k = self.step_count
        obj = env.object_positions()[self.object_index, :2]
        hand = env.end_effector_position()
        action = np.zeros(4)
        if k in LOWER_STEPS and hand[2] > _LOWER_ABOVE_Z:
            action[2] = _LOWER_ACTION
        elif k <= APPROACH_STEPS:
            away = obj - self.target_xy
            behind = obj + _BEHIND * away / max(norm(away), 1e-12)
            action[:2] = _APPROACH_GAIN * (behind - hand[:2])
        elif self._x0 < hand[0] < self._x1 and self._y0 < hand[1] < self._y1:
            action[:2] = _PUSH_GAIN * (self.target_xy - obj)
        return self.bound(np.clip(action, -1.0, 1.0))

    def bound(self, action: np.ndarray) -> np.ndarray:
        """Zeroes an x or y component that would move a hand at or beyond ±0.35 m further out."""
        hand = self.env.end_effector_position()  # type: ignore[attr-defined]
        action = np.array(action, np.float64)
        for axis, (lo, hi) in enumerate(((self._x0, self._x1), (self._y0, self._y1))):
            if (hand[axis] >= hi and action[axis] > 0) or (hand[axis] <= lo and action[axis] < 0):
                action[axis] = 0.0
        return action


def make_tabletop_policy(
    env: TabletopEnv, rng: np.random.Generator, target_object: int | str | None = None
) -> TabletopPushPolicy:
    """The noise-free pushing policy for ``env`` (call after ``env.reset``; see the module doc)."""
    return TabletopPushPolicy(env, rng, target_object=target_object)


#: ``factory(env, rng, target) -> policy`` by the policy key a tabletop
#: :class:`~vp2.envs.tasks.Task` names (``Task.policy``), given the object it pushes.
TabletopPolicyFactory = Callable[[TabletopEnv, np.random.Generator, Any], ScriptedPolicy]
TABLETOP_POLICIES: dict[str, TabletopPolicyFactory] = {
    "push_object": lambda env, rng, target: make_tabletop_policy(env, rng, target_object=target),
}
