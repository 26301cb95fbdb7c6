"""Scripted policies of the seven RoboDesk tasks (SPEC §3).

Each policy is a small state machine over privileged simulator state (finger, button, handle and
object positions) that outputs the env's 5-D action: end-effector displacement, wrist rotation
rate, gripper opening. They generate the RoboDesk training data (with noise,
:func:`make_noisy_robodesk_policy`) and the goals of the task suite (without noise).

Facts about the RoboDesk arm that shape them (measured, see ``docs/robodesk.md``):

* the end effector moves about :data:`EE_SPEED` = 8.2 cm per env step per unit of action (the
  IK target leads the arm by 1 cm per repeat, the position servos lag behind it), so the
  controllers below are proportional controllers in metres divided by that speed;
* the IK is position-only: the gripper's pitch is whatever the arm's redundancy gives, and for
  most initial states the fingers point forward-down at about 45 degrees. The policies therefore
  steer a point on the fingers (not the ``end_effector`` site) and align only the wrist's yaw;
* close to the robot's base the elbow reaches its joint limit and the IK, which ignores limits,
  then drives the hand up and away. The policies keep clear of that region and, if the elbow
  gets there anyway, first move outwards (:meth:`RoboDeskPolicy._guard_elbow`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from vp2.data.policies.base import ROBODESK_NOISE, NoisyPolicy, ScriptedPolicy
from vp2.envs.base import Env
from vp2.envs.robodesk import TASKS, RoboDeskEnv
from vp2.envs.tasks import get_task
from vp2.utils.fixedmath import norm

#: End-effector displacement per env step for a unit action (m), measured on free motion.
EE_SPEED = 0.082
#: Wrist (joint 7) rotation per env step for a unit wrist action (rad), measured.
WRIST_SPEED = 0.64
#: Position of the shoulder joint (panda0_joint2) in the world: the arm folds around it.
SHOULDER = np.array([0.0, 0.1, 0.883])
#: Elbow (panda0_joint4) angle below which the arm is about to fold up (its limit is -3.07).
ELBOW_FOLDED = -2.93
#: Depth of the fingertip point along the fingers, from the finger bodies' origin (m).
FINGERTIP_DEPTH = 0.09
# Desk geometry (world frame), from the robodesk model.
DESK_FRONT_Y = 0.575  # front face of the desk top
DESK_TOP_Z = 0.76
DRAWER_WALL_TOP_Z = 0.705  # top edge of the drawer's front wall
OPEN = 1.0
CLOSED = -1.0


class RoboDeskPolicy(ScriptedPolicy):
    """Base class: geometry of the fingers and the motion primitives shared by the tasks.

    Args:
        env: a :class:`~vp2.envs.robodesk.RoboDeskEnv`.
        rng: draws each episode's small variations (approach heights, contact points) so
            that the dataset does not repeat one path per initial state.
    """

    def __init__(self, env: Env, rng: np.random.Generator):
        if not isinstance(env, RoboDeskEnv):
            raise TypeError(f"RoboDesk policies need a RoboDeskEnv, got {type(env).__name__}")
        super().__init__(env, rng)
        self.env: RoboDeskEnv = env
        self.phase = ""
        self.reset()

    # ---- geometry ------------------------------------------------------------------------
    def fingers(self, depth: float = FINGERTIP_DEPTH) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The point between the fingers ``depth`` along them, the opening axis, the pointing axis.

        ``depth`` 0.09 is the fingertips, 0.06 the middle of the finger pads.
        """
        left, rot = self.env.body_pose("panda0_leftfinger")
        right, _ = self.env.body_pose("panda0_rightfinger")
        pointing = rot[:, 2]
        return 0.5 * (left + right) + depth * pointing, rot[:, 1], pointing

    def wrist_toward(self, yaw: float) -> tuple[float, float]:
        """Wrist action turning the fingers' opening axis to ``yaw`` (mod pi) in the xy-plane.

        Returns ``(action, error)``; the error is in radians, in ``[-pi/2, pi/2)``.
        """
        _, opening, _ = self.fingers()
        error = (yaw - math.atan2(opening[1], opening[0]) + math.pi / 2) % math.pi - math.pi / 2
        # With the fingers pointing down, turning joint 7 by +1 rad turns the axis by -1 rad.
        return float(np.clip(-error / WRIST_SPEED, -1.0, 1.0)), error

    # ---- motion primitives ---------------------------------------------------------------
    @staticmethod
    def velocity(delta: np.ndarray, gain: float = 0.8) -> np.ndarray:
        """Action moving the end effector by ``delta`` (m): proportional, direction kept.

        The action is scaled down as a whole (not clipped per axis) so that the hand moves
        straight at the target, which keeps it off obstacles next to the straight line.
        """
        v = np.asarray(delta, dtype=np.float64) * (gain / EE_SPEED)
        length = norm(v)
        return v / length if length > 1.0 else v

    def toward(self, target: np.ndarray, point: np.ndarray, gain: float = 0.8) -> np.ndarray:
        """Action moving ``point`` (a point on the hand) to ``target``."""
        return self.velocity(np.asarray(target) - point, gain)

    def action(self, xyz: np.ndarray, wrist: float = 0.0, gripper: float = CLOSED) -> np.ndarray:
        """Assembles a 5-D action in ``[-1, 1]``."""
        return np.clip(np.array([xyz[0], xyz[1], xyz[2], wrist, gripper]), -1.0, 1.0)

    def _guard_elbow(self, xyz: np.ndarray) -> np.ndarray:
        """Replaces the motion by "away from the shoulder" while the elbow is nearly folded.

        Called in free-space phases only: in contact the fold is the task's own limit.
        """
        if self.env.data.qpos[3] >= ELBOW_FOLDED:
            return xyz
        ee = self.env.end_effector_pos
        out = ee - SHOULDER
        out[2] = 0.0
        out /= max(norm(out), 1e-6)
        return 0.5 * out + np.array([0.0, 0.0, float(np.clip((0.85 - ee[2]) * 5.0, -0.5, 0.5))])


