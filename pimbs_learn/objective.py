"""The training objective of stacked runs, and its gradient written out by hand.

:func:`objective` is the definition (model + losses, differentiable by autograd).
:func:`objective_and_grads` computes the same value and its exact gradient with explicit
matmuls: no autograd graph, no double backward, and the two W2 weight-gradient products
(from L_basic and from L_pinn) fused into one matmul. Tests check it against autograd.

Shapes: R stacked runs, B training rows (+1 all-zero row for h(0, 0)), D inputs, H hidden,
M muscles, N joints, K elastic basis functions.

Automatic physics weight (``auto``): the residuals of lengths and torques are treated as
Gaussian with unknown variances, profiled out. The negative log-likelihood per sample is
(M/2)·log mse_l + (N/2)·log mse_τ; its gradient, rescaled by mse_l (Adam does not see a
common scale), is ∇mse_l + α_eff·∇mse_τ with α_eff = (N/M)·mse_l/mse_τ. Each variance has
a floor relative to the data's own scale, so α_eff is dimensionless in use and needs no
unit choice. The torque floor is also the torque noise that the evidence of a smooth model
supports (:mod:`pimbs_learn.noise`): a large network interpolates its few samples, wrong
torques included, so its own residual cannot tell a wrong torque balance (friction,
offsets) from a right one, and α_eff falls by itself only through that floor.
α_eff is recomputed every epoch and held constant within it (iteratively re-weighted
least squares).

Sensor terms (``sensors``, :mod:`pimbs_learn.sensor_terms`): the torque balance uses the
tensions and gravity torques corrected by fitted loadcell and gravity errors, whose unit
Gaussian prior enters the same profiled likelihood: its gradient, rescaled like the rest,
is (2·max(mse_l, floor)/(B·M))·z.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import torch

from pimbs_learn import sensor_terms
from pimbs_learn.losses import basic_loss, const_loss
from pimbs_learn.model import Params, gtf, hidden_layers, output_length


@dataclass(frozen=True)
class Batch:
    """Full-batch training tensors of R runs."""

    x: torch.Tensor  # (R, B+1, D) scaled inputs; row B is all zeros (θ = 0, f = 0)
    length: torch.Tensor  # (R, B, M) m
    tension: torch.Tensor  # (R, B, M) N
    tau: torch.Tensor  # (R, B, N) N·m
    length_scale: torch.Tensor  # (R, 1, M)
    theta_inverse: torch.Tensor  # (R, 1, N)
    const_weight: torch.Tensor  # (R,) 0 or 1
    pinn_weight: torch.Tensor  # (R,) α, or 0 without L_pinn (auto: multiplier of α_eff)
    phi: torch.Tensor | None = None  # (R, B+1, K, M) elastic basis (series-elastic), row B 0
    auto: torch.Tensor | None = None  # (R,) 1 where α is automatic
    length_floor: torch.Tensor | None = None  # (R,) m², floor of mse_l (auto)
    torque_floor: torch.Tensor | None = None  # (R,) N²·m², floor of mse_τ (auto)
    sensors: torch.Tensor | None = None  # (R,) 1 where the torque balance has sensor terms
    tension_scale: torch.Tensor | None = None  # (R, 1, M) N, the offsets' unit (sensors)

    # cached: on a GPU each evaluation would be a host sync, once per epoch
    @cached_property
    def use_const(self) -> bool:
        return bool((self.const_weight != 0).any())

    @cached_property
    def use_pinn(self) -> bool:
        return bool((self.pinn_weight != 0).any())

    @cached_property
    def use_auto(self) -> bool:
        return self.auto is not None and bool((self.auto != 0).any())

    @cached_property
    def use_sensors(self) -> bool:
        return self.sensors is not None and bool((self.sensors != 0).any())


# The trainer holds the elastic coefficients as c / ELASTIC_GAIN: Adam moves every
# parameter by about lr per epoch, and a coefficient of order 0.1–1 must settle within tens
# of epochs, before the network's bias b3 and curvature absorb the spring's share of the
# lengths. Saved models hold c itself.
ELASTIC_GAIN = 30.0


def elastic_length(p: Params, phi: torch.Tensor | None, ls: torch.Tensor) -> torch.Tensor | float:
    """e(f) = l_s·Σ_k c_k φ_k(f), (R, B+1, M), or 0 without the series-elastic term."""
    if phi is None:
        return 0.0
    return (phi * (ELASTIC_GAIN * p["c"]).unsqueeze(-3)).sum(dim=-2) * ls


def predicted_length(p: Params, a2: torch.Tensor, batch: Batch) -> torch.Tensor:
    return output_length(p, a2, batch.length_scale) + elastic_length(p, batch.phi,
                                                                     batch.length_scale)


def pinn_weight(batch: Batch, lb: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
    """(R,) weight of mse_τ this epoch: α (fixed) or α·(N/M)·max(mse_l, floor)/max(mse_τ, floor)."""
    if not batch.use_auto:
        return batch.pinn_weight
    assert batch.auto is not None and batch.length_floor is not None
    assert batch.torque_floor is not None
    m, n = batch.length.shape[-1], batch.tau.shape[-1]
    mse_t = (residual * residual).mean(dim=(-2, -1))
    ratio = (n / m) * torch.maximum(lb, batch.length_floor) / torch.maximum(
        mse_t, batch.torque_floor)
    return batch.pinn_weight * torch.where(batch.auto != 0, ratio, torch.ones_like(ratio))


def _sensor_params(p: Params, batch: Batch) -> Params | None:
    """The sensor terms' z of runs that have them (held as z / STEP_GAIN); zero on the
    others; None where no run has them."""
    if not batch.use_sensors:
        return None
    assert batch.sensors is not None
    mask = batch.sensors.view(-1, 1, 1) * sensor_terms.STEP_GAIN
    return {k: p[k] * mask for k in sensor_terms.KEYS}


def balance_tension(z: Params | None, batch: Batch) -> torch.Tensor:
    """f of the torque balance: as recorded, or corrected by the sensor terms' ``z``
    (:func:`_sensor_params`; None without sensor terms)."""
    if z is None:
        return batch.tension
    assert batch.tension_scale is not None
    return sensor_terms.tension(z, batch.tension, batch.tension_scale)


def balance_residual(z: Params | None, batch: Batch, g: torch.Tensor) -> torch.Tensor:
    """The torque balance's residual from g = Gᵀf: g + τ, or with the gravity scales."""
    if z is None:
        return g + batch.tau
    return sensor_terms.residual(z, g, batch.tau)


