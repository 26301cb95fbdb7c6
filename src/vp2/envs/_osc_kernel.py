"""robosuite's operational-space position controller (OSC_POSITION), in fixed-order arithmetic.

One function, :func:`osc_torques`, computes the arm torques of
``OperationalSpaceController.run_controller`` (``control_utils.opspace_matrices``,
``orientation_error`` and ``nullspace_torques`` included) for one physics step. robosuite's
version multiplies and inverts its small matrices with ``np.dot``, ``np.linalg.inv`` and
``np.linalg.pinv``, i.e. with OpenBLAS/LAPACK kernels that numpy and scipy (through numba) pick
by CPU at run time, so its last bits -- and, through the contacts, the trajectories -- depend on
the machine. Here every sum runs in index order over plain loops, the 7x7 mass matrix and the
(symmetric positive definite) operational-space matrices are inverted by Cholesky solves, and
nothing calls BLAS: numba compiles the loops without fast-math, so LLVM may vectorise but not
reorder a sum or fuse a multiply-add, and the result is the same on every x86-64 CPU (checked
with ``NUMBA_CPU_NAME=generic`` against the host's code and across OpenBLAS kernels,
``tests/envs/test_cross_cpu.py``).

Mathematically the torques are robosuite's: ``pinv`` of the operational-space inverse inertia
equals its inverse wherever the Jacobian has full rank (everywhere in the benchmark's
workspace); at an exact singularity robosuite's ``pinv`` would drop the singular direction,
whereas the Cholesky pivots here are clamped at ``1e-15`` (MuJoCo's ``mjMINVAL``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

_MINDIAG = 1e-15  # MuJoCo's mjMINVAL


@numba.njit(cache=True, fastmath=False)
def _cholesky(a, n):
    """In-place lower Cholesky factor of the leading n x n block of ``a`` (reads the lower half)."""
    for j in range(n):
        s = a[j, j]
        for k in range(j):
            s -= a[j, k] * a[j, k]
        if s < _MINDIAG:
            s = _MINDIAG
        d = math.sqrt(s)
        a[j, j] = d
        for i in range(j + 1, n):
            t = a[i, j]
            for k in range(j):
                t -= a[i, k] * a[j, k]
            a[i, j] = t / d


@numba.njit(cache=True, fastmath=False)
def _chol_solve(lo, n, b):
    """Solves ``L L' x = b`` in place (``b``: n x m, every column), ``L`` from :func:`_cholesky`."""
    m = b.shape[1]
    for c in range(m):
        for i in range(n):  # L y = b
            t = b[i, c]
            for k in range(i):
                t -= lo[i, k] * b[k, c]
            b[i, c] = t / lo[i, i]
        for i in range(n - 1, -1, -1):  # L' x = y
            t = b[i, c]
            for k in range(i + 1, n):
                t -= lo[k, i] * b[k, c]
            b[i, c] = t / lo[i, i]


