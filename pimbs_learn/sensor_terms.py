"""Sensor errors fitted inside the torque balance: loadcell gain and offset, tendon friction,
gravity scale.

Why: the physics term asks Gᵀf + τ = 0 of the recorded tensions f and the model's gravity
torques τ. On a real arm neither is exact: a loadcell reads with a gain and an offset
error, a tendon loses tension to friction on its way from the loadcell to the joint
(more or less depending on the direction it last moved), and a link is heavier or lighter
than its model. Each error is *consistent* across poses, so a network that must satisfy
the balance bends its G (the body schema's moment arms) to absorb it, and the physics then
hurts the lengths it was meant to help. Fitting the errors beside the network gives each
its own parameter:

    f' = f + Σ_c z_c·u_c                                          (per muscle)
    k  = 1 + GRAVITY_SD·z_gravity                                 (per joint)
    L_pinn = mean (Gᵀf' / k + τ)²

with one column u_c per kind of loadcell error (:func:`columns`):

    gain       GAIN_SD·f                    a loadcell's scale
    offset     OFFSET_SD·f_s                its zero (f_s: the largest recorded tension)
    friction   FRICTION_SD·a·f              capstan friction to first order: the joint
                                            sees f·e^(±μ), the sign that of the recorded
                                            approach a (+1 lengthening, −1 shortening)

A recording without approach (an import that had none) gives that column zeros, and its z
stays at the prior mean. A loadcell's thermal drift has no term: tried as a column in the
motor temperature, it was not told apart from the others (a temperature follows the load
and drifts slowly, like much else; docs/learning-notebook.md §20).

The gravity scale divides the tension side rather than multiplying τ: the residual stays
in the units of τ, whose noise the automatic weight knows, and a gain common to every
loadcell with the same gravity scale leaves it unchanged, as it should (scaling τ instead
would let the fit shrink every torque, residual and noise alike, towards zero).

Each z is held near zero by a unit Gaussian prior, so the SDs are the sizes of error one
expects of a calibrated arm: a loadcell's gain within about 10 %, its offset within about
5 % of the largest recorded tension, a tendon's friction loss within about 10 %, a link's
gravity torque within about 20 % (cables, motors and brackets are rarely in the robot
file). Weighed against the torque noise of the automatic weight (the floors of
:mod:`pimbs_learn.objective`), the prior is the MAP balance: with few samples the z stay
small and the physics acts as before; with many, a consistent error moves its z.

The z are trained by the same Adam as the weights, held as z / STEP_GAIN: Adam moves a
parameter by about lr per epoch, and a z of order 1–3 must settle within tens of epochs,
before the network bends G to absorb the error itself (the same reason as the elastic
coefficients' gain in :mod:`pimbs_learn.objective`).
"""

from __future__ import annotations

import numpy as np
import torch

GAIN_SD = 0.1
OFFSET_SD = 0.05  # share of the largest recorded tension (the network's tension scale)
FRICTION_SD = 0.1  # share of the tension lost (or gained) between loadcell and joint
GRAVITY_SD = 0.2
# the loadcell corrections, in the order of the last axis of :func:`columns`
TENSION_KEYS = ("z_gain", "z_offset", "z_friction")
KEYS = TENSION_KEYS + ("z_gravity",)
STEP_GAIN = 30.0


def columns(f: np.ndarray, f_scale: np.ndarray, approach: np.ndarray | None) -> np.ndarray:
    """(S, M, 3) how each loadcell error of :data:`TENSION_KEYS` moves each recorded tension
    ``f`` (S, M) per unit z; ``f_scale`` (M,) or (1, M) N; ``approach`` (S, M) ±1/0, None
    where the recording has none."""
    f = np.asarray(f, np.float64)
    fs = np.broadcast_to(np.asarray(f_scale, np.float64).reshape(1, -1), f.shape)
    friction = np.zeros_like(f) if approach is None else FRICTION_SD * np.asarray(
        approach, np.float64) * f
    return np.stack([GAIN_SD * f, OFFSET_SD * fs, friction], axis=-1)


def zeros(runs: int, muscles: int, joints: int, dtype: torch.dtype) -> dict[str, torch.Tensor]:
    """The sensor parameters of ``runs`` stacked runs at their prior mean."""
    out = {k: torch.zeros(runs, 1, muscles, dtype=dtype) for k in TENSION_KEYS}
    out["z_gravity"] = torch.zeros(runs, 1, joints, dtype=dtype)
    return out


