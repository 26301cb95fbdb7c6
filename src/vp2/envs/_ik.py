"""Position-only inverse kinematics of one site, on raw MuJoCo.

This is the algorithm of dm_control's ``inverse_kinematics.qpos_from_site_pose`` restricted to a
position target and to hinge/slide joints (what the ``robodesk`` package calls on every one of
its 50 action repeats), rewritten so that one iteration costs a few microseconds of C instead of
a full ``mj_fwdPosition`` (which runs collision detection, constraint assembly and mass-matrix
factorisation that the IK never reads). Only the site position and its Jacobian are needed, and
those depend on ``mj_kinematics`` (poses) and ``mj_comPos`` (``cdof``/``subtree_com``).

Every floating-point operation that produces the joint update is the same as dm_control's, in the
same order and on arrays of the same layout, so the solution is bit-identical to the package's,
not merely close: the RoboDesk equivalence benchmark relies on that.
"""

from __future__ import annotations

import math
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
        self._qadrs = np.asarray(qadrs)
        self.tol = tol
        self.regularization_threshold = regularization_threshold
        self.regularization_strength = regularization_strength
        self.max_update_norm = max_update_norm
        self.progress_thresh = progress_thresh
        self.max_steps = max_steps
        self._jac = np.empty((3, model.nv))
        self._err = np.empty(3)
        self._eye = np.eye(len(dofs))
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
        site_xpos = data.site_xpos[site_id]
        source = data
        d.qpos[:] = data.qpos
        steps = 0
        for steps in range(self.max_steps):  # noqa: B007 (steps is reported after the loop)
            np.subtract(target_pos, site_xpos, out=err)
            # 0.0 + norm, as dm_control accumulates it; np.linalg.norm is sqrt(x.dot(x)).
            err_norm = 0.0 + math.sqrt(err.dot(err))
            if err_norm < self.tol:
                break
            jac_site(m, source, jac, None, site_id)
            jac_joints = jac[:, dof_index]
            hess_approx = jac_joints.T.dot(jac_joints)
            joint_delta = jac_joints.T.dot(err)
            if err_norm > self.regularization_threshold and self.regularization_strength > 0:
                hess_approx += self._eye * self.regularization_strength
                update = np.linalg.solve(hess_approx, joint_delta)
            else:
                # The Gauss-Newton matrix has rank 3 here; lstsq returns the minimum-norm step.
                update = _lstsq(hess_approx, joint_delta)
            update_norm = math.sqrt(update.dot(update))
            if update_norm == 0.0 or err_norm / update_norm > self.progress_thresh:
                break
            if update_norm > self.max_update_norm:
                update *= self.max_update_norm / update_norm
            # mj_integratePos on hinge/slide joints is qpos += 1 * qvel: the same rounding.
            if self._qpos_slice is not None:
                self._qpos_slice += update
            else:
                d.qpos[self._qadrs] += update
            kinematics(m, d)
            com_pos(m, d)
            source, site_xpos = d, self._site_xpos
        self.last_steps = steps
        return d.qpos


def _as_slice(indices: list[int]) -> slice | None:
    """``indices`` as a slice if they are consecutive, else ``None``."""
    if indices == list(range(indices[0], indices[0] + len(indices))):
        return slice(indices[0], indices[0] + len(indices))
    return None


def _numpy_lstsq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.lstsq(a, b, rcond=-1)[0]


def _make_lstsq() -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``np.linalg.lstsq(a, b, rcond=-1)[0]`` for a square ``a`` and a vector ``b``.

    ``np.linalg.lstsq`` spends two thirds of its 11 us in argument handling around one LAPACK
    call (``gelsd``); the IK makes ~150 calls per env step. NumPy 1.x exposes that call as a
    gufunc, which gives the same bits for a third of the cost. Anything else (another NumPy)
    falls back to the public function.
    """
    try:
        from numpy.linalg import _umath_linalg
        from numpy.linalg.linalg import _raise_linalgerror_lstsq, get_linalg_error_extobj

        gufunc = _umath_linalg.lstsq_m
        extobj = get_linalg_error_extobj(_raise_linalgerror_lstsq)

        def fast(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            return gufunc(a, b[:, None], -1.0, signature="ddd->ddid", extobj=extobj)[0][:, 0]

        check = np.random.default_rng(0).standard_normal((3, 6))
        a, b = check.T @ check, check.T @ np.arange(3.0)
        if np.array_equal(fast(a, b), _numpy_lstsq(a, b)):
            return fast
    except (ImportError, AttributeError, TypeError):
        pass
    return _numpy_lstsq


_lstsq = _make_lstsq()
