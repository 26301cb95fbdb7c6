"""The scripted pushing policy of the tabletop environment (SPEC §3).

Each episode the policy picks an object (at random, or the one it is given: the task suite
pushes the task's own object), a direction ``theta`` uniform in ``[0, pi]`` -- the push moves the
object by ``push_distance * (cos theta, sin theta)`` in the table plane (world x points away from
the robot, y to its left) -- and a target that far away in that direction (0.3 m, SPEC §3, for
training data and the task suite alike). Directions are redrawn
until the target lies in the scene's ``placement.target_region`` (on the table, within the arm's reach) and, with
``clear_path`` (the default), until neither the pushed object nor the fingers sweep through
another object on the way (such a push cannot reach the goal, which keeps the other objects in
place). A proportional controller on the end-effector position then

1. moves to a point behind the object (opposite the push direction) at a safe height above
   every object (``approach``),
2. goes down to pushing height (``descend``),
3. pushes along the line from the object to its target, slowing down near the target, with a
   sideways correction that keeps the leading fingertip on the line through the object's centre
   (re-aimed every step, which steers a drifting object back); if the fingers slip past or off
   the object it starts again from 1 (``push``),
4. stops once the object is within :data:`DONE_TOLERANCE` of its target (``done``), resuming the
   push if the object drifts away again.

The gripper is commanded closed throughout, so the two fingers form one compact pusher.

Goal API: :meth:`TabletopPushPolicy.goal_positions` gives the object positions the episode aims
for (the pushed object at its target, the others where they started), and
:meth:`TabletopPushPolicy.goal_state` the same as a state vector (the episode's initial state
with those positions) that :meth:`vp2.envs.tabletop.TabletopEnv.is_success` and
:meth:`~vp2.envs.base.Env.set_goal` accept.

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
from vp2.envs.tabletop_scene import SceneObject
from vp2.utils.fixedmath import dot, matvec, norm

__all__ = [
    "DONE_TOLERANCE",
    "PUSH_DISTANCE",
    "TABLETOP_POLICIES",
    "TabletopPushPolicy",
    "make_tabletop_policy",
]

#: Distance the pushed object should travel (metres), SPEC §3.
PUSH_DISTANCE = 0.3
#: The push stops when the object is this close to its target (metres).
DONE_TOLERANCE = 0.012

# End-effector (grip site) heights above the table top: above every object (objects are at
# most 5 cm tall and the fingertips reach about 1 cm below the grip site), and low enough to
# push every object near its middle while keeping the fingertips off the table and the hand
# above the objects.
_SAFE_HEIGHT = 0.085
_PUSH_HEIGHT = 0.025
# Footprint of the closed fingers around the grip site at the height of the objects' middles
# (world x range, y range; metres): measured with mj_geomDistance between robosuite's Panda
# finger collision geoms and a sphere moved around them. The hand above the fingers starts
# _HAND_BOTTOM above the grip site, higher than any object when pushing at _PUSH_HEIGHT; its
# footprint matters only for objects taller than that.
_FINGERS_BOX = ((-0.009, 0.009), (-0.019, 0.019))
_HAND_BOX = ((-0.044, 0.019), (-0.100, 0.104))
_HAND_BOTTOM = 0.029
# The whole fingers' footprint (they widen above the objects' middles), for path clearance.
_SWEEP_BOX = ((-0.016, 0.010), (-0.027, 0.027))
# Free gap left between the gripper and the object while descending behind it (metres).
_APPROACH_GAP = 0.02
# Step the push phase asks for per control step (metres; the controller's output_max is a full
# action), and
# the gain of its sideways correction.
_PUSH_ADVANCE = 0.05
_LATERAL_GAIN = 1.5
_MISALIGNED = 0.03
# How far the contact point may drift off the push line before the push is restarted, beyond
# the object's own extent, and how sharply the leading point moves to a fingertip corner.
_SLIP_WIDTH = 0.025
_CORNER_SOFTNESS = 0.25
# Proportional gain times the controller's output_max: full action for a position error of
# 2/3 of output_max (the arm covers about 70% of a commanded step within the step).
_GAIN_TIMES_OUTPUT = 1.5
# Free space required between the sweep of a push and the other objects (metres).
_CLEARANCE = 0.02
_MAX_DIRECTION_DRAWS = 100
_MAX_OBJECT_DRAWS = 20


_DISK_NORMALS = np.array(
    [[math.cos(a), math.sin(a)] for a in np.linspace(0, 2 * np.pi, 72, endpoint=False).tolist()]
)
_AXIS_NORMALS = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


def _pusher_vertex(u: np.ndarray) -> np.ndarray:
    """Point of the closed fingers (relative to the grip site) that leads a push along ``u``.

    The centre of a face for axis-aligned pushes, a corner for diagonal ones, blended smoothly
    in between so that the aim does not jump when the direction wobbles.
    """
    (x0, x1), (y0, y1) = _FINGERS_BOX
    soft = [math.tanh(x / _CORNER_SOFTNESS) for x in np.asarray(u, np.float64).tolist()]
    return np.array(
        [(x0 + x1) / 2 + (x1 - x0) / 2 * soft[0], (y0 + y1) / 2 + (y1 - y0) / 2 * soft[1]]
    )


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance from point ``p`` to the segment ``[a, b]`` (2-D)."""
    ab = b - a
    t = float(np.clip(dot(p - a, ab) / max(dot(ab, ab), 1e-12), 0.0, 1.0))
    return norm(p - (a + t * ab))


