"""The model of a robot description as a torch module: θ, f → (l_model, G_geom).

l_model = h_geom(θ) − log1p(f)/K (the description's geometry and elastic law,
``ArmModel.length``). Used as the prior of a body schema (l = l_model + learned
correction) and written into
the model file, so a trained schema is self-contained and exports to ONNX: forward
kinematics of a revolute chain (Rodrigues), via points carried by their joints, muscle
length = sum of straight segments, relative to θ = 0. G is analytic: a point carried by
joint k moves with ω_k × (p − o_k) per radian, and a segment's length changes by
u·(dp_b − dp_a). The constants come from pinocchio once (at training time); evaluating
needs only the stored tensors. Tests check it against ``ArmModel.h_geom`` and
``muscle_jacobian``.
"""

from __future__ import annotations

import numpy as np
import torch

PREFIX = "prior."
KEYS = ("rot0", "pos0", "axis", "parent", "theta_map", "q_offset", "via_joint", "via_local",
        "seg_a", "seg_b", "seg_muscle", "h0", "supports", "K")
_REVOLUTE_AXES = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0),
                  "JointModelRZ": (0.0, 0.0, 1.0)}


class PriorUnavailable(ValueError):
    """The robot description cannot serve as a prior (message says why)."""


def prior_arrays(arm) -> dict[str, np.ndarray]:  # arm: pimbs_calibration.ArmModel
    """Constants of the geometric model, from pinocchio (joint 0 is the fixed world)."""
    if arm.backend.kind != "urdf":
        raise PriorUnavailable(f"{arm.robot.name} is an MJCF robot whose tendons MuJoCo "
                               "routes, and the prior is a tensor model of via points on a "
                               "URDF; the schema learns the whole length map from the data "
                               "instead")
    vb = arm.backend  # the via-point backend holds the pinocchio model and the via points
    model = vb._model
    nj = model.njoints
    rot0, pos0, axis = np.zeros((nj, 3, 3)), np.zeros((nj, 3)), np.zeros((nj, 3))
    rot0[0] = np.eye(3)
    # every joint of the (reduced) model: q_j = theta_map[j]·θ + q_offset[j] (driven joints,
    # and mimic joints that follow them; locked joints are already folded in by pinocchio)
    theta_map, q_offset = np.zeros((nj, arm.n_joints)), np.zeros(nj)
    for j in range(1, nj):
        jm = model.joints[j]
        kind = jm.shortname()
        if kind in _REVOLUTE_AXES:
            axis[j] = _REVOLUTE_AXES[kind]
        elif kind == "JointModelRevoluteUnaligned":
            axis[j] = np.asarray(jm.extract().axis, dtype=np.float64)
        else:
            raise PriorUnavailable(f"joint '{model.names[j]}' is a {kind}; the geometric "
                                   "prior supports revolute joints only")
        rot0[j] = model.jointPlacements[j].rotation
        pos0[j] = model.jointPlacements[j].translation
        col = list(vb._iq_cols).index(jm.idx_q)
        theta_map[j] = vb._S[col]
        q_offset[j] = vb._offset[col]
    supports = np.zeros((nj, nj))  # supports[k, j]: joint k moves frame j
    for j in range(nj):
        for k in model.supports[j]:
            supports[k, j] = 1.0
    vj = np.array(vb._joint_ids)[vb._via_joint]
    return {"rot0": rot0, "pos0": pos0, "axis": axis, "parent": np.array(
        list(model.parents), dtype=np.int64), "theta_map": theta_map, "q_offset": q_offset,
        "via_joint": vj.astype(np.int64), "via_local": vb._via_local.copy(),
        "seg_a": vb._seg_a.astype(np.int64), "seg_b": vb._seg_b.astype(np.int64),
        "seg_muscle": vb._seg_muscle.copy(), "h0": arm._h0.copy(),
        "supports": supports, "K": np.asarray(arm.K, dtype=np.float64)}


