"""A loaded body schema as one plain torch graph: (θ, f) → (length, G), for export.

Stand-in until the learning side's ``pimbs_learn.graph.SchemaGraph`` lands on main (same
interface): everything a controller needs in one forward, in physical units, with the input
and output scaling inside and G = ∂length/∂θ in closed form (no autograd), so that an
exporter sees nothing but matmuls and element-wise ops.
"""

from __future__ import annotations

import torch

from pimbs_learn.model import PARAM_NAMES


class SchemaGraph(torch.nn.Module):
    """forward(theta (B, N), tension (B, M)) → length (B, M) m, G (B, M, N) m/rad."""

    def __init__(self, schema, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        p = schema._p
        for k in PARAM_NAMES:
            self.register_buffer(k, p[k].to(dtype).clone())
        n, m = schema.n_joints, schema.n_muscles
        inv = torch.as_tensor(schema.scaling.input_inverse(), dtype=dtype)
        if not schema.atl:  # an AL-Map ignores tension: zero columns keep one interface
            self.w1 = torch.cat([self.w1, torch.zeros(self.w1.shape[0], m, dtype=dtype)], 1)
            inv = torch.cat([inv, torch.zeros(m, dtype=dtype)])
        self.register_buffer("input_inverse", inv)
        self.register_buffer("length_scale", torch.as_tensor(schema.scaling.length,
                                                             dtype=dtype))
        self.n_joints = n
        self.joints, self.muscles = list(schema.joints), list(schema.muscles)

    def forward(self, theta: torch.Tensor, tension: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        n = self.n_joints
        x = torch.cat([theta, tension], dim=-1) * self.input_inverse
        a1 = torch.tanh(x @ self.w1.T + self.b1)  # (B, H)
        # Forward-mode chain rule (N columns, not M rows), carried beside the activations so
        # that each weight matrix is read once per evaluation: [a | ∂a/∂θ] is (B, H, 1 + N).
        j1 = (1 - a1 * a1).unsqueeze(-1) * (self.w1[:, :n] * self.input_inverse[:n])
        y2 = torch.matmul(self.w2, torch.cat([a1.unsqueeze(-1), j1], dim=-1))
        a2 = torch.tanh(y2[..., 0] + self.b2)
        j2 = (1 - a2 * a2).unsqueeze(-1) * y2[..., 1:]
        y3 = torch.matmul(self.w3, torch.cat([a2.unsqueeze(-1), j2], dim=-1))  # (B, M, 1+N)
        scale = self.length_scale.unsqueeze(-1)
        return (y3[..., 0] + self.b3) * self.length_scale, y3[..., 1:] * scale
