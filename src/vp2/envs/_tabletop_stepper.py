"""A lean control step of the tabletop world, bit-identical to robosuite's ``env.step``.

:class:`LeanStepper` advances a :class:`~vp2.envs._tabletop_world.TabletopWorld` by one control
step with exactly the arithmetic of robosuite's ``env.step`` -- the controllers' own
``set_goal`` for the new action, then per physics step the same NumPy/numba operations in the
same order for the torques and the same ``mj_step1``/``mj_step2`` split -- but without
robosuite's per-substep bookkeeping (observables, action-dimension properties, proprioception
buffers, repeated Jacobian queries by name). The result is bit-identical to robosuite's step;
``tests/envs/test_tabletop.py`` checks it.
"""

from __future__ import annotations

import mujoco
import numpy as np
from robosuite.utils.control_utils import nullspace_torques, opspace_matrices, orientation_error

from vp2.envs._tabletop_world import TabletopWorld


class LeanStepper:
    """One control step of a :class:`TabletopWorld`, bit-identical to robosuite's ``env.step``.

    robosuite's step spends most of its time outside the physics: per physics step (25 per
    control step) it re-queries Jacobians by site name four times, recomputes action limits,
    updates every observable, and pushes proprioception buffers. This class keeps only what
    changes the simulation: at the first physics step the controllers' own ``set_goal`` (so the
    goal arithmetic is robosuite's code), then at every physics step the operational-space
    torques computed with the same operations, in the same order, on arrays of the same
    layout as ``OperationalSpaceController.run_controller`` (the numba kernels are robosuite's
    own), and the same gripper command.

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
        self._arm_actuators = np.array(robot._ref_actuators_indexes_dict["right"])
        self._grip_actuators = np.array(robot._ref_actuators_indexes_dict["right_gripper"])
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
        self._kp_pos = np.array(osc.kp[0:3])
        self._kp_ori = np.array(osc.kp[3:6])
        self._kd_pos = osc.kd[0:3]
        self._kd_ori = osc.kd[3:6]

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
        m, d = self.model, self.data
        mujoco.mj_step1(m, d)
        # robosuite's own goal arithmetic, once per control step, on fresh simulator data.
        self.osc.new_update = True
        self.grip.new_update = True
        self.composite.update_state()
        self.composite.set_goal(action)
        goal_pos, goal_ori = self.osc.goal_pos, self.osc.goal_ori
        grip_ctrl = np.clip(
            self._grip_bias + self._grip_weight * np.array(self.grip.goal_qvel),
            self._grip_low,
            self._grip_high,
        )
        for i in range(self.n_substeps):
            if i:
                mujoco.mj_step1(m, d)
            torques = self._osc_torques(goal_pos, goal_ori)
            d.ctrl[self._arm_actuators] = np.minimum(
                np.maximum(torques, self._arm_low), self._arm_high
            )
            d.ctrl[self._grip_actuators] = grip_ctrl
            mujoco.mj_step2(m, d)
        # Leave the controllers as robosuite's run_controller would: the next read is fresh.
        self.osc.new_update = True
        self.grip.new_update = True

    def _osc_torques(self, goal_pos: np.ndarray, goal_ori: np.ndarray) -> np.ndarray:
        """``OperationalSpaceController.run_controller`` (+ ``update``), operation for operation.

        Element-wise arithmetic may read MuJoCo's arrays in place; everything that goes into a
        matrix product (BLAS) or one of robosuite's numba kernels is a fresh C-ordered copy, as
        in robosuite, because those may round differently for other layouts.
        """
        m, d = self.model, self.data
        qvel = d.qvel
        qvel_index = self._qvel_index
        jacp, jacr = self._jacp, self._jacr

        # CompositeController.update_state -> origin of the base frame.
        origin_pos = d.site_xpos[self._center_site]
        origin_ori = np.array(d.site_xmat[self._center_site].reshape([3, 3]))
        mujoco.mj_jacSite(m, d, jacp, jacr, self._center_site)
        base_pos_vel = np.dot(jacp, qvel)
        base_ori_vel = np.dot(jacr, qvel)

        # Controller.update: end-effector site pose, velocity, Jacobians, arm mass matrix.
        ref_pos = d.site_xpos[self._ref_site]
        ref_ori_mat = np.array(d.site_xmat[self._ref_site].reshape([3, 3]))
        mujoco.mj_jacSite(m, d, jacp, jacr, self._ref_site)
        ref_pos_vel = np.dot(jacp, qvel)
        ref_ori_vel = np.dot(jacr, qvel)
        # robosuite copies the Jacobians into preallocated C-ordered arrays; numba compiles
        # (and rounds) differently for other layouts, so the layout must match, not just values.
        j_pos = np.ascontiguousarray(jacp[:, qvel_index])
        j_ori = np.ascontiguousarray(jacr[:, qvel_index])
        j_full = np.concatenate([j_pos, j_ori])
        joint_pos = d.qpos[self._qpos_index]
        joint_vel = qvel[qvel_index]
        mujoco.mj_fullM(m, self._full_mass, d.qM)
        mass_matrix = self._full_mass[qvel_index, :][:, qvel_index]

        # OperationalSpaceController.run_controller ("base" input frame, no interpolator).
        desired_world_pos = origin_pos + np.dot(origin_ori, goal_pos)
        desired_world_ori = np.dot(origin_ori, goal_ori)
        ori_error = orientation_error(desired_world_ori, ref_ori_mat)
        desired_force = (desired_world_pos - ref_pos) * self._kp_pos + (
            -(ref_pos_vel - base_pos_vel)
        ) * self._kd_pos
        desired_torque = ori_error * self._kp_ori + (-(ref_ori_vel - base_ori_vel)) * self._kd_ori
        _, lambda_pos, lambda_ori, nullspace_matrix = opspace_matrices(
            mass_matrix, j_full, j_pos, j_ori
        )
        decoupled_wrench = np.concatenate(
            [np.dot(lambda_pos, desired_force), np.dot(lambda_ori, desired_torque)]
        )
        torques = np.dot(j_full.T, decoupled_wrench) + d.qfrc_bias[qvel_index]
        torques += nullspace_torques(
            mass_matrix, nullspace_matrix, self.osc.initial_joint, joint_pos, joint_vel
        )
        return torques
