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
# Most observations used for the estimate (S samples give S·(M+N)): each of the 300 steps
# needs a Cholesky of that square and its inverse, so this cap bounds the estimate's time
# (about 2.5 s on one core at the cap, 0.3 s at 180 observations); more samples are
# subsampled.
MAX_OBSERVATIONS = 400
_STEPS = 300


@dataclass(frozen=True)
class NoiseEstimate:
    """rms length noise (m) and rms torque noise (N·m) the evidence supports."""

    length_rms: float
    torque_rms: float
    length_scale: float  # RBF length-scale in scaled θ units
    evidence: float  # log marginal likelihood per observation
    # leave-one-sample-out squared length errors (scaled units, summed over muscles), one
    # per sample used: predicted from the other samples' lengths and torques, and from
    # their lengths alone (same hyperparameters). What the torques add to a length
    # prediction at a pose not trained on: the question the physics term answers.
    loo_with_torque: np.ndarray | None = None
    loo_without_torque: np.ndarray | None = None


def _kernel_blocks(x: torch.Tensor, ell: float
                   ) -> tuple[tuple[torch.Tensor, ...], tuple[torch.Tensor, ...]]:
    """Unit-amplitude RBF covariances of g (S,S), ∂g/∂x with g (S,N,S), ∂g with ∂g
    (S,N,S,N) at the S points x (S,N), and their derivatives with respect to log ℓ.

    With q = |x_i − x_k|²/ℓ²: ∂k/∂log ℓ = k·q, ∂kd/∂log ℓ = kd·(q − 2) and
    ∂kdd/∂log ℓ = (−2I/ℓ² + 4·ddᵀ/ℓ⁴)·k + (I/ℓ² − ddᵀ/ℓ⁴)·k·q.
    """
    d = x[:, None, :] - x[None, :, :]  # (S,S,N) x_i − x_k
    q = (d * d).sum(-1) / ell**2
    k = torch.exp(-0.5 * q)
    kd = -(d / ell**2) * k[..., None]  # cov(∂_j g(x_i), g(x_k)) (S,S,N)
    eye = torch.eye(x.shape[1], dtype=x.dtype)
    outer = d[..., :, None] * d[..., None, :] / ell**4
    shape = (eye / ell**2 - outer)
    kdd = shape * k[..., None, None]
    dkdd = (4 * outer - 2 * eye / ell**2) * k[..., None, None] + kdd * q[..., None, None]
    dkd = kd * (q - 2)[..., None]

    def arranged(a: torch.Tensor, b: torch.Tensor, c: torch.Tensor) -> tuple[torch.Tensor, ...]:
        return a, b.permute(0, 2, 1), c.permute(0, 2, 1, 3)

    return arranged(k, kd, kdd), arranged(k * q, dkd, dkdd)


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


def _gp_covariance(blocks: tuple[torch.Tensor, ...], f: torch.Tensor) -> torch.Tensor:
    """Unit-amplitude covariance of the observations from the GP part g, from the kernel
    blocks k (S,S), kd (S,N,S), kdd (S,N,S,N) (or their derivatives: the map is linear):
    cov(l_im, l_km') = δ_mm'·k_ik, cov(τ_ij, l_km) = −f_im·∂_j k_ik,
    cov(τ_ij, τ_kl) = (f_i·f_k)·∂_j∂'_l k_ik."""
    k, kd, kdd = blocks
    s, n = kd.shape[:2]
    m = f.shape[1]
    ll = torch.kron(k, torch.eye(m, dtype=k.dtype))
    tl = (-f[:, None, None, :] * kd[..., None]).reshape(s * n, s * m)
    tt = ((f @ f.T)[:, None, :, None] * kdd).reshape(s * n, s * n)
    return torch.cat([torch.cat([ll, tl.T], 1), torch.cat([tl, tt], 1)], 0)


