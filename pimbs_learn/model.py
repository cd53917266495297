"""The body-schema network h(θ) (AL-Map) or h(θ, f) (ATL-Map) → muscle lengths l.

The paper's network: three fully connected layers in → 1000 → 1000 → M, tanh after the
first two. The functions here are written once on a plain dict of weight tensors with
arbitrary leading dimensions, so the reference trainer (one nn.Module), the fast trainer
(R runs stacked along a leading axis, trained at once) and the loaded model all run the very
same arithmetic.

Scaling is purely multiplicative (x = θ/θ_s, x_f = f/f_s, l = l_s·out) so that θ = 0, f = 0
in physical units is exactly input 0 — the constraint h(0, 0) = 0 needs that — and the
network's Jacobian converts to physical units by two diagonal factors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from pimbs_learn.widths import DEFAULT_HIDDEN, HIDDEN  # noqa: F401 (re-exported)

PARAM_NAMES = ("w1", "b1", "w2", "b2", "w3", "b3")
Params = dict[str, torch.Tensor]

# Floors keep a scale finite when a training set happens to hold only zeros in a column.
_THETA_FLOOR = 1e-3  # rad
_TENSION_FLOOR = 1.0  # N
_LENGTH_FLOOR = 1e-4  # m


@dataclass(frozen=True)
class Scaling:
    """Physical units per unit of network input/output, chosen from the training data.

    theta: (N,) rad; tension: (M,) N, or None for an AL-Map; length: (M,) m.
    """

    theta: np.ndarray
    tension: np.ndarray | None
    length: np.ndarray

    @classmethod
    def from_data(cls, theta: np.ndarray, tension: np.ndarray | None,
                  length: np.ndarray) -> Scaling:
        """Per-joint max |θ|; one max |f| and one max |l| shared by all muscles.

        Shared tension/length scales keep the relative size of muscles intact, and a
        muscle that barely moved in a small training set does not get a huge input gain.
        """
        th = np.maximum(np.abs(theta).max(axis=0), _THETA_FLOOR)
        m = length.shape[1]
        ls = np.full(m, max(float(np.abs(length).max()), _LENGTH_FLOOR))
        fs = None
        if tension is not None:
            fs = np.full(m, max(float(np.abs(tension).max()), _TENSION_FLOOR))
        return cls(th.astype(np.float64), fs, ls)

    @property
    def n_inputs(self) -> int:
        return len(self.theta) + (0 if self.tension is None else len(self.tension))

    def input_inverse(self) -> np.ndarray:
        """(D,) factors that turn physical inputs [θ, f] into network inputs."""
        parts = [1.0 / self.theta]
        if self.tension is not None:
            parts.append(1.0 / self.tension)
        return np.concatenate(parts)

    def to_json(self) -> dict[str, Any]:
        return {
            "theta": self.theta.tolist(),
            "tension": None if self.tension is None else self.tension.tolist(),
            "length": self.length.tolist(),
            "rule": "x = [theta/theta_s, f/f_s], l = length_s * out (no offsets)",
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Scaling:
        t = d.get("tension")
        return cls(np.asarray(d["theta"], float), None if t is None else np.asarray(t, float),
                   np.asarray(d["length"], float))


def init_params(n_in: int, n_out: int, seed: int, hidden: int = HIDDEN,
                dtype: torch.dtype = torch.float32) -> Params:
    """nn.Linear's default initialisation, drawn from a seeded generator.

    Both trainers start from this, so a benchmark compares them from identical weights.
    Biases are stored as (1, H) rows so that stacked runs (R, 1, H) broadcast over samples.
    """
    g = torch.Generator().manual_seed(int(seed))
    p: Params = {}
    for i, (fi, fo) in enumerate(((n_in, hidden), (hidden, hidden), (hidden, n_out)), 1):
        bound = 1.0 / math.sqrt(fi)
        p[f"w{i}"] = (torch.rand(fo, fi, generator=g, dtype=torch.float64) * 2 - 1) * bound
        p[f"b{i}"] = (torch.rand(1, fo, generator=g, dtype=torch.float64) * 2 - 1) * bound
    return {k: v.to(dtype) for k, v in p.items()}


def hidden_layers(p: Params, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Activations a1, a2 of the two tanh layers for network inputs x (..., B, D)."""
    a1 = torch.tanh(x @ p["w1"].mT + p["b1"])
    a2 = torch.tanh(a1 @ p["w2"].mT + p["b2"])
    return a1, a2


