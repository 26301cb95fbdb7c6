"""One RoboDesk env step (50 action repeats: IK, targets, 10 physics steps each) in compiled code.

:meth:`vp2.envs.robodesk.RoboDeskEnv.step` is 500 physics steps and 50 inverse-kinematics solves.
Made from Python, the calls around the physics (the IK's few microseconds of C per iteration, the
gravity compensation copied before each physics step, the loops) cost a third again as much as
the physics itself (docs/measurements.md). :func:`simulate_step` makes the same calls, in the same
order, from one numba-compiled function: MuJoCo's C functions by symbol
(:mod:`vp2.envs._mujoco_c`) on the raw ``MjModel``/``MjData`` addresses, the data's own arrays as
views. The arithmetic is the Python path's operation for operation (the IK of
:class:`vp2.envs._ik.SitePositionIK`, the package's target expressions), so states are
bit-identical to it (``tests/envs/test_robodesk_kernel.py``), and through it to the ``robodesk``
package (``tests/envs/test_robodesk.py``).

The function holds no Python object and releases the GIL (``nogil``).
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

_mj_kinematics = external("mj_kinematics", types.void, _P, _P)
_mj_comPos = external("mj_comPos", types.void, _P, _P)
_mju_norm3 = external("mju_norm3", types.float64, _P)
_mju_norm = external("mju_norm", types.float64, _P, types.intc)
_mju_mulMatMatT = external(
    "mju_mulMatMatT", types.void, _P, _P, _P, types.intc, types.intc, types.intc
)
_mju_cholFactor = external("mju_cholFactor", types.intc, _P, types.intc, types.float64)
_mju_cholSolve = external("mju_cholSolve", types.void, _P, _P, _P, types.intc)
_mju_mulMatTVec = external("mju_mulMatTVec", types.void, _P, _P, _P, types.intc, types.intc)


@numba.njit(nogil=True, fastmath=False, cache=True)
def ik_solve(
    model, sim, ik, sim_qpos, sim_site_xpos, ik_qpos, ik_site_xpos, site_id, target_pos,
    dofs, qadrs, tol, reg_threshold, reg_strength, max_update_norm, progress_thresh,
    max_steps, mindiag, jac, jac_joints, jj, err, y, update,
):  # fmt: skip
    """:meth:`vp2.envs._ik.SitePositionIK.solve`, compiled; returns its iteration count.

    ``sim``/``ik``: raw addresses of the simulation's data and of the IK's private copy;
    ``sim_qpos``, ``sim_site_xpos``, ``ik_qpos``, ``ik_site_xpos``: their arrays (views). The
    solution is left in ``ik_qpos``. ``jac`` (3 x nv), ``jac_joints`` (3 x joints), ``jj``
    (3 x 3), ``err``, ``y`` (3) and ``update`` (joints): scratch, C-contiguous float64.
    """
    n = dofs.shape[0]
    for i in range(sim_qpos.shape[0]):
        ik_qpos[i] = sim_qpos[i]
    source = sim
    xpos = sim_site_xpos
    steps = 0
    for it in range(max_steps):
        steps = it
        for k in range(3):
            err[k] = target_pos[k] - xpos[site_id, k]
        err_norm = _mju_norm3(err.ctypes.data)
        if err_norm < tol:
            break
        _mj_jacSite(model, source, jac.ctypes.data, 0, site_id)
        for r in range(3):
            for j in range(n):
                jac_joints[r, j] = jac[r, dofs[j]]
        _mju_mulMatMatT(jj.ctypes.data, jac_joints.ctypes.data, jac_joints.ctypes.data, 3, n, 3)
        if err_norm > reg_threshold and reg_strength > 0:
            jj[0, 0] += reg_strength
            jj[1, 1] += reg_strength
            jj[2, 2] += reg_strength
        _mju_cholFactor(jj.ctypes.data, 3, mindiag)
        _mju_cholSolve(y.ctypes.data, jj.ctypes.data, err.ctypes.data, 3)
        _mju_mulMatTVec(update.ctypes.data, jac_joints.ctypes.data, y.ctypes.data, 3, n)
        update_norm = _mju_norm(update.ctypes.data, n)
        if update_norm == 0.0 or err_norm / update_norm > progress_thresh:
            break
        if update_norm > max_update_norm:
            scale = max_update_norm / update_norm
            for j in range(n):
                update[j] *= scale
        for j in range(n):
            ik_qpos[qadrs[j]] += update[j]
        _mj_kinematics(model, ik)
        _mj_comPos(model, ik)
        source = ik
        xpos = ik_site_xpos
    return steps


@numba.njit(nogil=True, fastmath=False, cache=True)
def simulate_step(
    model, sim, ik, sim_qpos, sim_site_xpos, ik_qpos, ik_site_xpos, site_id,
    dofs, qadrs, tol, reg_threshold, reg_strength, max_update_norm, progress_thresh,
    max_steps, mindiag, jac, jac_joints, jj, err, y, update,
    qfrc_applied, qfrc_bias, ctrl, delta, wrist_delta, wrist_low, wrist_high, gripper,
    n_repeats, n_substeps, n_robot,
):  # fmt: skip
    """One env step: ``n_repeats`` times the IK towards ``site + delta``, the joint targets
    (the IK's first 6 joints, the wrist ``qpos[6] + wrist_delta`` clamped to its range, both
    fingers ``gripper``) written to ``ctrl``, then ``n_substeps`` physics steps, each with
    ``qfrc_applied = qfrc_bias`` on the ``n_robot`` robot dofs and dm_control's legacy order
    (``mj_step2`` then ``mj_step1``). Returns the last IK solve's iteration count."""
    target_pos = np.empty(3)
    steps = 0
    for _ in range(n_repeats):
        for k in range(3):
            target_pos[k] = sim_site_xpos[site_id, k] + delta[k]
        steps = ik_solve(
            model, sim, ik, sim_qpos, sim_site_xpos, ik_qpos, ik_site_xpos, site_id, target_pos,
            dofs, qadrs, tol, reg_threshold, reg_strength, max_update_norm, progress_thresh,
            max_steps, mindiag, jac, jac_joints, jj, err, y, update,
        )  # fmt: skip
        for j in range(6):
            ctrl[j] = ik_qpos[j]
        # min(max(v, low), high) as Python evaluates it (the first argument wins a tie).
        wrist = wrist_delta + sim_qpos[6]
        if wrist_low > wrist:
            wrist = wrist_low
        if wrist_high < wrist:
            wrist = wrist_high
        ctrl[6] = wrist
        ctrl[7] = gripper
        ctrl[8] = gripper
        for _s in range(n_substeps):
            for j in range(n_robot):
                qfrc_applied[j] = qfrc_bias[j]
            _mj_step2(model, sim)
            _mj_step1(model, sim)
    return steps