def _nll_and_grad(z: np.ndarray, low: np.ndarray, xt: torch.Tensor, ft: torch.Tensor,
                  y: torch.Tensor, base: torch.Tensor, is_len: torch.Tensor,
                  with_grad: bool = True) -> tuple[float, np.ndarray]:
    """Negative log evidence of the log hyperparameters z and its gradient, by hand.

    ∂nll/∂z_i = ½·Σ (K⁻¹ − ααᵀ) ⊙ ∂K/∂z_i with α = K⁻¹y: one Cholesky and its inverse per
    step, where autograd through the Cholesky cost five times as much.
    """
    u = np.maximum(z, low)
    amp, ell, sl, st = np.exp(u)
    blocks, dblocks = _kernel_blocks(xt, float(ell))
    kgp = _gp_covariance(blocks, ft)
    noise = torch.where(is_len, sl**2, st**2)
    cov = amp**2 * kgp + base + torch.diag(noise + 1e-10)
    chol = torch.linalg.cholesky(cov)
    alpha = torch.cholesky_solve(y[:, None], chol)[:, 0]
    nll = float(0.5 * (y @ alpha) + torch.log(torch.diagonal(chol)).sum())
    if not with_grad:
        return nll, np.zeros_like(z)
    w = torch.cholesky_inverse(chol) - alpha[:, None] * alpha[None, :]  # K⁻¹ − ααᵀ
    wd = torch.diagonal(w)
    grad = np.array([
        float((w * kgp).sum()) * amp**2,  # ∂K/∂log s = 2s²·K_gp, times ½
        0.5 * amp**2 * float((w * _gp_covariance(dblocks, ft)).sum()),
        float(wd[is_len].sum()) * sl**2,  # ∂K/∂log σ = 2σ² on its diagonal, times ½
        float(wd[~is_len].sum()) * st**2])
    # torch.maximum's subgradient, as autograd took it: 1 above the floor, ½ at it
    return nll, grad * np.where(z > low, 1.0, np.where(z == low, 0.5, 0.0))


def _maximise_evidence(z: np.ndarray, low: np.ndarray, xt: torch.Tensor, ft: torch.Tensor,
                       y: torch.Tensor, base: torch.Tensor, is_len: torch.Tensor
                       ) -> np.ndarray:
    """The log hyperparameters after Adam on the negative log evidence, from ``z``."""
    # Adam (lr 0.05, torch's defaults otherwise), written out for four numbers
    m1, m2 = np.zeros(4), np.zeros(4)
    b1, b2, lr, eps = 0.9, 0.999, 0.05, 1e-8
    for step in range(1, _STEPS + 1):
        _, g = _nll_and_grad(z, low, xt, ft, y, base, is_len)
        m1 = b1 * m1 + (1 - b1) * g
        m2 = b2 * m2 + (1 - b2) * g * g
        denom = np.sqrt(m2) / math.sqrt(1 - b2**step) + eps
        z = z - (lr / (1 - b1**step)) * m1 / denom
    return z


def _sensor_columns(z: np.ndarray, low: np.ndarray, xt: torch.Tensor, ft: torch.Tensor,
                    y: torch.Tensor, b: torch.Tensor, base: torch.Tensor,
                    is_len: torch.Tensor, f_s: np.ndarray) -> torch.Tensor:
    """(observations, 2M+N) how each sensor term of :mod:`pimbs_learn.sensor_terms` moves the
    scaled torque observations, with a unit prior on each. The balance Gᵀf'/k + τ = 0 gives,
    to first order in the z, τ = −Gᵀf − Gᵀ(f' − f) − (k − 1)·τ: linear in the z for a given
    G, so G is plugged in at its posterior mean under the fit without them (the error of
    that is second order: an unknown G times an error already small)."""
    from pimbs_learn import sensor_terms

    amp, ell, sl, st = np.exp(np.maximum(z, low)).tolist()
    (k, kd, kdd), _ = _kernel_blocks(xt, float(ell))
    s, n = kd.shape[:2]
    m = ft.shape[1]
    noise = torch.where(is_len, sl**2, st**2)
    cov = amp**2 * _gp_covariance((k, kd, kdd), ft) + base + torch.diag(noise + 1e-10)
    alpha = torch.cholesky_solve(y[:, None], torch.linalg.cholesky(cov))[:, 0]
    a_l, a_t = alpha[:s * m].reshape(s, m), alpha[s * m:].reshape(s, n)
    # E[∂_j g_m(x_i)] = s²·(Σ_k kd_ijk·α_l,km − Σ_kl f_km·kdd_ijkl·α_τ,kl)
    dg = amp**2 * (torch.einsum("ijk,km->imj", kd, a_l)
                   - torch.einsum("km,ijkl,kl->imj", ft, kdd, a_t))
    coef = (b.T @ alpha) * _BASIS_PRIOR  # posterior mean of offsets, slopes, springs
    slope = coef.reshape(m, -1)[:, 1:1 + n]  # (M, N)
    grad = dg + slope[None]  # (S, M, N) ∂l̃/∂x at each sample
    rows = torch.zeros(len(y), 2 * m + n, dtype=y.dtype)
    torque_rows = slice(s * m, None)
    gain = -sensor_terms.GAIN_SD * ft[:, :, None] * grad  # (S, M, N)
    offset = -sensor_terms.OFFSET_SD * torch.as_tensor(f_s)[None, :, None] * grad
    rows[torque_rows, :m] = gain.permute(0, 2, 1).reshape(s * n, m)
    rows[torque_rows, m:2 * m] = offset.permute(0, 2, 1).reshape(s * n, m)
    y_t = y[s * m:].reshape(s, n)
    gravity = -sensor_terms.GRAVITY_SD * torch.diag_embed(y_t)  # (S, N, N)
    rows[torque_rows, 2 * m:] = gravity.reshape(s * n, n)
    return rows