class PushButtonPolicy(RoboDeskPolicy):
    """``push_<color>``: hover above the button with the gripper closed, then press it down.

    Args:
        env: the env.
        rng: per-episode variations: hover height and a millimetre-scale press offset.
        color: ``"red"``, ``"green"`` or ``"blue"``.
    """

    def __init__(self, env: Env, rng: np.random.Generator, color: str):
        if color not in ("red", "green", "blue"):
            raise ValueError(f"unknown button colour {color!r}")
        self.color = color
        super().__init__(env, rng)

    def reset(self) -> None:
        self.phase = "above"
        self.hover = self.rng.uniform(0.12, 0.18)
        self.offset = np.append(self.rng.uniform(-0.008, 0.008, size=2), 0.0)

    def act(self) -> np.ndarray:
        button = self.env.body_pos(f"{self.color}_button") + self.offset
        ee = self.env.end_effector_pos
        above = button + np.array([0.0, 0.0, self.hover])
        if self.phase == "above" and norm((ee - above)[:2]) < 0.02:
            self.phase = "press"
        # The site is ~5 cm above the fingertips: aiming it at the button presses it ~5 cm deep,
        # i.e. as far as it goes (the button travels 5 mm).
        target = above if self.phase == "above" else button
        xyz = self.toward(target, ee)
        if self.phase == "above":
            xyz = self._guard_elbow(xyz)
        return self.action(xyz, gripper=CLOSED)


