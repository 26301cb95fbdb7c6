"""Position-only inverse kinematics of one site, on raw MuJoCo.

This is the algorithm of dm_control's ``inverse_kinematics.qpos_from_site_pose`` restricted to a
position target and to hinge/slide joints (what the ``robodesk`` package calls on every one of
its 50 action repeats), rewritten so that one iteration costs a few microseconds of C instead of
a full ``mj_fwdPosition`` (which runs collision detection, constraint assembly and mass-matrix
factorisation that the IK never reads). Only the site position and its Jacobian are needed, and
those depend on ``mj_kinematics`` (poses) and ``mj_comPos`` (``cdof``/``subtree_com``).

The iteration (error, Jacobian, damped step, progress test, clamping, integration) is
dm_control's, operation for operation, except for its two CPU-dependent pieces: dm_control gets
the step from ``np.linalg.solve``/``np.linalg.lstsq`` on ``J'J`` and the norms from
``np.linalg.norm``, i.e. from OpenBLAS/LAPACK kernels chosen by CPU at run time, which round
differently on different machines (and ``gelsd`` on the rank-3 matrix ``J'J`` occasionally keeps
a rounding-level singular value, adding a large null-space component to the step). Here the step
is ``J' (J J' + l I)^-1 e`` -- the same vector (for ``l = 0`` the minimum-norm least-squares
step) -- from a 3x3 Cholesky solve, and the norms are MuJoCo's: compiled code with a fixed
summation order, the same bits on every CPU. With dm_control's ``nullspace_method`` and norms
replaced by :func:`nullspace_step` and ``mju_norm`` the package's IK and dynamics match this one
bit for bit (``tests/envs/test_robodesk.py``); against the unmodified package the trajectories
agree as closely as the package agrees with itself on another OpenBLAS kernel (docs/robodesk.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import mujoco
import numpy as np


class SitePositionIK:
    """Damped least-squares IK that moves one site to a target position.

    The solver works on a private ``MjData`` (the "IK copy" of the ``robodesk`` package), so the
    simulation's own data is never touched. Defaults are those of dm_control's
    ``qpos_from_site_pose``.

    Args:
        model: the MuJoCo model (shared, not modified).
        site_name: the site to move (``"end_effector"`` for RoboDesk).
        joint_names: the joints the IK may move; each must be a hinge or slide joint.
        tol: stop when the position error norm is below this (metres).
        regularization_threshold: use L2 regularisation while the error is above this.
        regularization_strength: coefficient of that regularisation.
        max_update_norm: the joint update of one iteration is scaled down to this norm.
        progress_thresh: stop when ``error / update_norm`` exceeds this (no progress).
        max_steps: maximum number of iterations.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        site_name: str,
        joint_names: Sequence[str],
        tol: float = 1e-14,
        regularization_threshold: float = 0.1,
        regularization_strength: float = 3e-2,
        max_update_norm: float = 2.0,
        progress_thresh: float = 20.0,
        max_steps: int = 100,
    ):
        self.model = model
        self.data = mujoco.MjData(model)
        self.site_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site_name)
        if self.site_id < 0:
            raise ValueError(f"site {site_name!r} is not in the model")
        dofs, qadrs = [], []
        for name in joint_names:
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid < 0:
                raise ValueError(f"joint {name!r} is not in the model")
            if model.jnt_type[jid] not in (
                mujoco.mjtJoint.mjJNT_HINGE,
                mujoco.mjtJoint.mjJNT_SLIDE,
            ):
                raise ValueError(f"joint {name!r} is not a hinge or slide joint")
            dofs.append(int(model.jnt_dofadr[jid]))
            qadrs.append(int(model.jnt_qposadr[jid]))
        #: The dofs and the ``qpos`` addresses of the IK's joints, in order (int64).
        self.dofs = np.asarray(dofs, dtype=np.int64)
        self.qpos_addresses = np.asarray(qadrs, dtype=np.int64)
        self.tol = tol
        self.regularization_threshold = regularization_threshold
        self.regularization_strength = regularization_strength
        self.max_update_norm = max_update_norm
        self.progress_thresh = progress_thresh
        self.max_steps = max_steps
        self._jac = np.empty((3, model.nv))
        self._err = np.empty(3)
        self._jac_joints = np.empty((3, len(dofs)))
        self._jj = np.empty((3, 3))
        self._y = np.empty(3)
        self._update = np.empty(len(dofs))
        self._site_xpos = self.data.site_xpos[self.site_id]  # a view, refreshed by mj_kinematics
        # With consecutive dofs/qpos (the Panda's), slices replace fancy indexing: the same
        # numbers (the equivalence benchmark checks every bit), two microseconds less per
        # iteration.
        self._dof_index: slice | list[int] = _as_slice(dofs) or dofs
        qslice = _as_slice(qadrs)
        self._qpos_slice = None if qslice is None else self.data.qpos[qslice]
        #: Iterations used by the last :meth:`solve` (for profiling and tests).
        self.last_steps = 0

    def solve(self, data: mujoco.MjData, target_pos: np.ndarray) -> np.ndarray:
        """Finds joint positions that put the site at ``target_pos``, starting from ``data.qpos``.

        Called once per action repeat by the RoboDesk env with the simulation's data: the
        package syncs its IK copy from the simulation after every repeat, so the IK always
        starts from the simulation's configuration.

        Args:
            data: the simulation's data, with current kinematics (as after ``mj_step1`` or
                ``mj_forward``); read, never modified. The first iteration reads its site
                position and Jacobian instead of recomputing them on the copy.
            target_pos: the target site position, shape ``(3,)``.

        Returns:
            The solution, a view of the private data's ``qpos`` (valid until the next call).
        """
        m, d = self.model, self.data
        kinematics, com_pos, jac_site = mujoco.mj_kinematics, mujoco.mj_comPos, mujoco.mj_jacSite
        site_id, err, jac, dof_index = self.site_id, self._err, self._jac, self._dof_index
        jj, jac_joints, y, update = self._jj, self._jac_joints, self._y, self._update
        site_xpos = data.site_xpos[site_id]
        source = data
        d.qpos[:] = data.qpos
        steps = 0
        for steps in range(self.max_steps):  # noqa: B007 (steps is reported after the loop)
            np.subtract(target_pos, site_xpos, out=err)
            err_norm = _norm3(err)
            if err_norm < self.tol:
                break
            jac_site(m, source, jac, None, site_id)
            jac_joints[:] = jac[:, dof_index]
            # The damped least-squares step (J'J + l I)^-1 J' e, computed as J' (J J' + l I)^-1 e
            # (the same vector; for l = 0 the minimum-norm least-squares step that dm_control
            # asks LAPACK's gelsd for): a 3x3 Cholesky solve in MuJoCo's own routines, whose
            # summation order is compiled in, instead of CPU-dispatched BLAS/LAPACK.
            _mul_mat_mat_t(jj, jac_joints, jac_joints)
            if err_norm > self.regularization_threshold and self.regularization_strength > 0:
                jj[0, 0] += self.regularization_strength
                jj[1, 1] += self.regularization_strength
                jj[2, 2] += self.regularization_strength
            _chol_factor(jj, MINDIAG)
            _chol_solve(y, jj, err)
            _mul_mat_t_vec(update, jac_joints, y)
            update_norm = _norm(update)
            if update_norm == 0.0 or err_norm / update_norm > self.progress_thresh:
                break
            if update_norm > self.max_update_norm:
                update *= self.max_update_norm / update_norm
            # mj_integratePos on hinge/slide joints is qpos += 1 * qvel: the same rounding.
            if self._qpos_slice is not None:
                self._qpos_slice += update
            else:
                d.qpos[self.qpos_addresses] += update
            kinematics(m, d)
            com_pos(m, d)
            source, site_xpos = d, self._site_xpos
        self.last_steps = steps
        return d.qpos