def sensor_prior_weight(batch: Batch, lb: torch.Tensor) -> torch.Tensor:
    """(R,) weight of Σz² in L_train: α's multiplier·max(mse_l, floor)/(B·M) on runs with
    sensor terms (the unit prior in the profiled likelihood, rescaled like its other terms),
    0 elsewhere."""
    assert batch.sensors is not None and batch.length_floor is not None
    b, m = batch.length.shape[1:]
    return (batch.sensors * batch.pinn_weight * torch.maximum(lb, batch.length_floor)
            / (b * m))


def objective(p: Params, batch: Batch) -> tuple[torch.Tensor, torch.Tensor]:
    """(L_train, L_basic), each (R,): the definition the hand-written gradient must match."""
    b = batch.length.shape[1]
    a1, a2 = hidden_layers(p, batch.x)
    l_pred = predicted_length(p, a2, batch)
    lb = basic_loss(l_pred[:, :b], batch.length)
    total = lb + batch.const_weight * const_loss(l_pred[:, b])
    if batch.use_pinn:
        z = _sensor_params(p, batch)
        g = gtf(p, a1[:, :b], a2[:, :b], balance_tension(z, batch), batch.length_scale,
                batch.theta_inverse)
        res = balance_residual(z, batch, g)
        w = pinn_weight(batch, lb, res).detach()
        total = total + w * (res * res).mean(dim=(-2, -1))
        if z is not None:
            total = total + (sensor_prior_weight(batch, lb).detach()
                             * sensor_terms.prior_sum(z))
    return total, lb


def selection_score(batch: Batch, lb: torch.Tensor, residual: torch.Tensor | None,
                    prior: torch.Tensor | None = None) -> torch.Tensor:
    """(R,) what the selection rule minimises: L_basic (the paper's rule), or with the
    automatic weight the profiled negative log-likelihood per length observation,
    log max(mse_l, floor) + (N/M)·log max(mse_τ, floor) [+ Σz²/(B·M) with sensor terms,
    ``prior`` = Σz² (R,)] — the quantity that weight descends, so the epoch kept is the one
    that best explains lengths *and* torques."""
    if not batch.use_auto or residual is None:
        return lb
    assert batch.auto is not None and batch.length_floor is not None
    assert batch.torque_floor is not None
    b, m = batch.length.shape[1:]
    n = batch.tau.shape[-1]
    mse_t = (residual * residual).mean(dim=(-2, -1))
    nll = torch.log(torch.maximum(lb, batch.length_floor)) + (n / m) * torch.log(
        torch.maximum(mse_t, batch.torque_floor))
    if prior is not None:
        nll = nll + prior / (b * m)
    return torch.where(batch.auto != 0, nll, lb)