class OpenSlidePolicy(RoboDeskPolicy):
    """``open_slide``: put the closed fingers left of the slide's handle, push it to the right.

    The handle is approached from the front at its height, then pushed along +x with a slight
    push into the panel (so the fingers stay on the handle) until the slide is open.
    """

    def reset(self) -> None:
        self.phase = "approach"
        self.left_of = self.rng.uniform(0.06, 0.09)
        self.height = self.rng.uniform(-0.035, -0.005)

    def act(self) -> np.ndarray:
        handle = self.env.site_pos("slide_handle")
        ee = self.env.end_effector_pos
        start = handle + np.array([-self.left_of, 0.0, self.height])
        if self.phase == "approach":
            target = start.copy()
            # Come in from the front, left of the handle, so as not to push it the wrong way.
            if ee[1] < handle[1] - 0.06 and abs(ee[0] - start[0]) > 0.03:
                target[1] = handle[1] - 0.12
            if norm(ee - start) < 0.03:
                self.phase = "push"
        if self.phase == "push":
            target = np.array([handle[0] + 0.3, handle[1] + 0.01, start[2]])
        xyz = self.toward(target, ee)
        if self.phase == "approach":
            xyz = self._guard_elbow(xyz)
        return self.action(xyz, gripper=CLOSED)


class OpenDrawerPolicy(RoboDeskPolicy):
    """``open_drawer``: hook the drawer with the fingertips and pull it towards the robot.

    The drawer is pulled by two hooks, whichever the drawer's opening allows:

    * ``wall``: once the drawer is open by more than ~9 cm, the fingertips fit between the
      desk's front edge and the drawer's front wall; they go down inside the drawer at
      ``x = 0.18`` (far from the shoulder, where the arm reaches furthest) and pull the
      wall's inner face;
    * ``bar``: otherwise the fingertips go down behind the handle bar (at ``x = 0.05``, the bar
      ends at 0.08) and pull it until the drawer is open enough for the wall hook.

    The wrist keeps the fingers' opening axis along x, so that the closed fingers present
    their thin side to the bar and the wall.

    Known limitation: this succeeds on only ~12% of the package's initial states. With the
    gripper pitched forward (most initial arm poses), the arm cannot reach close enough to its
    base to pull the bar far: the wall hook does the opening, and it only fits when the drawer
    starts open by more than ~8.5 cm. See docs/findings/environments.md.
    """

    # Drawer geometry at drawer joint q = 0 (world frame); everything moves with +q along y.
    BAR_Y = 0.49  # handle bar axis
    BAR_Z = 0.665
    WALL_INNER_Y = 0.61  # inner face of the drawer's front wall (outer face: 0.59)
    FINGER_HALF_THICKNESS = 0.02  # closed fingers, across the opening axis
    WALL_X = 0.18
    BAR_X = 0.05
    WALL_TIP_Z = 0.64
    BAR_TIP_Z = 0.645
    STAGE_Z = 0.76
    OPEN_FOR_WALL = -0.09  # drawer joint position from which the wall hook fits

    def reset(self) -> None:
        self.phase = "stage"
        self.mode = ""
        self.pull_speed = self.rng.uniform(0.5, 0.7)

    def act(self) -> np.ndarray:
        q = float(self.env.joint_qpos("drawer_joint")[0])
        tip, _, pointing = self.fingers()
        wrist, wrist_error = self.wrist_toward(0.0)
        # The fingers lean forward: points higher up the fingers are further back by `lean`.
        lean = pointing[1] / max(-pointing[2], 0.3)
        # Hysteresis: the wall hook keeps going while the pull wobbles the drawer a little.
        wall = q <= (self.OPEN_FOR_WALL + 0.03 if self.mode == "wall" else self.OPEN_FOR_WALL)
        mode = "wall" if wall else "bar"
        if self.mode and mode != self.mode:
            self.phase = "lift"
        self.mode = mode
        if mode == "wall":
            x, tip_z, press = self.WALL_X, self.WALL_TIP_Z, 0.05
            # The finger crosses the wall's top midway between the wall and the desk's edge.
            y_at_wall_top = 0.5 * (
                (self.WALL_INNER_Y + q + self.FINGER_HALF_THICKNESS)
                + (DESK_FRONT_Y - self.FINGER_HALF_THICKNESS)
            )

            def tip_y(z: float) -> float:
                return y_at_wall_top + (DRAWER_WALL_TOP_Z - z) * lean
        else:
            x, tip_z, press = self.BAR_X, self.BAR_TIP_Z, 0.03

            def tip_y(z: float) -> float:
                # 3 cm behind the bar where the finger crosses the bar's height, short of the
                # front wall's outer face.
                behind_bar = self.BAR_Y + q + 0.03 + max(self.BAR_Z - z, 0.0) * lean
                return min(behind_bar, self.WALL_INNER_Y - 0.04 + q)

        if self.phase == "lift":
            target = np.array([tip[0], tip[1], self.STAGE_Z])
            if tip[2] > self.STAGE_Z - 0.02:
                self.phase = "stage"
        if self.phase == "stage":
            target = np.array([x, tip_y(self.STAGE_Z), self.STAGE_Z])
            if mode == "bar" and tip[2] < self.STAGE_Z - 0.03:
                target = np.array([tip[0], tip[1], self.STAGE_Z])  # up first, then over
            if norm(target - tip) < 0.02 and abs(wrist_error) < 0.2:
                self.phase = "descend"
        if self.phase == "descend":
            target = np.array([x, tip_y(tip_z), tip_z])
            if abs(tip[2] - tip_z) < 0.012:
                self.phase = "pull"
        if self.phase == "pull":
            # Constant pull speed, proportional hold of x and of a height below the hook point
            # (the pressing keeps the fingertips from riding up over the edge).
            delta = np.array(
                [x - tip[0], -self.pull_speed * EE_SPEED / 0.8, tip_z - press - tip[2]]
            )
            xyz = self.velocity(delta)
        else:
            xyz = self.toward(target, tip)
        if self.phase in ("stage", "lift"):
            xyz = self._guard_elbow(xyz)
        return self.action(xyz, wrist=wrist, gripper=CLOSED)


