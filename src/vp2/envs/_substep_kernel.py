"""The physics steps of one tabletop control step, in compiled code with no Python per step.

A one-second control step is 500 physics steps of 2 ms. Each one needs the operational-space
torques of the current state (two site Jacobians, the dense mass matrix, the OSC kernel) and
MuJoCo's ``mj_step1``/``mj_step2`` around them. Made from Python, those calls and their small
arrays cost a third again as much as the physics (docs/measurements.md), so :func:`run_substeps`
makes every call from a numba-compiled loop, MuJoCo's C functions called by symbol
(:mod:`vp2.envs._mujoco_c`) with the model's and data's raw addresses. The arithmetic
is unchanged -- the same C functions in the same order, the same :func:`osc_torques` -- so
states are bit-identical to stepping through the bindings (``tests/envs/test_tabletop.py``).

The loop holds no Python object and runs with the GIL released (``nogil``), so threads can
step several environments at once.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types

from vp2.envs._mujoco_c import P as _P
from vp2.envs._mujoco_c import external
from vp2.envs._mujoco_c import mj_jacSite as _mj_jacSite
from vp2.envs._mujoco_c import mj_step1 as _mj_step1
from vp2.envs._mujoco_c import mj_step2 as _mj_step2
from vp2.envs._osc_kernel import osc_torques

_mj_fullM = external("mj_fullM", types.void, _P, _P, _P)


@numba.njit(nogil=True, fastmath=False, cache=True)
def run_substeps(
    model, data, n_substeps,
    qpos, qvel, qfrc_bias, qM, ctrl, site_xpos, site_xmat,
    center_site, ref_site, jacp_c, jacr_c, jacp_r, jacr_r, full_mass,
    qpos_index, qvel_index, goal_pos, goal_ori,
    kp_pos, kd_pos, kp_ori, kd_ori, joint_kp, initial_joint, torques,
    arm_actuators, arm_low, arm_high, grip_actuators, grip_ctrl,
):  # fmt: skip
    """``n_substeps`` physics steps under the OSC, the first one's ``mj_step1`` already done.

    ``model``/``data`` are the raw addresses of the ``MjModel``/``MjData``; the arrays are the
    data's own fields (views, so they follow the C calls) and scratch buffers. Per physics step,
    as :class:`vp2.envs._tabletop_stepper.LeanStepper` did through the bindings: ``mj_step1``
    (from the second on), the two sites' Jacobians, ``mj_fullM``, :func:`osc_torques`, the arm
    torques clipped to the actuators' range and the gripper command written to ``ctrl``, then
    ``mj_step2``.
    """
    origin_ori = np.empty((3, 3))
    ref_ori = np.empty((3, 3))
    for i in range(n_substeps):
        if i:
            _mj_step1(model, data)
        _mj_jacSite(model, data, jacp_c.ctypes.data, jacr_c.ctypes.data, center_site)
        _mj_jacSite(model, data, jacp_r.ctypes.data, jacr_r.ctypes.data, ref_site)
        _mj_fullM(model, full_mass.ctypes.data, qM.ctypes.data)
        for r in range(3):
            for c in range(3):
                origin_ori[r, c] = site_xmat[center_site, 3 * r + c]
                ref_ori[r, c] = site_xmat[ref_site, 3 * r + c]
        osc_torques(
            qpos, qvel, qfrc_bias, full_mass, jacp_c, jacr_c, jacp_r, jacr_r,
            qpos_index, qvel_index, site_xpos[center_site], origin_ori,
            site_xpos[ref_site], ref_ori, goal_pos, goal_ori,
            kp_pos, kd_pos, kp_ori, kd_ori, joint_kp, initial_joint, torques,
        )  # fmt: skip
        for j in range(arm_actuators.shape[0]):
            ctrl[arm_actuators[j]] = min(max(torques[j], arm_low[j]), arm_high[j])
        for j in range(grip_actuators.shape[0]):
            ctrl[grip_actuators[j]] = grip_ctrl[j]
        _mj_step2(model, data)
