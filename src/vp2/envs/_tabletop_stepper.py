"""A lean control step of the tabletop world: robosuite's ``env.step``, CPU-independent.

:class:`LeanStepper` advances a :class:`~vp2.envs._tabletop_world.TabletopWorld` by one control
step with the computation of robosuite's ``env.step`` -- the controllers' goals for the new
action, then per physics step the operational-space torques and the same ``mj_step1``/``mj_step2``
split -- but without robosuite's per-substep bookkeeping (observables, action-dimension
properties, proprioception buffers, repeated Jacobian queries by name). robosuite computes its
goals and torques with ``np.dot``/``np.linalg.inv``/``np.linalg.pinv``, i.e. OpenBLAS and LAPACK
kernels that numpy and scipy choose by CPU at run time; the last bits of its trajectories, and
through the contacts the trajectories themselves, depend on the machine. Here the goal is
computed element-wise and the torques by :func:`vp2.envs._osc_kernel.osc_torques` (fixed-order
loops compiled by numba): the same bits on every CPU. The physics steps of a control step run in
:func:`vp2.envs._substep_kernel.run_substeps`, one compiled loop with no Python per physics step.
Against robosuite's own step the states agree to rounding (``tests/envs/test_tabletop.py``;
figures in docs/tabletop.md).
"""

from __future__ import annotations

import mujoco
import numpy as np

from vp2.envs._substep_kernel import run_substeps
from vp2.envs._tabletop_world import TabletopWorld