class PushOffTablePolicy(RoboDeskPolicy):
    """``<object>_off_table``: push the object off the desk's right edge (+x).

    The fingers come down left of the object (from a height clear of the other objects), then
    push it along +x, holding the push line's y and the height. Pushing +x keeps the pushed
    object in its own lane: the flat block lies in front of the upright block (smaller y) and
    the ball is left of both, so neither is touched. The flat block is pushed behind its centre
    so that it turns away from the upright block, not towards it.

    Args:
        env: the env.
        rng: per-episode variations of the contact point.
        obj: ``"flat_block"`` or ``"upright_block"``.
    """

    #: Per object: half length along x, push height of the fingertips, clearance height above
    #: the desk for the approach, push line offset in y (from the object's centre), push speed
    #: (fraction of full speed).
    GEOMETRY = {
        "flat_block": dict(half_x=0.08, push_z=0.78, clear_z=0.90, dy=0.02, speed=1.0),
        "upright_block": dict(half_x=0.023, push_z=0.80, clear_z=1.00, dy=0.005, speed=0.8),
    }
    BACK_OFF = 0.045  # fingertip distance from the object's left face when starting the push

    def __init__(self, env: Env, rng: np.random.Generator, obj: str):
        if obj not in self.GEOMETRY:
            raise ValueError(
                f"no off-table policy for {obj!r}; objects: {', '.join(self.GEOMETRY)}"
            )
        self.obj = obj
        self.geometry = self.GEOMETRY[obj]
        super().__init__(env, rng)

    def reset(self) -> None:
        self.phase = "above"
        self.dy = self.geometry["dy"] + self.rng.uniform(-0.005, 0.005)
        self.dz = self.rng.uniform(-0.005, 0.005)

    def act(self) -> np.ndarray:
        g = self.geometry
        pos = self.env.body_pos(self.obj)
        tip, _, _ = self.fingers(0.085)
        wrist, wrist_error = self.wrist_toward(0.0)
        start = np.array(
            [pos[0] - g["half_x"] - self.BACK_OFF, pos[1] + self.dy, g["push_z"] + self.dz]
        )
        if self.phase == "above":
            target = np.array([start[0], start[1], g["clear_z"]])
            far = norm((target - tip)[:2]) > 0.05
            if far and tip[2] < g["clear_z"] - 0.05:
                target = np.array([tip[0], tip[1], g["clear_z"]])  # up before moving over
            if not far and norm((target - tip)[:2]) < 0.02 and abs(wrist_error) < 0.2:
                self.phase = "descend"
        if self.phase == "descend":
            target = start
            if abs(tip[2] - start[2]) < 0.01:
                self.phase = "push"
        if self.phase == "push":
            forward = g["speed"] * EE_SPEED / 0.8
            xyz = self.velocity(np.array([forward, start[1] - tip[1], start[2] - tip[2]]))
        else:
            xyz = self.toward(target, tip)
        if self.phase == "above":
            xyz = self._guard_elbow(xyz)
        return self.action(xyz, wrist=wrist, gripper=CLOSED)