def _rodrigues(axis: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """Rotation (B, 3, 3) by angle q (B,) about the unit axis (3,)."""
    x, y, z = axis[0], axis[1], axis[2]
    zero = torch.zeros_like(x)
    k = torch.stack([torch.stack([zero, -z, y]), torch.stack([z, zero, -x]),
                     torch.stack([-y, x, zero])])
    s, c = torch.sin(q)[:, None, None], torch.cos(q)[:, None, None]
    return torch.eye(3, dtype=axis.dtype) + s * k + (1 - c) * (k @ k)


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a × b over the last axis (broadcasting), written out: exports to any ONNX opset."""
    return torch.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                        a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                        a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], dim=-1)


class GeometricPrior(torch.nn.Module):
    """θ [B, N], f [B, M] → (l_model [B, M] m, G_geom [B, M, N] m/rad)."""

    def __init__(self, arrays: dict[str, torch.Tensor]) -> None:
        super().__init__()
        for k, v in arrays.items():
            self.register_buffer(k, v.clone())
        # the chain's structure is fixed: plain ints, so the loop below unrolls in a trace
        self._parent = [int(p) for p in self.parent.tolist()]

    @classmethod
    def from_numpy(cls, arrays: dict[str, np.ndarray], dtype: torch.dtype = torch.float64
                   ) -> GeometricPrior:
        return cls({k: torch.from_numpy(v) if v.dtype == np.int64 else
                    torch.as_tensor(v, dtype=dtype) for k, v in arrays.items()})

    def forward(self, theta: torch.Tensor, tension: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        zero = theta[:, :1] * 0  # (B, 1): batch-sized zeros by broadcasting, no shape ops
        q_all = theta @ self.theta_map.transpose(-1, -2) + self.q_offset  # (B, J)
        rots, poss, omegas = [], [], []
        for j, parent in enumerate(self._parent):
            if j == 0:  # the world frame
                rots.append(zero.unsqueeze(-1) + self.rot0[0])
                poss.append(zero + self.pos0[0])
                omegas.append(zero + self.axis[0])
                continue
            r_p, p_p = rots[parent], poss[parent]
            r_fixed = r_p @ self.rot0[j]
            poss.append((r_p @ self.pos0[j].unsqueeze(-1)).squeeze(-1) + p_p)
            omegas.append((r_fixed @ self.axis[j].unsqueeze(-1)).squeeze(-1))
            rots.append(r_fixed @ _rodrigues(self.axis[j], q_all[:, j]))
        rot = torch.stack(rots, dim=1)  # (B, J, 3, 3)
        pos = torch.stack(poss, dim=1)  # (B, J, 3)
        omega = torch.stack(omegas, dim=1)  # (B, J, 3)
        pts = (rot[:, self.via_joint] @ self.via_local.unsqueeze(-1)).squeeze(-1) \
            + pos[:, self.via_joint]  # (B, V, 3)
        d = pts[:, self.seg_b] - pts[:, self.seg_a]
        seg_len = torch.sqrt((d * d).sum(-1))  # (B, S)
        h = seg_len @ self.seg_muscle.transpose(-1, -2) - self.h0 \
            - torch.log1p(tension.clamp(min=0)) / self.K
        # dp_v/dq_k = ω_k × (p_v − o_k) where joint k supports the via point's joint
        rel = pts.unsqueeze(2) - pos.unsqueeze(1)  # (B, V, J, 3)
        dp = _cross(omega.unsqueeze(1), rel)
        moved = self.supports.transpose(-1, -2)[self.via_joint]  # (V, J)
        dp = dp * moved.unsqueeze(0).unsqueeze(-1)  # (B, V, J, 3)
        dp_theta = (dp.transpose(-1, -2) @ self.theta_map)  # (B, V, 3, N)
        u = d / seg_len.unsqueeze(-1)
        dlen = (u.unsqueeze(-1) * (dp_theta[:, self.seg_b] - dp_theta[:, self.seg_a])).sum(-2)
        return h, self.seg_muscle @ dlen  # (B, M), (B, M, N)


def load_prior(robot: str, joints: tuple[str, ...], muscles: tuple[str, ...]
               ) -> dict[str, np.ndarray]:
    """Prior constants of a robot NAME|PATH whose joints and muscles match the recording's."""
    from pimbs_arm.model import ArmModel

    try:
        arm = ArmModel.load(robot)
    except Exception as e:  # description errors come in several types: all mean "no prior"
        raise PriorUnavailable(f"robot '{robot}' cannot be loaded ({e})") from e
    if tuple(arm.joints) != tuple(joints) or tuple(arm.muscles) != tuple(muscles):
        raise PriorUnavailable(f"robot '{robot}' has joints {list(arm.joints)} and muscles "
                               f"{list(arm.muscles)}, the recording {list(joints)} and "
                               f"{list(muscles)}")
    return prior_arrays(arm)