@numba.njit(cache=True, fastmath=False)
def osc_torques(
    qpos, qvel, qfrc_bias, full_mass,
    jacp_c, jacr_c, jacp_r, jacr_r,
    qpos_index, qvel_index,
    origin_pos, origin_ori, ref_pos, ref_ori,
    goal_pos, goal_ori, kp_pos, kd_pos, kp_ori, kd_ori, joint_kp, initial_joint, out,
):  # fmt: skip
    """Arm torques of robosuite's OSC (position, fixed impedance, "base" input frame).

    ``jacp_c``/``jacr_c`` are the translational/rotational Jacobians (3 x nv) of the arm's base
    ("center") site, ``jacp_r``/``jacr_r`` those of the end-effector site; ``origin_*`` and
    ``ref_*`` the two sites' world positions (3) and orientation matrices (3 x 3);
    ``full_mass`` is ``mj_fullM``'s nv x nv matrix; ``joint_kp`` the stiffness of the nullspace
    pull towards ``initial_joint`` (robosuite's ``nullspace_torques`` uses 10). Writes the torques (before actuator
    clipping) into ``out`` (7).
    """
    nv = qvel.shape[0]
    n = qvel_index.shape[0]
    # Site velocities (Controller.update / get_site_xvel*): J qdot.
    bpv = np.zeros(3)
    bov = np.zeros(3)
    rpv = np.zeros(3)
    rov = np.zeros(3)
    for i in range(3):
        a = 0.0
        b = 0.0
        c = 0.0
        e = 0.0
        for k in range(nv):
            a += jacp_c[i, k] * qvel[k]
            b += jacr_c[i, k] * qvel[k]
            c += jacp_r[i, k] * qvel[k]
            e += jacr_r[i, k] * qvel[k]
        bpv[i] = a
        bov[i] = b
        rpv[i] = c
        rov[i] = e
    # Arm Jacobian (6 x n: position rows, then orientation rows) and arm mass matrix (n x n).
    jac = np.empty((6, n))
    for j in range(n):
        dof = qvel_index[j]
        for i in range(3):
            jac[i, j] = jacp_r[i, dof]
            jac[3 + i, j] = jacr_r[i, dof]
    mass = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            mass[i, j] = full_mass[qvel_index[i], qvel_index[j]]
    # Desired pose in the world ("base" input frame): origin + R goal_pos, R goal_ori.
    dwp = np.empty(3)
    dwo = np.empty((3, 3))
    for i in range(3):
        s = 0.0
        for k in range(3):
            s += origin_ori[i, k] * goal_pos[k]
        dwp[i] = origin_pos[i] + s
        for j in range(3):
            s = 0.0
            for k in range(3):
                s += origin_ori[i, k] * goal_ori[k, j]
            dwo[i, j] = s
    # orientation_error(desired, current) = 0.5 * sum_c cross(current[:, c], desired[:, c]).
    ori_err = np.zeros(3)
    for c in range(3):
        ori_err[0] += ref_ori[1, c] * dwo[2, c] - ref_ori[2, c] * dwo[1, c]
        ori_err[1] += ref_ori[2, c] * dwo[0, c] - ref_ori[0, c] * dwo[2, c]
        ori_err[2] += ref_ori[0, c] * dwo[1, c] - ref_ori[1, c] * dwo[0, c]
    force = np.empty(3)
    torque = np.empty(3)
    for i in range(3):
        force[i] = (dwp[i] - ref_pos[i]) * kp_pos[i] + (-(rpv[i] - bpv[i])) * kd_pos[i]
        torque[i] = (0.5 * ori_err[i]) * kp_ori[i] + (-(rov[i] - bov[i])) * kd_ori[i]
    # opspace_matrices: X = M^-1 J' (n x 6), lambda_full^-1 = J X (6 x 6, symmetrised from its
    # lower triangle); lambda_pos^-1 and lambda_ori^-1 are its diagonal 3 x 3 blocks.
    chol_m = mass.copy()
    _cholesky(chol_m, n)
    x = np.empty((n, 6))
    for i in range(n):
        for j in range(6):
            x[i, j] = jac[j, i]
    _chol_solve(chol_m, n, x)
    lam_inv = np.empty((6, 6))
    for i in range(6):
        for j in range(i + 1):
            s = 0.0
            for k in range(n):
                s += jac[i, k] * x[k, j]
            lam_inv[i, j] = s
            lam_inv[j, i] = s
    # Decoupled wrench: lambda_pos force, lambda_ori torque (Cholesky solves of the blocks).
    blk = np.empty((3, 3))
    rhs = np.empty((3, 1))
    wrench = np.empty(6)
    for part in range(2):
        o = 3 * part
        for i in range(3):
            for j in range(3):
                blk[i, j] = lam_inv[o + i, o + j]
            rhs[i, 0] = force[i] if part == 0 else torque[i]
        _cholesky(blk, 3)
        _chol_solve(blk, 3, rhs)
        for i in range(3):
            wrench[o + i] = rhs[i, 0]
    # Nullspace matrix N = I - Jbar J with Jbar = X lambda_full: N = I - X (lambda_full J).
    chol_l = lam_inv.copy()
    _cholesky(chol_l, 6)
    z = jac.copy()  # 6 x n right-hand sides
    _chol_solve(chol_l, 6, z)
    null = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(6):
                s += x[i, k] * z[k, j]
            null[i, j] = (1.0 if i == j else 0.0) - s
    # nullspace_torques (robosuite: joint_kp = 10): N' M (kp (q0 - q) - kv qdot).
    kp = joint_kp
    kv = math.sqrt(kp) * 2
    v = np.empty(n)
    for i in range(n):
        v[i] = kp * (initial_joint[i] - qpos[qpos_index[i]]) - kv * qvel[qvel_index[i]]
    pose = np.empty(n)
    for i in range(n):
        s = 0.0
        for k in range(n):
            s += mass[i, k] * v[k]
        pose[i] = s
    # torques = J' wrench + bias + N' pose_torques.
    for j in range(n):
        s = 0.0
        for i in range(6):
            s += jac[i, j] * wrench[i]
        t = 0.0
        for i in range(n):
            t += null[i, j] * pose[i]
        out[j] = (s + qfrc_bias[qvel_index[j]]) + t