def objective_and_grads(p: Params, batch: Batch
                        ) -> tuple[torch.Tensor, Params, torch.Tensor]:
    """L_basic (R,), ∂(Σ_runs L_train)/∂p by reverse mode written out by hand, and the
    selection score (R,) of these weights (:func:`selection_score`).

    Forward: z1 = x W1ᵀ+b1, a1 = tanh z1, z2 = a1 W2ᵀ+b2, a2 = tanh z2, l = (a2 W3ᵀ+b3)·l_s.
    PINN branch (rows < B): v = f·l_s, q2 = (v W3)·s2, q1 = (q2 W2)·s1, g = (q1 W1θ)·θ_inv,
    with s = 1 − a². Backward visits these in reverse; ∂s/∂a = −2a.
    """
    w1, w2, w3 = p["w1"], p["w2"], p["w3"]
    x, ls = batch.x, batch.length_scale
    r, b, m = batch.length.shape
    n = batch.theta_inverse.shape[-1]
    a1, a2 = hidden_layers(p, x)
    s1, s2 = 1 - a1 * a1, 1 - a2 * a2
    l_pred = predicted_length(p, a2, batch)

    err = l_pred[:, :b] - batch.length
    lb = (err * err).mean(dim=(-2, -1))
    dl = torch.empty_like(l_pred)
    dl[:, :b] = err * (2.0 / (b * m))
    dl[:, b] = l_pred[:, b] * (batch.const_weight.view(r, 1) * (2.0 / m))
    do = dl * ls  # ∂L/∂(a2 W3ᵀ + b3)
    da2 = do @ w3
    g_w3 = do.mT @ a2

    res = prior = None
    if batch.use_pinn:
        z = _sensor_params(p, batch)
        v = balance_tension(z, batch) * ls
        p2 = v @ w3
        q2 = p2 * s2[:, :b]
        p1 = q2 @ w2
        q1 = p1 * s1[:, :b]
        g = (q1 @ w1[..., :n]) * batch.theta_inverse
        res = balance_residual(z, batch, g)
        dres = res * (pinn_weight(batch, lb, res).view(r, 1, 1) * (2.0 / (b * n)))
        dg = dres if z is None else dres / sensor_terms.gravity_factor(z)  # ∂res/∂g = 1/k
        dgs = dg * batch.theta_inverse
        dq1 = dgs @ w1[..., :n].mT
        dp1 = dq1 * s1[:, :b]
        dq2 = dp1 @ w2.mT
        dp2 = dq2 * s2[:, :b]
        g_w3 = g_w3 + v.mT @ dp2
        da2[:, :b] -= 2 * a2[:, :b] * (dq2 * p2)
        if z is not None:
            assert batch.sensors is not None and batch.tension_scale is not None
            prior = sensor_terms.prior_sum(z)
            mask = batch.sensors.view(r, 1, 1) * sensor_terms.STEP_GAIN
            sensor_grads = sensor_terms.grads(
                z, (dp2 @ w3.mT) * ls, dres, g, batch.tension, batch.tension_scale,
                sensor_prior_weight(batch, lb))

    dz2 = da2 * s2
    da1 = dz2 @ w2
    if batch.use_pinn:
        da1[:, :b] -= 2 * a1[:, :b] * (dq1 * p1)
        # both W2 products in one matmul: q2ᵀ dp1 + dz2ᵀ a1
        g_w2 = torch.cat([q2, dz2], dim=1).mT @ torch.cat([dp1, a1], dim=1)
    else:
        g_w2 = dz2.mT @ a1
    dz1 = da1 * s1
    g_w1 = dz1.mT @ x
    if batch.use_pinn:
        g_w1[..., :n] += q1.mT @ dgs
    grads = {"w1": g_w1, "b1": dz1.sum(dim=1, keepdim=True), "w2": g_w2,
             "b2": dz2.sum(dim=1, keepdim=True), "w3": g_w3,
             "b3": do.sum(dim=1, keepdim=True)}
    if batch.phi is not None:
        grads["c"] = ELASTIC_GAIN * (do.unsqueeze(-2) * batch.phi).sum(dim=1)
    if prior is not None:
        grads.update({k: v * mask for k, v in sensor_grads.items()})
    return lb, grads, selection_score(batch, lb, res, prior)
