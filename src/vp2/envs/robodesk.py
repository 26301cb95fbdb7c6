"""RoboDesk: a Franka Panda at a desk with a drawer, a slide, three buttons and three objects.

The benchmark's seven RoboDesk task categories (SPEC §1.1) on the ``robodesk`` package's MuJoCo
assets, simulated with ``mujoco`` directly. The dynamics are those of
``robodesk.RoboDesk(action_repeat=50)`` -- bit-identical, see ``docs/robodesk.md`` and
``benchmarks/fidelity/robodesk_equivalence.py`` -- at a fraction of its cost:

* one env step = 50 action repeats; each repeat solves IK for the end-effector target
  ``site position + 0.01 * action[:3]`` (:class:`vp2.envs._ik.SitePositionIK`, the same
  algorithm as dm_control's ``qpos_from_site_pose`` without its collision detection), sets the
  wrist and gripper targets as the package does, then runs 10 physics steps with gravity
  compensation (``qfrc_applied = qfrc_bias`` on the 9 robot dofs);
* physics steps use dm_control's "legacy" order (``mj_step2`` then ``mj_step1``), so that the
  position-dependent quantities read between steps (``qfrc_bias``, the site position) are those
  of the current state, exactly as in the package;
* the success criterion is judged once per env step, on the state after it, not at every repeat.

Bugs of the package fixed here (SPEC §1.1): the original object positions used by the "did not
move" checks are copied (the package keeps views of live data, so those checks always passed),
and images are resized with ``Image.Resampling.LANCZOS`` (``Image.ANTIALIAS`` was removed from
Pillow). The package's ``qpos_objects`` observation (which returns velocities) has no counterpart:
the env exposes the simulator state instead.

State vector (:meth:`RoboDeskEnv.get_state`): MuJoCo's ``mjSTATE_INTEGRATION`` state (time,
qpos, qvel, act, the constraint solver's warm start, ctrl, applied forces, ...), followed by the
positions of the three objects at reset (9 numbers) that the off-table tasks compare against.

The physics and render-only models and the camera's :data:`RENDER_SPEC` are built in
:mod:`vp2.envs._robodesk_model`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np

from vp2.envs._ik import MINDIAG as IK_MINDIAG
from vp2.envs._ik import SitePositionIK
from vp2.envs._robodesk_kernel import simulate_step
from vp2.envs._robodesk_model import RENDER_SPEC, load_model, load_render_model
from vp2.envs.base import Env
from vp2.envs.rendering import Renderer
from vp2.envs.tasks import ROBODESK_TASKS, Task, get_task

#: The seven task categories (:data:`vp2.envs.tasks.ROBODESK_TASKS`).
TASKS: tuple[str, ...] = ROBODESK_TASKS
#: The movable objects, in the order their reset positions appear in the state vector.
OBJECTS: tuple[str, ...] = ("ball", "upright_block", "flat_block")

ACTION_DIM = 5
ACTION_REPEAT = 50
PHYSICS_STEPS_PER_REPEAT = 10
END_EFFECTOR_SCALE = 0.01  # metres of end-effector target motion per unit action per repeat
WRIST_SCALE = 0.02
NUM_ROBOT_JOINTS = 9  # 7 arm joints + 2 fingers; the first 9 qpos/dofs/actuators
IK_JOINTS = tuple(f"panda0_joint{i}" for i in range(1, 7))
# Success thresholds of the package's task functions.
BUTTON_PRESSED_BELOW = -0.00453  # light joint position
SLIDE_OPEN_ABOVE = 0.55
DRAWER_OPEN_BELOW = -0.2
OFF_TABLE_BELOW = 0.6  # object height (m)
DID_NOT_MOVE_WITHIN = 0.01  # m, for the objects that must stay put
#: The paper's success-classifier label (SPEC §6): the package's dense reward summed over an
#: env step's 50 action repeats is at least this (a mean dense reward >= 0.6).
DENSE_LABEL_THRESHOLD = 30.0
# Initial-state distribution of the package (``RoboDesk.reset``).
INIT_ROBOT_QPOS = np.array([-0.30, -0.4, 0.28, -2.5, 0.13, 1.87, 0.91, 0.01, 0.01])
INIT_ROBOT_NOISE = 0.15  # times a uniform draw over each actuator's control range
# Norms of 3-vectors with MuJoCo's compiled arithmetic: np.linalg.norm / ndarray.dot go through
# OpenBLAS, whose kernel (and so the last bit) depends on the CPU.
_norm3 = mujoco.mju_norm3


class RoboDeskEnv(Env):
    """One RoboDesk task category.

    Args:
        task: one of :data:`TASKS`.
        seed: seed of the env's generator (initial states drawn by ``reset()`` without a seed).
        observation_size: side of the square RGB observation returned by ``reset``/``step``;
            ``None`` renders nothing (data collection that re-renders later, planning with
            the simulator oracle).

    Actions are 5-D in ``[-1, 1]``: end-effector target displacement ``(dx, dy, dz)`` of
    ``0.01 m`` per unit per action repeat, wrist rotation rate, gripper opening (``-1``
    closed, ``1`` open). Out-of-range actions are clipped (the package does not clip; with
    actions in the box the two agree).
    """

    action_dim = ACTION_DIM

    def __init__(self, task: str, seed: int | None = None, observation_size: int | None = 64):
        if task not in TASKS:
            raise ValueError(f"unknown RoboDesk task {task!r}; tasks are: {', '.join(TASKS)}")
        if observation_size is not None and (
            not isinstance(observation_size, (int, np.integer)) or observation_size <= 0
        ):
            raise ValueError(
                f"observation_size must be a positive int or None, got {observation_size!r}"
            )
        self.task = task
        self.name = f"robodesk/{task}"
        self.observation_size = None if observation_size is None else int(observation_size)
        self._seed = seed
        self._rng = np.random.default_rng(seed)
        self._goal_state: np.ndarray | None = None

        self.model = load_model()
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._ik = SitePositionIK(m, "end_effector", IK_JOINTS)
        self._ee_site = self._id(mujoco.mjtObj.mjOBJ_SITE, "end_effector")
        self._ee_xpos = self.data.site_xpos[self._ee_site]  # live view
        self._ctrlrange = m.actuator_ctrlrange.copy()
        self._object_bodies = [self._id(mujoco.mjtObj.mjOBJ_BODY, name) for name in OBJECTS]
        self._object_qadr = [
            int(m.jnt_qposadr[self._id(mujoco.mjtObj.mjOBJ_JOINT, name)]) for name in OBJECTS
        ]
        self._integration_size = mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_INTEGRATION)
        #: Length of the state vector.
        self.state_size = self._integration_size + 3 * len(OBJECTS)
        self._original_pos = np.zeros((len(OBJECTS), 3))
        registered = get_task(self.name)
        self._success_fn = self._make_success_fn(registered)
        self._dense_fn = self._make_dense_reward_fn(registered)
        #: When true, ``step`` sums the package's dense reward over its 50 action repeats into
        #: ``info["dense_reward"]`` (data collection for the classifiers' paper label; off by
        #: default to keep the planner's step lean).
        self.track_dense_reward = False
        # Views used on every physics step, created once (indexing costs microseconds, and a
        # step makes 500 of them).
        self._qfrc_applied = self.data.qfrc_applied[:NUM_ROBOT_JOINTS]
        self._qfrc_bias = self.data.qfrc_bias[:NUM_ROBOT_JOINTS]
        self._ctrl = self.data.ctrl[:NUM_ROBOT_JOINTS]
        self._target = np.empty(NUM_ROBOT_JOINTS)
        self._kernel = self._kernel_arguments()
        self._renderer: Renderer | None = None
        self._warnings_seen = self._warning_count()
        self.reset()

    def _kernel_arguments(self) -> tuple[Any, ...]:
        """The leading arguments of :func:`simulate_step`: addresses, views, the IK's settings
        and its scratch arrays (made once; the views follow the data)."""
        ik, m = self._ik, self.model
        n = len(IK_JOINTS)
        return (
            m._address, self.data._address, ik.data._address,
            self.data.qpos, self.data.site_xpos, ik.data.qpos, ik.data.site_xpos, ik.site_id,
            ik.dofs, ik.qpos_addresses, ik.tol, ik.regularization_threshold,
            ik.regularization_strength, ik.max_update_norm, ik.progress_thresh, ik.max_steps,
            IK_MINDIAG, np.empty((3, m.nv)), np.empty((3, n)), np.empty((3, 3)), np.empty(3),
            np.empty(3), np.empty(n), self._qfrc_applied, self._qfrc_bias, self._ctrl,
        )  # fmt: skip

    # ---- privileged state (for scripted policies and tests) --------------------------------
    def _id(self, kind: mujoco.mjtObj, name: str) -> int:
        i = mujoco.mj_name2id(self.model, kind, name)
        if i < 0:
            raise KeyError(f"no {kind.name[6:].lower()} named {name!r} in the RoboDesk model")
        return i

    @property
    def end_effector_pos(self) -> np.ndarray:
        """Position of the ``end_effector`` site (between the fingertips), a copy."""
        return self._ee_xpos.copy()

    def body_pos(self, name: str) -> np.ndarray:
        """World position of a body (e.g. ``"red_button"``, ``"flat_block"``), a copy."""
        return self.data.xpos[self._id(mujoco.mjtObj.mjOBJ_BODY, name)].copy()

    def site_pos(self, name: str) -> np.ndarray:
        """World position of a site (``"end_effector"``, ``"slide_handle"``), a copy."""
        return self.data.site_xpos[self._id(mujoco.mjtObj.mjOBJ_SITE, name)].copy()

    def geom_pos(self, name: str) -> np.ndarray:
        """World position of a named geom (e.g. ``"drawer_handle"``), a copy."""
        return self.data.geom_xpos[self._id(mujoco.mjtObj.mjOBJ_GEOM, name)].copy()

    def body_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """World position and ``(3, 3)`` rotation matrix of a body (e.g. a finger), copies."""
        i = self._id(mujoco.mjtObj.mjOBJ_BODY, name)
        return self.data.xpos[i].copy(), self.data.xmat[i].reshape(3, 3).copy()

    def joint_qpos(self, name: str) -> np.ndarray:
        """The ``qpos`` entries of a joint (1 for hinge/slide, 7 for free joints), a copy."""
        jid = self._id(mujoco.mjtObj.mjOBJ_JOINT, name)
        start = int(self.model.jnt_qposadr[jid])
        size = {0: 7, 1: 4}.get(int(self.model.jnt_type[jid]), 1)
        return self.data.qpos[start : start + size].copy()

    @property
    def original_object_positions(self) -> dict[str, np.ndarray]:
        """Positions of the objects at reset (what the "did not move" checks compare to)."""
        return {name: self._original_pos[i].copy() for i, name in enumerate(OBJECTS)}

    # ---- lifecycle -------------------------------------------------------------------------
    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray | None, dict[str, Any]]:
        """Draws an initial state from the package's distribution (see ``RoboDesk.reset``).

        The drawer is opened by ``U(0, 0.1)`` m, the slide by ``U(0, 0.2)`` m, the three objects
        are shifted in x/y within their boxes, and the robot's joints are perturbed by
        ``0.15 * U(ctrl range)``. The uniform draws come from the env's generator, in the
        package's order.
        """
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        rng, m, d = self._rng, self.model, self.data
        mujoco.mj_resetData(m, d)
        qpos = d.qpos
        qpos[self._qadr("drawer_joint")] -= 0.10 * rng.random()
        qpos[self._qadr("slide_joint")] += 0.20 * rng.random()
        flat, ball, upright = (self._qadr(n) for n in ("flat_block", "ball", "upright_block"))
        qpos[flat] += 0.3 * rng.random()
        qpos[flat + 1] += 0.07 * rng.random()
        qpos[ball] += 0.48 * rng.random()
        qpos[ball + 1] += 0.08 * rng.random()
        qpos[upright] += 0.3 * rng.random() + 0.05
        qpos[upright + 1] += 0.05 * rng.random()
        low, high = self._ctrlrange[:NUM_ROBOT_JOINTS].T
        qpos[:NUM_ROBOT_JOINTS] = INIT_ROBOT_QPOS + INIT_ROBOT_NOISE * rng.uniform(low, high)
        d.qvel[:NUM_ROBOT_JOINTS] = 0.0
        mujoco.mj_forward(m, d)
        for i, body in enumerate(self._object_bodies):
            self._original_pos[i] = d.xpos[body]  # a copy (the package kept a view: its bug)
        self._warnings_seen = self._warning_count()
        return self._observation(), {"success": self.is_success(self._goal_state)}

    def _qadr(self, joint: str) -> int:
        return int(self.model.jnt_qposadr[self._id(mujoco.mjtObj.mjOBJ_JOINT, joint)])

    def get_state(self) -> np.ndarray:
        state = np.empty(self.state_size)
        mujoco.mj_getState(
            self.model,
            self.data,
            state[: self._integration_size],
            mujoco.mjtState.mjSTATE_INTEGRATION,
        )
        state[self._integration_size :] = self._original_pos.ravel()
        return state

    def reset_to(self, state: np.ndarray) -> np.ndarray | None:
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (self.state_size,):
            raise ValueError(
                f"{self.name}: state must have shape ({self.state_size},), got {state.shape}; "
                "pass a vector from get_state() of a RoboDesk env"
            )
        if not np.all(np.isfinite(state)):
            raise ValueError(f"{self.name}: state contains NaN or inf")
        mujoco.mj_setState(
            self.model,
            self.data,
            np.ascontiguousarray(state[: self._integration_size]),
            mujoco.mjtState.mjSTATE_INTEGRATION,
        )
        self._original_pos[:] = state[self._integration_size :].reshape(len(OBJECTS), 3)
        # After a (legacy) step, everything that depends on position and velocity is current;
        # mj_forward restores that. The IK copy needs nothing: it is synced from qpos on use.
        mujoco.mj_forward(self.model, self.data)
        self._warnings_seen = self._warning_count()
        return self._observation()

    def step(
        self, action: np.ndarray
    ) -> tuple[np.ndarray | None, float, bool, bool, dict[str, Any]]:
        action = self.check_action(action)
        dense = self._simulate(action)
        success = self.is_success(self._goal_state)
        info: dict[str, Any] = {"success": success}
        if dense is not None:
            info["dense_reward"] = dense
        return self._observation(), float(success), False, False, info

    def _simulate(self, action: np.ndarray) -> float | None:
        """The package's ``RoboDesk.step`` dynamics, one env step = 50 repeats.

        Returns the dense reward summed over the repeats if ``track_dense_reward``, else None.
        Without the dense reward the step runs in compiled code
        (:func:`vp2.envs._robodesk_kernel.simulate_step`), bit-identical to
        :meth:`_simulate_python`, which the dense reward (a Python function per repeat) needs.
        """
        if self.track_dense_reward:
            return self._simulate_python(action, self._dense_fn)
        wrist_low, wrist_high, wrist_delta, gripper = self._wrist_and_gripper(action)
        self._ik.last_steps = simulate_step(
            *self._kernel, action[0:3] * END_EFFECTOR_SCALE, wrist_delta, wrist_low, wrist_high, gripper,
            ACTION_REPEAT, PHYSICS_STEPS_PER_REPEAT, NUM_ROBOT_JOINTS,
        )  # fmt: skip
        self._check_warnings()
        return None

    def _wrist_and_gripper(self, action: np.ndarray) -> tuple[float, float, float, float]:
        """The wrist's range and target change and the gripper target of ``action``."""
        # Same expressions as the package's _action_to_delta_joint, for the same rounding.
        wrist_low, wrist_high = self._ctrlrange[6]
        wrist_delta = WRIST_SCALE * ((((action[3] + 1) * (wrist_high - wrist_low)) / 2) + wrist_low)
        grip_low, grip_high = self._ctrlrange[7]
        gripper = (((action[4] + 1) * (grip_high - grip_low)) / 2) + grip_low
        return float(wrist_low), float(wrist_high), float(wrist_delta), float(gripper)

    def _simulate_python(
        self, action: np.ndarray, dense_fn: Callable[[], float] | None
    ) -> float | None:
        """:meth:`_simulate` through MuJoCo's Python bindings, one call per physics step (the
        reference the compiled step is tested against); sums ``dense_fn`` over the repeats."""
        dense_total = 0.0
        m, d, ik = self.model, self.data, self._ik
        qpos, ee, target = d.qpos, self._ee_xpos, self._target
        applied, bias, ctrl = self._qfrc_applied, self._qfrc_bias, self._ctrl
        step1, step2 = mujoco.mj_step1, mujoco.mj_step2
        delta = action[0:3] * END_EFFECTOR_SCALE
        wrist_low, wrist_high, wrist_delta, gripper = self._wrist_and_gripper(action)
        for _ in range(ACTION_REPEAT):
            solution = ik.solve(d, ee + delta)
            target[:6] = solution[:6]
            target[6] = min(max(wrist_delta + qpos[6], wrist_low), wrist_high)
            target[7] = target[8] = gripper
            # The package re-assigns ctrl before each of the 10 steps; MuJoCo never writes ctrl,
            # so once is the same.
            ctrl[:] = target
            for _ in range(PHYSICS_STEPS_PER_REPEAT):
                applied[:] = bias  # gravity (and Coriolis) compensation of the robot
                step2(m, d)
                step1(m, d)
            if dense_fn is not None:
                dense_total += dense_fn()
        self._check_warnings()
        return None if dense_fn is None else dense_total

    def _warning_count(self) -> int:
        return int(sum(w.number for w in self.data.warning))

    def _check_warnings(self) -> None:
        # dm_control raises PhysicsError when MuJoCo issues a warning (e.g. a diverging
        # simulation that MuJoCo silently resets); do the same, once per env step.
        count = self._warning_count()
        if count > self._warnings_seen:
            self._warnings_seen = count
            issued = [
                mujoco.mjtWarning(i).name for i, w in enumerate(self.data.warning) if w.number > 0
            ]
            raise RuntimeError(
                f"{self.name}: MuJoCo reported a simulation warning ({', '.join(issued)}); "
                "the state is no longer valid, reset the environment"
            )

    # ---- success ---------------------------------------------------------------------------
    # The task's success rule and target come from its registry entry (vp2.envs.tasks.TASKS);
    # the thresholds and the state they are read from are this simulator's, kept here.
    def _make_success_fn(self, task: Task) -> Callable[[], bool]:
        qpos = self.data.qpos
        if task.success == "button_pressed":
            light = self._qadr(f"{task.target}_light")
            return lambda: qpos[light] < BUTTON_PRESSED_BELOW
        if task.success == "slide_open":
            slide = self._qadr("slide_joint")
            return lambda: qpos[slide] > SLIDE_OPEN_ABOVE
        if task.success == "drawer_open":
            drawer = self._qadr("drawer_joint")
            return lambda: qpos[drawer] < DRAWER_OPEN_BELOW
        if task.success != "off_table":
            raise ValueError(f"{task.name}: RoboDesk has no success rule {task.success!r}")
        target = OBJECTS.index(task.target)
        z_adr = self._object_qadr[target] + 2
        others = [i for i in range(len(OBJECTS)) if i != target]

        def off_table() -> bool:
            if not qpos[z_adr] < OFF_TABLE_BELOW:
                return False
            return all(self._did_not_move(i) for i in others)

        return off_table

    def _make_dense_reward_fn(self, task: Task) -> Callable[[], float]:
        """The ``robodesk`` package's dense reward of the task, on the current state.

        Same terms and weights as the package's task rewards, with its original-position bug
        fixed (the "stay put" and "pushed" terms compare with the positions at reset).
        """
        d, ee = self.data, self._ee_xpos

        def reach(point: np.ndarray) -> float:  # 1 at the point, 0 a metre or more away
            return min(1.0, max(0.0, 1.0 - _norm3(ee - point)))

        if task.success == "button_pressed":
            pressed = self._make_success_fn(task)
            button = self._id(mujoco.mjtObj.mjOBJ_BODY, f"{task.target}_button")
            return lambda: 0.25 * pressed() + 0.75 * reach(d.xpos[button])
        if task.success == "slide_open":
            slide = self._qadr("slide_joint")
            handle = self._id(mujoco.mjtObj.mjOBJ_SITE, "slide_handle")
            offset = np.array([0.15, 0.0, 0.0])
            weights = (0.34, 0.33, 0.33)  # ball, upright block, flat block (the package's)

            def slide_reward() -> float:
                stay = sum(w * self._did_not_move(i) for i, w in enumerate(weights))
                task_reward = 0.75 * d.qpos[slide] / 0.6 + 0.25 * reach(d.site_xpos[handle] - offset)
                return 0.9 * task_reward + 0.1 * stay

            return slide_reward
        if task.success == "drawer_open":
            drawer = self._qadr("drawer_joint")
            handle = self._id(mujoco.mjtObj.mjOBJ_GEOM, "drawer_handle")
            return lambda: 0.75 * abs(d.qpos[drawer]) / 0.3 + 0.25 * reach(d.geom_xpos[handle])
        target = OBJECTS.index(task.target)  # off_table (checked by _make_success_fn)
        others = [i for i in range(len(OBJECTS)) if i != target]
        body = self._object_bodies[target]

        def off_table_reward() -> float:
            pushed = 1.0 - d.xpos[body][2] / self._original_pos[target][2]
            stay = sum(
                0.1 * (1.0 - _norm3(d.xpos[self._object_bodies[i]] - self._original_pos[i]) / 5.0)
                for i in others
            )
            progress = min(1.0, max(0.0, 0.8 * pushed + stay))
            return 0.75 * progress + 0.25 * reach(d.xpos[body])

        return off_table_reward

    def _did_not_move(self, i: int) -> bool:
        moved = self.data.xpos[self._object_bodies[i]] - self._original_pos[i]
        return _norm3(moved) < DID_NOT_MOVE_WITHIN

    def dense_reward(self) -> float:
        """The package's dense reward of the task on the current state (one action repeat)."""
        return float(self._dense_fn())

    def is_success(self, goal_state: np.ndarray | None = None) -> bool:
        """The package's success criterion of the task, on the current state.

        * ``push_<color>``: the button's light joint is below ``-0.00453`` (button pressed);
        * ``open_slide``: slide joint ``> 0.55``; ``open_drawer``: drawer joint ``< -0.2``;
        * ``<object>_off_table``: the object's height is below ``0.6`` m and each of the two
          other objects is within 1 cm of its position at reset.

        ``goal_state`` is ignored: the criteria need no goal.
        """
        return bool(self._success_fn())

    # ---- rendering -------------------------------------------------------------------------
    def render(self, height: int = 64, width: int | None = None) -> np.ndarray:
        if self._renderer is None:
            self._renderer = Renderer(
                self.model, RENDER_SPEC, render_model=load_render_model(RENDER_SPEC.mesh_reduction)
            )
        return self._renderer.render(self.data, height, width)

    def _observation(self) -> np.ndarray | None:
        if self.observation_size is None:
            return None
        return self.render(self.observation_size)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def reseed(self, seed: int | None) -> None:
        self._seed = seed
        self._rng = np.random.default_rng(seed)

    def serialize(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kwargs": {"seed": self._seed, "observation_size": self.observation_size},
        }