#: ``factory(env, rng, target) -> policy`` by the policy key a RoboDesk task names
#: (``Task.policy`` of :data:`vp2.envs.tasks.TASKS`), given the task's ``target`` (button colour
#: or object).
ROBODESK_POLICIES: dict[str, Callable[[Env, np.random.Generator, Any], RoboDeskPolicy]] = {
    "push_button": lambda env, rng, target: PushButtonPolicy(env, rng, color=target),
    "open_slide": lambda env, rng, _: OpenSlidePolicy(env, rng),
    "open_drawer": lambda env, rng, _: OpenDrawerPolicy(env, rng),
    "push_off_table": lambda env, rng, target: PushOffTablePolicy(env, rng, obj=target),
}


def make_robodesk_policy(env: Env, rng: np.random.Generator) -> RoboDeskPolicy:
    """The noise-free scripted policy of ``env``'s task (its registry entry names it)."""
    if not isinstance(env, RoboDeskEnv):
        raise TypeError(f"make_robodesk_policy needs a RoboDeskEnv, got {type(env).__name__}")
    task = get_task(env.name)
    if task.policy not in ROBODESK_POLICIES:
        raise ValueError(f"no scripted policy for RoboDesk task {env.task!r}; tasks: {TASKS}")
    return ROBODESK_POLICIES[task.policy](env, rng, task.target)


def robodesk_noise_sigma(trajectory_index: int) -> float:
    """Action-noise σ of a data-collection trajectory: 0.1 for even, 0.2 for odd indices.

    SPEC §3: half of the RoboDesk trajectories of a task use σ = 0.1 and half σ = 0.2.
    """
    return ROBODESK_NOISE[trajectory_index % len(ROBODESK_NOISE)]


def make_noisy_robodesk_policy(
    env: Env, rng: np.random.Generator, noise_rng: np.random.Generator, trajectory_index: int
) -> NoisyPolicy:
    """The data-collection policy of trajectory ``trajectory_index`` of ``env``'s task.

    The scripted policy plus independent Gaussian noise on all five action dimensions, with
    σ from :func:`robodesk_noise_sigma`; actions are clipped to ``[-1, 1]``.
    """
    return NoisyPolicy(
        make_robodesk_policy(env, rng), robodesk_noise_sigma(trajectory_index), noise_rng
    )


__all__ = [
    "EE_SPEED",
    "OpenDrawerPolicy",
    "OpenSlidePolicy",
    "PushButtonPolicy",
    "PushOffTablePolicy",
    "ROBODESK_POLICIES",
    "RoboDeskPolicy",
    "make_noisy_robodesk_policy",
    "make_robodesk_policy",
    "robodesk_noise_sigma",
]
