"""One definition of a trained body schema as a plain tensor graph: θ, f → l, G.

:class:`SchemaGraph` is what ``load_body_schema`` evaluates and what ``pimbs export``
writes to ONNX. It uses only plain tensor ops (matmul, tanh, log1p, broadcasting): no
autograd, no numpy, no Python loop over the batch, so tracing it gives one static graph
with a free batch dimension. The input/output normalisation is inside.

G = ∂l/∂θ is exact, by forward-mode differentiation through the layers (the tangent of
every joint is carried along with the activations), not a finite difference.

Structures (``meta["structure"]``):

- ``mlp`` — the paper's network: x = [θ/θ_s, f/f_s] (ATL) or θ/θ_s (AL),
  l = l_s·(W3 tanh(W2 tanh(W1 x + b1) + b2) + b3).
- ``series-elastic`` — l = g(θ) + e(f): the same network on θ only, plus a per-muscle
  elastic term e_m(f_m) = l_s·Σ_k c_km φ_k(f_m) with φ = (log1p(f)/log1p(f_s), f/f_s),
  so e(0) = 0 and G = ∂g/∂θ does not depend on f (a wire in series with a spring).

With a geometric prior (tensors ``prior.*``, :mod:`pimbs_learn.prior`) the robot
description's model length h_geom(θ) − log1p(f)/K and its analytic G_geom are added: the
network is a correction.
"""

from __future__ import annotations

from typing import Any

import torch

from pimbs_learn.prior import PREFIX as PRIOR_PREFIX
from pimbs_learn.prior import GeometricPrior

MLP, SERIES_ELASTIC = "mlp", "series-elastic"
STRUCTURES = (MLP, SERIES_ELASTIC)
ELASTIC_BASIS = ("log1p(f)/log1p(f_s)", "f/f_s")


def elastic_basis(f: torch.Tensor, tension_scale: torch.Tensor) -> torch.Tensor:
    """φ(f), (..., K, M): each zero at f = 0 and about 1 at f = f_s."""
    return torch.stack([torch.log1p(f.clamp(min=0)) / torch.log1p(tension_scale),
                        f / tension_scale],
                       dim=-2)


class SchemaGraph(torch.nn.Module):
    """θ [B, N], f [B, M] → (length [B, M] m, G [B, M, N] m/rad) of one trained schema.

    Built from the weights and the JSON description of a model (see ``pimbs_learn.io``);
    the dtype of the weights is kept (``.float()`` it for float32 export).
    """

    def __init__(self, params: dict[str, torch.Tensor], meta: dict[str, Any]) -> None:
        super().__init__()
        sc = meta["scaling"]
        self.structure = meta.get("structure", MLP)
        if self.structure not in STRUCTURES:
            raise ValueError(f"unknown body-schema structure {self.structure!r}")
        self.n_joints = len(meta["joints"])
        self.n_muscles = len(meta["muscles"])
        self.atl = meta["map"] == "atl"
        dt = params["w1"].dtype
        for k in ("w1", "b1", "w2", "b2", "w3", "b3"):
            self.register_buffer(k, params[k].detach().clone())
        self.register_buffer("theta_inv", 1.0 / torch.tensor(sc["theta"], dtype=dt))
        self.register_buffer("length_scale", torch.tensor(sc["length"], dtype=dt))
        fs = sc.get("tension")
        self.register_buffer("tension_scale", torch.tensor(
            fs if fs is not None else [1.0] * self.n_muscles, dtype=dt))
        self.elastic = self.structure == SERIES_ELASTIC
        self.register_buffer("c", params["c"].detach().clone() if self.elastic
                             else torch.zeros(len(ELASTIC_BASIS), self.n_muscles, dtype=dt))
        prior = {k[len(PRIOR_PREFIX):]: v for k, v in params.items()
                 if k.startswith(PRIOR_PREFIX)}
        self.prior = GeometricPrior(prior) if prior else None
        # θ columns of W1 in physical units: ∂z1/∂θ = W1θ / θ_s, stored transposed (N, H)
        self.register_buffer("w1_theta_t", (self.w1[:, :self.n_joints]
                                            * self.theta_inv).transpose(-1, -2).contiguous())

    def forward(self, theta: torch.Tensor, tension: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        x = theta * self.theta_inv
        if self.atl and not self.elastic:
            x = torch.cat([x, tension / self.tension_scale], dim=-1)
        a1 = torch.tanh(x @ self.w1.transpose(-1, -2) + self.b1)
        a2 = torch.tanh(a1 @ self.w2.transpose(-1, -2) + self.b2)
        out = a2 @ self.w3.transpose(-1, -2) + self.b3
        if self.elastic:
            out = out + (elastic_basis(tension, self.tension_scale) * self.c).sum(dim=-2)
        # forward mode: tangents (B, N, H) of the hidden layers w.r.t. each joint
        t1 = self.w1_theta_t * (1 - a1 * a1).unsqueeze(-2)
        t2 = (t1 @ self.w2.transpose(-1, -2)) * (1 - a2 * a2).unsqueeze(-2)
        g = (t2 @ self.w3.transpose(-1, -2)).transpose(-1, -2) \
            * self.length_scale.unsqueeze(-1)  # (B, M, N)
        length = out * self.length_scale
        if self.prior is not None:
            h_geom, g_geom = self.prior(theta, tension)
            return length + h_geom, g + g_geom
        return length, g