def output_length(p: Params, a2: torch.Tensor, length_scale: torch.Tensor) -> torch.Tensor:
    """Muscle lengths in metres from the second hidden layer."""
    return (a2 @ p["w3"].mT + p["b3"]) * length_scale


def gtf(p: Params, a1: torch.Tensor, a2: torch.Tensor, f: torch.Tensor,
        length_scale: torch.Tensor, theta_inverse: torch.Tensor) -> torch.Tensor:
    """Gᵀf (..., B, N) in N·m with G = ∂h/∂θ, by the chain rule run backwards once.

    Gᵀf = diag(1/θ_s) W1θᵀ[(1−a1²) ⊙ W2ᵀ[(1−a2²) ⊙ W3ᵀ(l_s ⊙ f)]]: three thin matmuls per
    sample instead of M backward passes, and differentiable by autograd like any forward.
    """
    n = theta_inverse.shape[-1]
    q2 = ((f * length_scale) @ p["w3"]) * (1 - a2 * a2)
    q1 = (q2 @ p["w2"]) * (1 - a1 * a1)
    return (q1 @ p["w1"][..., :n]) * theta_inverse


def jacobian(p: Params, a1: torch.Tensor, a2: torch.Tensor, length_scale: torch.Tensor,
             theta_inverse: torch.Tensor) -> torch.Tensor:
    """Full muscle Jacobian G = ∂l/∂θ, (..., B, M, N) in m/rad, in closed form."""
    n = theta_inverse.shape[-1]
    j1 = (1 - a1 * a1).unsqueeze(-1) * p["w1"][..., :n].unsqueeze(-3)  # (B, H, N)
    j2 = (1 - a2 * a2).unsqueeze(-1) * (p["w2"].unsqueeze(-3) @ j1)  # (B, H, N)
    g = p["w3"].unsqueeze(-3) @ j2  # (B, M, N)
    return g * length_scale.unsqueeze(-1) * theta_inverse.unsqueeze(-2)


def network_inputs(theta: torch.Tensor, tension: torch.Tensor | None,
                   input_inverse: torch.Tensor) -> torch.Tensor:
    """Scaled network inputs [θ/θ_s, f/f_s] (or θ/θ_s for an AL-Map)."""
    x = theta if tension is None else torch.cat([theta, tension], dim=-1)
    return x * input_inverse


class BodySchemaNet(torch.nn.Module):
    """One body-schema network as an nn.Module, in physical units (used by the reference)."""

    def __init__(self, params: Params, scaling: Scaling) -> None:
        super().__init__()
        self.p = torch.nn.ParameterDict({k: torch.nn.Parameter(v.clone()) for k, v in
                                         params.items()})
        dtype = params["w1"].dtype
        self.atl = scaling.tension is not None
        self.register_buffer("input_inverse", torch.tensor(scaling.input_inverse(), dtype=dtype))
        self.register_buffer("length_scale", torch.tensor(scaling.length, dtype=dtype))

    @property
    def params(self) -> Params:
        return dict(self.p.items())

    def forward(self, theta: torch.Tensor, tension: torch.Tensor | None = None) -> torch.Tensor:
        x = network_inputs(theta, tension if self.atl else None, self.input_inverse)
        _, a2 = hidden_layers(self.params, x)
        return output_length(self.params, a2, self.length_scale)
