"""What MuJoCo itself says an MJCF with joint equalities measures at a pose of its driven
joints: the reference the coupled MJCF backend is checked against (by the tests and by
``benchmarks/myosuite_models.py``).

Nothing here reads ``polycoef``: the followers are placed by Newton's method on MuJoCo's own
constraint residual (``efc_pos`` of the equality rows, after ``mj_fwdPosition``) with its own
constraint Jacobian (``efc_J``), until the couplings hold to round-off: the coupling
*enforced by MuJoCo*. The Jacobian of the followers with respect to the driven joints is the
null space of those rows (dq_f = -J_f⁻¹ J_d dθ), so the muscle Jacobian ``ten_J · S`` and the
gravity ``Sᵀ qfrc_bias`` are MuJoCo's too.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np


@dataclass(frozen=True)
class CoupledTruth:
    length: np.ndarray  # (M,) ten_length of the tendons asked for
    jacobian: np.ndarray  # (M, N) d length / d driven joints, through the couplings
    gravity: np.ndarray  # (N,) generalized gravity on the driven joints
    residual: float  # largest |efc_pos| of the joint equalities left, m or rad
    qpos: np.ndarray  # the coupled pose


def coupled_truth(model: mujoco.MjModel, driven: Sequence[str], tendons: Sequence[str],
                  theta: np.ndarray, held: Mapping[str, float] | None = None,
                  tol: float = 1e-14) -> CoupledTruth:
    """MuJoCo's lengths, Jacobian and gravity with the driven joints at ``theta``, the joints
    in ``held`` at their values, the rest at ``qpos0`` and every follower of an active
    ``<equality><joint>`` where MuJoCo's constraint puts it."""
    m = copy.deepcopy(model)
    m.opt.jacobian = int(mujoco.mjtJacobian.mjJAC_DENSE)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    d = mujoco.MjData(m)
    jid = [m.joint(j).id for j in driven]
    qadr, dof = m.jnt_qposadr[jid], m.jnt_dofadr[jid]
    d.qpos[:] = m.qpos0
    for name, value in (held or {}).items():
        d.qpos[m.jnt_qposadr[m.joint(name).id]] = value
    d.qpos[qadr] = theta
    eqs = [i for i in range(m.neq) if m.eq_active0[i]
           and int(m.eq_type[i]) == int(mujoco.mjtEq.mjEQ_JOINT)]
    f_qadr = m.jnt_qposadr[m.eq_obj1id[eqs]]
    f_dof = m.jnt_dofadr[m.eq_obj1id[eqs]]
    rows = np.array([], dtype=int)
    residual = np.inf
    for _ in range(60):
        mujoco.mj_fwdPosition(m, d)
        J = np.asarray(d.efc_J).reshape(d.nefc, m.nv)
        rows = np.array([r for r in range(d.nefc)
                         if int(d.efc_type[r]) == int(mujoco.mjtConstraint.mjCNSTR_EQUALITY)
                         and int(d.efc_id[r]) in eqs], dtype=int)
        rows = rows[np.argsort([eqs.index(int(d.efc_id[r])) for r in rows])]
        r = np.asarray(d.efc_pos)[rows]
        residual = float(np.abs(r).max(initial=0.0))
        if residual <= tol:
            break
        d.qpos[f_qadr] -= np.linalg.solve(J[np.ix_(rows, f_dof)], r)
    mujoco.mj_fwdPosition(m, d)
    J = np.asarray(d.efc_J).reshape(d.nefc, m.nv)
    S = np.zeros((m.nv, len(driven)))
    S[dof] = np.eye(len(driven))
    if len(eqs):
        S[f_dof] = -np.linalg.solve(J[np.ix_(rows, f_dof)], J[np.ix_(rows, dof)])
    ten_j = np.zeros((m.ntendon, m.nv))
    mujoco.mju_sparse2dense(ten_j, d.ten_J, m.ten_J_rownnz, m.ten_J_rowadr, m.ten_J_colind)
    tid = [m.tendon(t).id for t in tendons]
    d.qvel[:] = 0.0
    mujoco.mj_forward(m, d)
    return CoupledTruth(length=d.ten_length[tid].copy(), jacobian=ten_j[tid] @ S,
                        gravity=S.T @ d.qfrc_bias, residual=residual, qpos=d.qpos.copy())