class LeanStepper:
    """One control step of a :class:`TabletopWorld`: robosuite's ``env.step``, CPU-independent.

    robosuite's step spends most of its time outside the physics: per physics step (500 per
    control step at 1 Hz) it re-queries Jacobians by site name four times, recomputes action limits,
    updates every observable, and pushes proprioception buffers. This class keeps only what
    changes the simulation: at the first physics step the goals (the gripper's by robosuite's
    own ``set_goal``, the arm's by :meth:`_set_goal`), then at every physics step the
    operational-space torques of ``OperationalSpaceController.run_controller`` in fixed-order
    arithmetic, and the same gripper command.

    State that robosuite keeps between control steps and that changes what a step does:
    the gripper's accumulated command (``PandaGripper.current_action``) and the nullspace target
    of the OSC (``initial_joint``, the arm configuration at reset). :meth:`controller_state` /
    :meth:`set_controller_state` save and restore both; the OSC goal itself is recomputed from
    the simulator state at every control step (robosuite's "achieved" goal-update mode).
    """

    #: Length of :meth:`controller_state`: gripper command (2) + OSC nullspace target (7).
    CONTROLLER_STATE_SIZE = 9

    def __init__(self, world: TabletopWorld):
        self.world = world
        robot = world.robots[0]
        self.composite = robot.composite_controller
        self.osc = self.composite.part_controllers["right"]
        self.grip = self.composite.part_controllers["right_gripper"]
        self.gripper_model = robot.gripper["right"]
        self.model = world.sim.model._model
        self.data = world.sim.data._data
        self.n_substeps = int(round(world.control_timestep / world.model_timestep))

        osc = self.osc
        if osc.interpolator_pos is not None or osc.use_ori or osc.impedance_mode != "fixed":
            raise RuntimeError(
                "LeanStepper mirrors OSC_POSITION with fixed impedance, no interpolator"
            )
        self._ref_site = self.model.site(osc.ref_name).id
        self._center_site = self.model.site(f"{osc.naming_prefix}{osc.part_name}_center").id
        self._qvel_index = np.asarray(osc.qvel_index, dtype=np.intp)
        self._qpos_index = np.asarray(osc.qpos_index, dtype=np.intp)
        self._arm_actuators = np.array(robot._ref_actuators_indexes_dict["right"], np.intp)
        self._grip_actuators = np.array(robot._ref_actuators_indexes_dict["right_gripper"], np.intp)
        ctrlrange = self.model.actuator_ctrlrange
        self._arm_low = ctrlrange[self._arm_actuators, 0]
        self._arm_high = ctrlrange[self._arm_actuators, 1]
        self._grip_low = ctrlrange[self._grip_actuators, 0]
        self._grip_high = ctrlrange[self._grip_actuators, 1]
        # SimpleGripController.run_controller's affine map from [-1, 1] to the actuator range.
        grip_range = np.stack([self.grip.actuator_min, self.grip.actuator_max], axis=-1)
        self._grip_bias = 0.5 * (grip_range[:, 1] + grip_range[:, 0])
        self._grip_weight = 0.5 * (grip_range[:, 1] - grip_range[:, 0])
        nv = self.model.nv
        self._jacp = np.zeros((3, nv))
        self._jacr = np.zeros((3, nv))
        self._full_mass = np.zeros((nv, nv))
        self._kp_pos = np.array(osc.kp[0:3], np.float64)
        self._kp_ori = np.array(osc.kp[3:6], np.float64)
        self._kd_pos = np.array(osc.kd[0:3], np.float64)
        self._kd_ori = np.array(osc.kd[3:6], np.float64)
        self._jacp_c = np.zeros((3, nv))
        self._jacr_c = np.zeros((3, nv))
        self._torques = np.zeros(len(self._qvel_index))
        # What the compiled physics loop reads and writes: raw addresses and the data's own
        # arrays (views into mjData, fixed for the data's lifetime).
        self._model_address = self.model._address
        self._data_address = self.data._address
        d = self.data
        self._qpos, self._qvel, self._qfrc_bias, self._qM = d.qpos, d.qvel, d.qfrc_bias, d.qM
        self._ctrl, self._site_xpos, self._site_xmat = d.ctrl, d.site_xpos, d.site_xmat
        self._hand = np.array(world.scene.controller.hand_orientation, np.float64)
        self._nullspace_kp = float(world.scene.controller.nullspace_kp)
        start, end = self.composite._action_split_indexes[self.osc.part_name]
        self._arm_action = slice(start, end)
        start, end = self.composite._action_split_indexes["right_gripper"]
        self._grip_action = slice(start, end)

    # ---- controller state --------------------------------------------------------------------
    def controller_state(self) -> np.ndarray:
        """The controller state that survives between control steps, shape ``(9,)``."""
        grip = np.broadcast_to(np.asarray(self.gripper_model.current_action, np.float64), (2,))
        return np.concatenate([grip, np.asarray(self.osc.initial_joint, np.float64)])

    def set_controller_state(self, state: np.ndarray) -> None:
        """Restores :meth:`controller_state`; the simulator state must already be set."""
        state = np.asarray(state, np.float64)
        self.gripper_model.current_action = state[0:2].copy()
        self.osc.initial_joint = state[2:9].copy()
        self.grip.goal_qvel = None
        # The next set_goal must read the restored simulator state, not a cached one.
        self.osc.new_update = True
        self.grip.new_update = True

    def reset_controllers(self, initial_joint: np.ndarray) -> None:
        """Controller state of a fresh episode: open gripper command, nullspace target ``q0``."""
        self.set_controller_state(np.concatenate([np.zeros(2), np.asarray(initial_joint)]))
        self.composite.update_state()
        self.osc.update(force=True)
        self.osc.reset_goal()

    # ---- stepping ---------------------------------------------------------------------------
    def step(self, action: np.ndarray) -> None:
        """Advances one control step (``n_substeps`` physics steps) with a 4-D action."""
        goals = self.begin_step(action)
        self.physics_steps(goals, self.n_substeps)
        self.end_step()

    def begin_step(self, action: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The first physics step's ``mj_step1`` and the step's goals: ``(goal_pos, goal_ori,
        grip_ctrl)`` for :meth:`physics_steps`."""
        mujoco.mj_step1(self.model, self.data)
        goal_pos, goal_ori = self._set_goal(action)
        grip_ctrl = np.clip(
            self._grip_bias + self._grip_weight * np.array(self.grip.goal_qvel),
            self._grip_low,
            self._grip_high,
        )
        return goal_pos, goal_ori, grip_ctrl

    def physics_steps(self, goals: tuple[np.ndarray, np.ndarray, np.ndarray], n: int) -> None:
        """``n`` physics steps under the OSC toward ``goals`` (:meth:`begin_step`), the first
        one's ``mj_step1`` already done, in one compiled loop."""
        goal_pos, goal_ori, grip_ctrl = goals
        run_substeps(
            self._model_address, self._data_address, n,
            self._qpos, self._qvel, self._qfrc_bias, self._qM, self._ctrl,
            self._site_xpos, self._site_xmat, self._center_site, self._ref_site,
            self._jacp_c, self._jacr_c, self._jacp, self._jacr, self._full_mass,
            self._qpos_index, self._qvel_index, goal_pos, goal_ori,
            self._kp_pos, self._kd_pos, self._kp_ori, self._kd_ori, self._nullspace_kp,
            np.asarray(self.osc.initial_joint, np.float64), self._torques,
            self._arm_actuators, self._arm_low, self._arm_high, self._grip_actuators, grip_ctrl,
        )  # fmt: skip

    def end_step(self) -> None:
        """Leaves the controllers as robosuite's run_controller would: the next read is fresh."""
        self.osc.new_update = True
        self.grip.new_update = True

    def _set_goal(self, action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """robosuite's ``composite.set_goal`` for the OSC ("achieved" mode, "base" frame) and the
        gripper, on fresh simulator data; returns the OSC goal (position, orientation matrix)
        in the base frame.

        The gripper part is robosuite's own code (element-wise). The arm goal is
        ``OperationalSpaceController.compute_goal_pos`` and the world's fixed orientation goal
        (``TabletopWorld``: the scene's ``hand_orientation`` H) written out in fixed-order
        arithmetic: robosuite composes 4x4 poses with ``np.dot`` (OpenBLAS, CPU-dependent
        rounding). Goal position: ``R' (p_ee - p_base) + scaled delta``; goal orientation:
        ``R' H``.
        """
        d = self.data
        self.grip.new_update = True
        self.grip.set_goal(self.gripper_model.format_action(action[self._grip_action]))
        origin_pos = d.site_xpos[self._center_site]
        origin_ori = d.site_xmat[self._center_site].reshape(3, 3)
        ref_pos = d.site_xpos[self._ref_site]
        hand = self._hand
        rel = ref_pos - origin_pos
        goal_pos = (
            origin_ori[0] * rel[0] + origin_ori[1] * rel[1] + origin_ori[2] * rel[2]
        ) + self.osc.scale_action(action[self._arm_action])
        goal_ori = (
            origin_ori[0][:, None] * hand[0][None, :]
            + origin_ori[1][:, None] * hand[1][None, :]
            + origin_ori[2][:, None] * hand[2][None, :]
        )
        self.osc.goal_pos, self.osc.goal_ori = goal_pos, goal_ori
        return goal_pos, goal_ori