def tension(p: dict[str, torch.Tensor], f: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
    """f' (R, B, M): the recorded tensions ``f`` with each loadcell's errors fitted;
    ``cols`` (R, B, M, 3) the :func:`columns` of each run."""
    z = torch.stack([p[k] for k in TENSION_KEYS], dim=-1)  # (R, 1, M, 3)
    return f + (cols * z).sum(dim=-1)


def gravity_factor(p: dict[str, torch.Tensor]) -> torch.Tensor:
    """k (R, 1, N): each joint's fitted scale of its gravity torque."""
    return 1 + GRAVITY_SD * p["z_gravity"]


def residual(p: dict[str, torch.Tensor], gtf: torch.Tensor, tau: torch.Tensor
             ) -> torch.Tensor:
    """Gᵀf'/k + τ (R, B, N), from ``gtf`` = Gᵀf' and the gravity torques τ."""
    return gtf / gravity_factor(p) + tau


def prior_sum(p: dict[str, torch.Tensor]) -> torch.Tensor:
    """Σ z² per run (R,): twice the negative log prior."""
    return sum((p[k] * p[k]).sum(dim=(-2, -1)) for k in KEYS)  # type: ignore[return-value]


def grads(p: dict[str, torch.Tensor], d_tension: torch.Tensor, d_residual: torch.Tensor,
          gtf: torch.Tensor, cols: torch.Tensor, prior_weight: torch.Tensor
          ) -> dict[str, torch.Tensor]:
    """∂/∂z of L_pinn (through ∂L/∂f' and ∂L/∂residual, each (R, B, ·), Gᵀf' and the
    tension columns (R, B, M, 3)) plus the prior's ``prior_weight``·Σz² ((R,) weight; 0 on
    runs without sensor terms)."""
    w = 2 * prior_weight.view(-1, 1, 1)
    k = gravity_factor(p)
    d_cols = (d_tension.unsqueeze(-1) * cols).sum(dim=1, keepdim=True)  # (R, 1, M, 3)
    out = {key: d_cols[..., i] + w * p[key] for i, key in enumerate(TENSION_KEYS)}
    out["z_gravity"] = (-GRAVITY_SD * (d_residual * gtf).sum(dim=1, keepdim=True) / (k * k)
                        + w * p["z_gravity"])
    return out


def physical(held: dict[str, np.ndarray], f_scale: np.ndarray) -> dict[str, list[float]]:
    """One run's fitted corrections (``held``: the trainer's z / STEP_GAIN) in the units a
    user reads: the factor and the newtons added to each loadcell's reading, the tension
    share the tendon gains on its way to the joint per unit approach (f·(1 + μ·a)), the
    factor on each joint's gravity torque."""
    z = {k: STEP_GAIN * v.astype(np.float64).ravel() for k, v in held.items()}
    fs = f_scale.ravel()
    return {"tension_scale_n": fs.tolist(),
            "tension_gain": (1 + GAIN_SD * z["z_gain"]).tolist(),
            "tension_offset_n": (OFFSET_SD * fs * z["z_offset"]).tolist(),
            "tension_friction": (FRICTION_SD * z["z_friction"]).tolist(),
            # the factor on τ that Gᵀf'/k + τ = 0 implies: τ·k balances Gᵀf'
            "gravity_scale": (1 + GRAVITY_SD * z["z_gravity"]).tolist()}


def line(fitted: dict[str, list[float]], muscles: list[str], joints: list[str],
         most: int = 4) -> str:
    """One line for ``pimbs train``: the fitted corrections a prior SD or more from none,
    largest first (a consistent sensor error the recording carries), or that there were
    none."""
    entries: list[tuple[float, str]] = []
    scale = fitted["tension_scale_n"]
    for i, name in enumerate(muscles):
        g, o = fitted["tension_gain"][i], fitted["tension_offset_n"][i]
        entries.append((abs(g - 1) / GAIN_SD, f"{name} loadcell ×{g:.3f}"))
        entries.append((abs(o / (OFFSET_SD * scale[i])), f"{name} loadcell {o:+.3g} N"))
        mu = fitted.get("tension_friction", [0.0] * len(muscles))[i]
        entries.append((abs(mu) / FRICTION_SD, f"{name} friction {mu:+.1%} per approach"))
    for name, k in zip(joints, fitted["gravity_scale"], strict=True):
        entries.append((abs((k - 1) / GRAVITY_SD), f"{name} gravity ×{k:.3f}"))
    big = sorted((e for e in entries if e[0] >= 1.0), reverse=True)[:most]
    if not big:
        return ("sensor terms: every loadcell gain and offset, every tendon's friction and "
                "every gravity scale fitted within one prior SD of none")
    return ("sensor terms fitted beyond one prior SD (the torque balance's consistent "
            "errors, not the body schema's): " + ", ".join(text for _, text in big))
