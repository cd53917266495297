"""How well the torque balance can be known from the training samples: a Gaussian-process
estimate of the length and torque noise that no flexible network can drive down.

Why: the automatic physics weight (:mod:`pimbs_learn.objective`) divides each residual by
its own profiled variance. A 1M-parameter network interpolates 5–30 samples, so both
training residuals reach their floors whether the torques are right or not — on a
friction-concealed arm it then fits the wrong torques exactly. The evidence (marginal
likelihood) of a smooth model that explains lengths and torques together is not fooled by
interpolation: when the torques disagree with what the lengths imply, the most probable
explanation is torque noise, and σ_τ comes out large. That σ_τ² is the torque variance's
floor in training, so the physics weight backs off by itself.

The model, per muscle m (lengths and angles scaled as the network scales them):
l_m(θ, f) = g_m(θ) + β_m·[1, x] + c_m·φ(f_m) + ε_l, with g_m ~ GP(0, s²·RBF(ℓ)) shared
hyperparameters across muscles, and the torque balance τ = −Gᵀf + ε_τ with
G = ∂(g + β·x)/∂θ. Every observation is linear in the latent function values and
derivatives, so the evidence is one Gaussian; (s, ℓ, σ_l, σ_τ) maximise it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from pimbs_learn.graph import elastic_basis
from pimbs_learn.model import Scaling

# Prior variance of the explicit basis coefficients (offset, slope, spring), in scaled units
# (lengths ≤ 1, x ≤ 1): broad enough not to bias, finite so the evidence is defined.
_BASIS_PRIOR = 1.0
# Most observations used for the estimate (S samples give S·(M+N)): the evidence needs a
# Cholesky of that square, 0.2–5 s for 300 steps on one core; more samples are subsampled.
MAX_OBSERVATIONS = 400
_STEPS = 300


@dataclass(frozen=True)
class NoiseEstimate:
    """rms length noise (m) and rms torque noise (N·m) the evidence supports."""

    length_rms: float
    torque_rms: float
    length_scale: float  # RBF length-scale in scaled θ units
    evidence: float  # log marginal likelihood per observation


def _kernel_blocks(x: torch.Tensor, ell: torch.Tensor
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Unit-amplitude RBF covariances of g (S,S), ∂g/∂x with g (S,N,S), ∂g with ∂g
    (S,N,S,N) at the S points x (S,N)."""
    d = x[:, None, :] - x[None, :, :]  # (S,S,N) x_i − x_k
    k = torch.exp(-0.5 * (d * d).sum(-1) / ell**2)
    kd = -(d / ell**2) * k[..., None]  # cov(∂_j g(x_i), g(x_k)) (S,S,N)
    eye = torch.eye(x.shape[1], dtype=x.dtype)
    kdd = (eye / ell**2 - d[..., :, None] * d[..., None, :] / ell**4) * k[..., None, None]
    return k, kd.permute(0, 2, 1), kdd.permute(0, 2, 1, 3)


def _basis(x: np.ndarray, tension: np.ndarray, tension_s: np.ndarray) -> torch.Tensor:
    """(S·M + S·N, M·(1+N+2)) map from each muscle's offset, slope and spring coefficients
    to the observations [lengths (i, m), torques (i, j)]: the explicit part of the model."""
    s, n = x.shape
    m = tension.shape[1]
    k = 1 + n + 2
    phi = elastic_basis(torch.as_tensor(tension), torch.as_tensor(tension_s)).numpy()
    b = np.zeros((s * m + s * n, m * k))
    for mu in range(m):
        rows = np.arange(s) * m + mu
        b[rows, mu * k] = 1.0
        b[rows, mu * k + 1:mu * k + 1 + n] = x
        b[rows, mu * k + 1 + n:(mu + 1) * k] = phi[:, :, mu]
        for j in range(n):  # τ_ij = −Σ_m f_im·∂l̃_m/∂x_j: the slope's share
            b[s * m + np.arange(s) * n + j, mu * k + 1 + j] = -tension[:, mu]
    return torch.as_tensor(b)