def _box_support(
    box: tuple[tuple[float, float], tuple[float, float]], normals: np.ndarray
) -> np.ndarray:
    """Support function of an axis-aligned box (x range, y range) for rows of ``normals``."""
    (x0, x1), (y0, y1) = box
    nx, ny = normals[:, 0], normals[:, 1]
    return np.maximum(x0 * nx, x1 * nx) + np.maximum(y0 * ny, y1 * ny)


def _footprint(
    obj: SceneObject, quat: np.ndarray, radius: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Facet normals ``(n, 2)`` and support values ``(n,)`` of an object's horizontal section.

    ``radius`` overrides the radius of a round object's section (the sphere is narrower at the
    hand's height than at its equator).
    """
    size = obj.size
    if obj.shape != "box":
        r = size[0] if radius is None else radius
        return _DISK_NORMALS, np.full(len(_DISK_NORMALS), r)
    w, x, y, z = quat
    w, x, y, z = (float(q) for q in (w, x, y, z))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    c, s = math.cos(yaw), math.sin(yaw)
    normals = np.array([[c, s], [-c, -s], [-s, c], [s, -c]])
    return normals, np.full(4, size[0])


def _section_support(
    obj_normals: np.ndarray, obj_support: np.ndarray, normals: np.ndarray
) -> np.ndarray:
    """Support of a centrally symmetric section (from :func:`_footprint`) along ``normals``."""
    if len(obj_normals) == len(_DISK_NORMALS):
        return np.full(len(normals), obj_support[0])
    a = obj_support[0]  # a square of half side a; rows 0 and 2 are its two facet directions
    return a * (np.abs(matvec(normals, obj_normals[0])) + np.abs(matvec(normals, obj_normals[2])))


def _ray_cast(
    box: tuple[tuple[float, float], tuple[float, float]],
    section: tuple[np.ndarray, np.ndarray],
    u: np.ndarray,
) -> float:
    """Distance along ``u`` from the grip site to an object centre that just touches ``box``.

    Seen from the grip site, the object's centre touches the gripper part on the boundary of the
    Minkowski sum of the part's footprint and the object's section; the distance is a ray cast
    in that convex set, from its support function over the facet normals of both.
    """
    obj_normals, obj_support = section
    normals = np.concatenate([_AXIS_NORMALS, obj_normals])
    support = np.concatenate(
        [
            _box_support(box, _AXIS_NORMALS)
            + _section_support(obj_normals, obj_support, _AXIS_NORMALS),
            _box_support(box, obj_normals) + obj_support,
        ]
    )
    cos = matvec(normals, u)
    ahead = cos > 1e-9
    return float(np.min(support[ahead] / cos[ahead]))


def _contact_distance(
    obj: SceneObject, quat: np.ndarray, u: np.ndarray, z_push: float, table_z: float
) -> float:
    """Grip-site distance behind an object's centre (along ``u``) at which the gripper touches it
    when pushing with the grip site at height ``z_push`` over a table top at ``table_z``.

    The fingers meet the object's widest section; the hand, which starts ``_HAND_BOTTOM`` above
    the grip site, meets what of the object rises above that height. The first to touch wins.
    """
    dist = _ray_cast(_FINGERS_BOX, _footprint(obj, quat), u)
    hand_z = z_push + _HAND_BOTTOM - table_z  # hand bottom above the table
    if obj.height > hand_z:
        radius = None
        if obj.shape == "ball":
            r = obj.size[0]
            radius = math.sqrt(max(r * r - (hand_z - r) * (hand_z - r), 0.0))
        dist = max(dist, _ray_cast(_HAND_BOX, _footprint(obj, quat, radius), u))
    return dist


class TabletopPushPolicy(ScriptedPolicy):
    """Pushes one object ``push_distance`` in a random direction in ``[0, pi]`` (module docstring).

    Args:
        env: the tabletop environment (the policy reads its simulator state).
        rng: generator of the policy's choices (object and direction).
        target_object: index into :data:`~vp2.envs.tabletop.OBJECT_NAMES`, an object name, or
            ``None`` to draw one per episode.
        clear_path: only accept directions whose push leaves the other objects alone (see
            :meth:`_draw_direction`).
        push_distance: how far the object is pushed (metres).
    """

    def __init__(
        self,
        env: TabletopEnv,
        rng: np.random.Generator,
        target_object: int | str | None = None,
        clear_path: bool = True,
        push_distance: float = PUSH_DISTANCE,
    ):
        super().__init__(env, rng)
        scene = env.scene
        self.scene = scene
        self._table_z = scene.table.top_z
        self._z_safe = scene.table.top_z + _SAFE_HEIGHT
        self._z_push = scene.table.top_z + _PUSH_HEIGHT
        self._gain = _GAIN_TIMES_OUTPUT / scene.controller.output_max
        if not push_distance > 0:
            raise ValueError(f"push_distance must be positive (metres), got {push_distance}")
        self.clear_path = clear_path
        self.push_distance = float(push_distance)
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
        self.initial_quaternions = self.env.object_quaternions()
        for _ in range(_MAX_OBJECT_DRAWS):
            if self.fixed_object is None:
                self.object_index = int(self.rng.integers(len(OBJECT_NAMES)))
            else:
                self.object_index = self.fixed_object
            found = self._draw_direction()
            if found or self.fixed_object is not None:
                break
        self.phase = "approach"
        self._last_u = self.push_direction

    def _draw_direction(self) -> bool:
        """Draws ``theta`` until the push is feasible; False if no draw is.

        Feasible: the target lies in the scene's ``placement.target_region`` and, if ``clear_path``, neither the
        pushed object nor the gripper sweeps through another object on the way (those pushes
        cannot reach the policy's goal, which keeps the other objects in place). If no draw is
        feasible, the last on-region draw is kept, or the target is clipped into the region.
        """
        k = self.object_index
        start = self.initial_positions[k, :2]
        (x0, x1), (y0, y1) = self.scene.placement.target_region
        fallback = None
        for _ in range(_MAX_DIRECTION_DRAWS):
            theta = float(self.rng.uniform(0.0, np.pi))
            u = np.array([math.cos(theta), math.sin(theta)])
            target = start + self.push_distance * u
            if not (x0 <= target[0] <= x1 and y0 <= target[1] <= y1):
                continue
            if not self.clear_path or self._path_is_clear(k, start, target, u):
                self._set_target(theta, target)
                return True
            fallback = fallback or (theta, target)
        if fallback is None:
            fallback = (theta, np.clip(target, [x0, y0], [x1, y1]))
        self._set_target(*fallback)
        return False

    def _path_is_clear(self, k: int, start: np.ndarray, target: np.ndarray, u: np.ndarray) -> bool:
        """Whether pushing object ``k`` from ``start`` to ``target`` leaves the others alone."""
        obj = self.scene.objects[k]
        contact = _contact_distance(obj, self.initial_quaternions[k], u, self._z_push, self._table_z)
        side = np.array([-u[1], u[0]])
        gripper_start = start - (contact + _APPROACH_GAP) * u
        gripper_end = target - contact * u
        for j, other in enumerate(self.scene.objects):
            if j == k:
                continue
            p, r = self.initial_positions[j, :2], other.footprint
            if _segment_distance(p, start, target) < obj.footprint + r + _CLEARANCE:
                return False
            # The gripper sweeps a box; bound it by a capsule around its travel.
            tall = other.height > self._z_push + _HAND_BOTTOM - self._table_z
            box = _HAND_BOX if tall else _SWEEP_BOX
            normals = np.stack([u, -u, side, -side])
            front, back, left, right = _box_support(box, normals)
            if (
                _segment_distance(p, gripper_start - back * u, gripper_end + front * u)
                < max(left, right) + r + _CLEARANCE
            ):
                return False
        return True

    def _set_target(self, theta: float, target: np.ndarray) -> None:
        self.theta = theta
        self.target_xy = target
        self.push_direction = np.array([math.cos(theta), math.sin(theta)])

    # ---- goal --------------------------------------------------------------------------------
    def goal_positions(self) -> np.ndarray:
        """Object positions ``(4, 3)`` the episode aims for: the pushed one on its target."""
        goal = self.initial_positions.copy()
        goal[self.object_index, :2] = self.target_xy
        return goal

    def goal_state(self) -> np.ndarray:
        """:meth:`goal_positions` as a state vector for ``env.is_success`` / ``env.set_goal``."""
        return TabletopEnv.with_object_positions(self.initial_state, self.goal_positions())

    # ---- control -----------------------------------------------------------------------------
    def act(self) -> np.ndarray:
        """The noise-free action for the env's current state: ``(dx, dy, dz, gripper)``."""
        env: TabletopEnv = self.env  # type: ignore[assignment]
        k = self.object_index
        obj = env.object_positions()[k]
        ee = env.end_effector_position()
        to_target = self.target_xy - obj[:2]
        dist = norm(to_target)
        u = to_target / dist if dist > 1e-6 else self._last_u
        self._last_u = u
        normals, support = _footprint(self.scene.objects[k], env.object_quaternions()[k])
        # The object's extent towards the gripper, and the point of the gripper that should
        # touch it: a contact whose normal is the push direction (a fingertip corner for
        # diagonal pushes, since a flat face pushes along its own normal).
        reach = float(_section_support(normals, support, -u[None])[0])
        vertex = _pusher_vertex(u)
        touching = obj[:2] - reach * u - vertex  # grip site position when touching
        behind = touching - _APPROACH_GAP * u
        # The contact point relative to the object, along and across the push line.
        rel = ee[:2] + vertex - obj[:2]
        along = dot(rel, u)
        across_signed = float(rel[0] * u[1] - rel[1] * u[0])  # > 0: right of the line

        if self.phase == "done" and dist > 2 * DONE_TOLERANCE:
            self.phase = "push"
        if self.phase != "done" and dist < DONE_TOLERANCE:
            self.phase = "done"
        if self.phase == "push" and (
            along > -0.3 * reach or abs(across_signed) > reach + _SLIP_WIDTH
        ):
            # The gripper slipped past or off the object: go around again from above.
            self.phase = "approach"
        if self.phase == "approach" and norm(ee[:2] - behind) < 0.015:
            self.phase = "descend"
        if self.phase == "descend" and ee[2] < self._z_push + 0.01:
            self.phase = "push"

        if self.phase == "approach":
            # Rise first if low next to the object, so as not to sweep through it on the way.
            near = norm(ee[:2] - obj[:2]) < reach + 0.08
            low_and_near = ee[2] < self._z_safe - 0.03 and near
            desired = (
                np.array([ee[0], ee[1], self._z_safe]) if low_and_near else np.append(behind, self._z_safe)
            )
        elif self.phase == "descend":
            desired = np.append(behind, self._z_push)
        elif self.phase == "push":
            # Forward along the object->target line, slowing down as the object nears its
            # target, plus a sideways correction that brings the contact point back onto the
            # line through the object (which steers the object back towards the target). When
            # misaligned, slow down so that the correction wins before the object turns away.
            side = np.array([-u[1], u[0]])  # unit vector to the left of the line
            forward = min(dist, _PUSH_ADVANCE) * max(0.2, 1.0 - abs(across_signed) / _MISALIGNED)
            desired_xy = ee[:2] + forward * u + _LATERAL_GAIN * across_signed * side
            desired = np.append(desired_xy, self._z_push)
        else:
            desired = ee.copy()

        _, base_rot = env.base_frame()
        delta = matvec(base_rot.T, desired - ee)  # actions are expressed in the robot base frame
        action = np.empty(4)
        command = self._gain * delta
        # Scale (not clip per axis) so that a saturated command keeps its direction.
        action[:3] = command / max(1.0, float(np.max(np.abs(command))))
        action[3] = 1.0  # keep the gripper closed
        return action


def make_tabletop_policy(
    env: TabletopEnv,
    rng: np.random.Generator,
    target_object: int | str | None = None,
    clear_path: bool = True,
    push_distance: float = PUSH_DISTANCE,
) -> TabletopPushPolicy:
    """The noise-free pushing policy for ``env`` (call after ``env.reset``; see the module doc)."""
    return TabletopPushPolicy(
        env, rng, target_object=target_object, clear_path=clear_path, push_distance=push_distance
    )


#: ``factory(env, rng, target) -> policy`` by the policy key a tabletop
#: :class:`~vp2.envs.tasks.Task` names (``Task.policy``), given the object it pushes.
TabletopPolicyFactory = Callable[[TabletopEnv, np.random.Generator, Any], ScriptedPolicy]
TABLETOP_POLICIES: dict[str, TabletopPolicyFactory] = {
    "push_object": lambda env, rng, target: make_tabletop_policy(env, rng, target_object=target),
}