def nullspace_step(
    jac_joints: np.ndarray, delta: np.ndarray, regularization_strength: float = 0.0
) -> np.ndarray:
    """One IK step, as :meth:`SitePositionIK.solve` computes it: ``J' (J J' + l I)^-1 delta``.

    The same vector as dm_control's ``inverse_kinematics.nullspace_method`` (``(J'J + l I)^-1
    J' delta``, or for ``l = 0`` the minimum-norm least-squares solution of ``J'J x = J'
    delta``), computed with MuJoCo's routines so that it has the same bits on every CPU.
    Tests substitute it for dm_control's to compare with the ``robodesk`` package bit for bit.
    """
    jac = np.ascontiguousarray(jac_joints, dtype=np.float64)
    rows, cols = jac.shape
    jj = np.empty((rows, rows))
    _mul_mat_mat_t(jj, jac, jac)
    if regularization_strength > 0:
        for i in range(rows):
            jj[i, i] += regularization_strength
    _chol_factor(jj, MINDIAG)
    y = np.empty(rows)
    _chol_solve(y, jj, np.ascontiguousarray(delta, dtype=np.float64))
    update = np.empty(cols)
    _mul_mat_t_vec(update, jac, y)
    return update


def _as_slice(indices: list[int]) -> slice | None:
    """``indices`` as a slice if they are consecutive, else ``None``."""
    if indices == list(range(indices[0], indices[0] + len(indices))):
        return slice(indices[0], indices[0] + len(indices))
    return None


_norm3, _norm = mujoco.mju_norm3, mujoco.mju_norm
_mul_mat_mat_t, _mul_mat_t_vec = mujoco.mju_mulMatMatT, mujoco.mju_mulMatTVec
_chol_factor, _chol_solve = mujoco.mju_cholFactor, mujoco.mju_cholSolve
#: Smallest pivot of the Cholesky factorisation (MuJoCo's mjMINVAL): a singular J J' (an arm
#: singularity without regularisation) gives a large but finite step, which the update-norm
#: clamp then limits.
MINDIAG = mujoco.mjMINVAL


class _NumpyWithMujocoNorm:
    """numpy, except ``linalg.norm``: MuJoCo's ``mju_norm`` (fixed summation order)."""

    class linalg:  # noqa: N801
        @staticmethod
        def norm(v: np.ndarray) -> float:
            return mujoco.mju_norm(np.ascontiguousarray(v, np.float64))

    def __getattr__(self, name: str) -> object:
        return getattr(np, name)


def make_dm_control_ik_deterministic(setattr_: Callable[..., None] = setattr) -> None:
    """Gives dm_control's inverse kinematics (which the ``robodesk`` package calls) this
    module's CPU-independent arithmetic for its two CPU-dependent pieces: the least-squares
    step (:func:`nullspace_step` for ``numpy.linalg.solve``/``lstsq`` on OpenBLAS) and the vector
    norms (``mju_norm`` for BLAS). Everything else stays dm_control's own code, which
    :class:`SitePositionIK` then matches bit for bit. ``setattr_``: how to patch (a test's
    ``monkeypatch.setattr`` undoes it afterwards)."""
    from dm_control.utils import inverse_kinematics

    setattr_(inverse_kinematics, "nullspace_method", nullspace_step)
    setattr_(inverse_kinematics, "np", _NumpyWithMujocoNorm())