def _gp_covariance(x: torch.Tensor, f: torch.Tensor, ell: torch.Tensor) -> torch.Tensor:
    """Unit-amplitude covariance of the observations from the GP part g:
    cov(l_im, l_km') = δ_mm'·k_ik, cov(τ_ij, l_km) = −f_im·∂_j k_ik,
    cov(τ_ij, τ_kl) = (f_i·f_k)·∂_j∂'_l k_ik."""
    s, n = x.shape
    m = f.shape[1]
    k, kd, kdd = _kernel_blocks(x, ell)  # (S,S), (S,N,S), (S,N,S,N)
    ll = torch.kron(k, torch.eye(m, dtype=x.dtype))
    tl = (-f[:, None, None, :] * kd[..., None]).reshape(s * n, s * m)
    tt = ((f @ f.T)[:, None, :, None] * kdd).reshape(s * n, s * n)
    return torch.cat([torch.cat([ll, tl.T], 1), torch.cat([tl, tt], 1)], 0)


def estimate_noise(theta: np.ndarray, tension: np.ndarray, length: np.ndarray,
                   tau: np.ndarray, seed: int = 0) -> NoiseEstimate:
    """Noise levels of lengths and torques that maximise the evidence (see module doc)."""
    rng = np.random.default_rng(seed)
    most = max(3, MAX_OBSERVATIONS // (theta.shape[1] + length.shape[1]))
    if theta.shape[0] > most:
        keep = np.sort(rng.permutation(theta.shape[0])[:most])
        theta, tension, length, tau = theta[keep], tension[keep], length[keep], tau[keep]
    s, n = theta.shape
    m = length.shape[1]
    scale = Scaling.from_data(theta, tension, length)  # the network's own scales
    th_s, l_s, f_s = scale.theta, float(scale.length[0]), scale.tension
    x = theta / th_s
    # torque in N·m = −Σ f·∂l/∂θ = −Σ f·(l_s/θ_s,j)·∂l̃/∂x_j; divide τ_j by l_s/θ_s,j so
    # the design needs only f, then restore the unit of σ_τ per joint by the same factor
    t_unit = l_s / th_s  # (N,)
    b = _basis(x, tension, f_s)
    y = torch.as_tensor(np.concatenate([(length / l_s).ravel(), (tau / t_unit).ravel()]))
    xt, ft = torch.as_tensor(x), torch.as_tensor(tension)
    n_len = s * m
    base = b @ b.T * _BASIS_PRIOR
    tau_rms = float(np.sqrt(np.mean((tau / t_unit) ** 2))) + 1e-12
    # log hyperparameters: amplitude s, length-scale ℓ, σ_l (scaled), σ_τ (scaled units)
    z = torch.tensor([math.log(0.1), math.log(1.0), math.log(1e-3), math.log(0.1 * tau_rms)],
                     dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([z], lr=0.05)
    is_len = torch.arange(len(y)) < n_len
    # floors keep the covariance well conditioned where a noise would fit exactly
    low = torch.tensor([-12.0, -5.0, math.log(1e-7), math.log(1e-7 * tau_rms)],
                       dtype=torch.float64)

    def nll() -> torch.Tensor:
        amp, ell, sl, st = torch.exp(torch.maximum(z, low))
        noise = torch.where(is_len, sl**2, st**2)
        cov = amp**2 * _gp_covariance(xt, ft, ell) + base + torch.diag(noise + 1e-10)
        chol = torch.linalg.cholesky(cov)
        alpha = torch.cholesky_solve(y[:, None], chol)
        return 0.5 * (y @ alpha[:, 0]) + torch.log(torch.diagonal(chol)).sum()

    for _ in range(_STEPS):
        opt.zero_grad()
        loss = nll()
        loss.backward()
        opt.step()
    with torch.no_grad():
        final = float(nll())
        _, ell, sl, st = torch.exp(torch.maximum(z, low)).tolist()
    torque_rms = float(st * np.sqrt(np.mean(t_unit**2)))
    return NoiseEstimate(length_rms=sl * l_s, torque_rms=torque_rms, length_scale=ell,
                         evidence=-final / len(y))