def estimate_noise(theta: np.ndarray, tension: np.ndarray, length: np.ndarray,
                   tau: np.ndarray, seed: int = 0, sensors: bool = False) -> NoiseEstimate:
    """Noise levels of lengths and torques that maximise the evidence (see module doc);
    with ``sensors``, the torque balance may also carry the loadcell and gravity errors of
    :mod:`pimbs_learn.sensor_terms` (so a consistent error there is not taken for noise)."""
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
    z = np.array([math.log(0.1), math.log(1.0), math.log(1e-3), math.log(0.1 * tau_rms)])
    is_len = torch.arange(len(y)) < n_len
    # floors keep the covariance well conditioned where a noise would fit exactly
    low = np.array([-12.0, -5.0, math.log(1e-7), math.log(1e-7 * tau_rms)])
    z = _maximise_evidence(z, low, xt, ft, y, base, is_len)
    if sensors:
        cols = _sensor_columns(z, low, xt, ft, y, b, base, is_len, f_s)
        base = base + cols @ cols.T
        z = _maximise_evidence(z, low, xt, ft, y, base, is_len)
    final, _ = _nll_and_grad(z, low, xt, ft, y, base, is_len, with_grad=False)
    amp, ell, sl, st = np.exp(np.maximum(z, low)).tolist()
    torque_rms = float(st * np.sqrt(np.mean(t_unit**2)))
    blocks, _ = _kernel_blocks(xt, float(ell))
    noise = torch.where(is_len, sl**2, st**2)
    cov = amp**2 * _gp_covariance(blocks, ft) + base + torch.diag(noise + 1e-10)
    sample = torch.cat([torch.arange(s).repeat_interleave(m), torch.arange(s).repeat_interleave(n)])
    with_t = _loo_length_sse(cov, y, sample, is_len, s)
    only_l = _loo_length_sse(cov[:n_len, :n_len], y[:n_len], sample[:n_len],
                             is_len[:n_len], s)
    return NoiseEstimate(length_rms=sl * l_s, torque_rms=torque_rms, length_scale=ell,
                         evidence=-final / len(y), loo_with_torque=with_t,
                         loo_without_torque=only_l)


def _loo_length_sse(cov: torch.Tensor, y: torch.Tensor, sample: torch.Tensor,
                    is_len: torch.Tensor, s: int) -> np.ndarray:
    """(S,) squared length error of each sample predicted from all the others (its lengths
    and torques left out together), summed over muscles.

    Closed form for a Gaussian: with P = C⁻¹ and the held-out block I, the prediction error
    is y_I − E[y_I | rest] = (P_II)⁻¹·(P·y)_I.
    """
    chol = torch.linalg.cholesky(cov)
    prec = torch.cholesky_inverse(chol)
    py = prec @ y
    out = np.zeros(s)
    for i in range(s):
        idx = torch.nonzero(sample == i).flatten()
        err = torch.linalg.solve(prec[idx][:, idx], py[idx])
        out[i] = float((err[is_len[idx]] ** 2).sum())
    return out


def noise_of(samples, seed: int = 0, sensors: bool = False) -> NoiseEstimate | None:
    """:func:`estimate_noise` of a sample set (anything with ``theta``, ``tension``,
    ``length`` and ``tau``), or None where it is degenerate for the Gaussian process. The
    automatic weight's floor and the self-check both read this one fit."""
    try:
        return estimate_noise(samples.theta, samples.tension, samples.length, samples.tau,
                              seed=seed, sensors=sensors)
    except torch.linalg.LinAlgError:
        return None
