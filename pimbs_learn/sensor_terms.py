"""Sensor errors fitted inside the torque balance: loadcell gain and offset, gravity scale.

Why: the physics term asks Gᵀf + τ = 0 of the recorded tensions f and the model's gravity
torques τ. On a real arm neither is exact: a loadcell reads with a gain and an offset
error, and a link is heavier or lighter than its model. Such an error is *consistent*
across poses, so a network that must satisfy the balance bends its G (the body schema's
moment arms) to absorb it, and the physics then hurts the lengths it was meant to help.
Fitting the errors beside the network gives each its own parameter:

    f' = f·(1 + GAIN_SD·z_gain) + OFFSET_SD·f_scale·z_offset      (per muscle)
    k  = 1 + GRAVITY_SD·z_gravity                                  (per joint)
    L_pinn = mean (Gᵀf' / k + τ)²

The gravity scale divides the tension side rather than multiplying τ: the residual stays
in the units of τ, whose noise the automatic weight knows, and a gain common to every
loadcell with the same gravity scale leaves it unchanged, as it should (scaling τ instead
would let the fit shrink every torque, residual and noise alike, towards zero).

Each z is held near zero by a unit Gaussian prior, so the SDs are the sizes of error one
expects of a calibrated arm: a loadcell's gain within about 10 %, its offset within about
5 % of the largest recorded tension, a link's gravity torque within about 20 % (cables,
motors and brackets are rarely in the robot file). Weighed against the torque noise of
the automatic weight (the floors of :mod:`pimbs_learn.objective`), the prior is the MAP
balance: with few samples the z stay small and the physics acts as before; with many, a
consistent error moves its z.

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
GRAVITY_SD = 0.2
KEYS = ("z_gain", "z_offset", "z_gravity")
STEP_GAIN = 30.0


def zeros(runs: int, muscles: int, joints: int, dtype: torch.dtype) -> dict[str, torch.Tensor]:
    """The sensor parameters of ``runs`` stacked runs at their prior mean."""
    return {"z_gain": torch.zeros(runs, 1, muscles, dtype=dtype),
            "z_offset": torch.zeros(runs, 1, muscles, dtype=dtype),
            "z_gravity": torch.zeros(runs, 1, joints, dtype=dtype)}


def tension(p: dict[str, torch.Tensor], f: torch.Tensor, f_scale: torch.Tensor
            ) -> torch.Tensor:
    """f' (R, B, M): the recorded tensions with each loadcell's gain and offset fitted."""
    return f * (1 + GAIN_SD * p["z_gain"]) + (OFFSET_SD * f_scale) * p["z_offset"]


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
          gtf: torch.Tensor, f: torch.Tensor, f_scale: torch.Tensor,
          prior_weight: torch.Tensor) -> dict[str, torch.Tensor]:
    """∂/∂z of L_pinn (through ∂L/∂f' and ∂L/∂residual, each (R, B, ·), and Gᵀf') plus the
    prior's ``prior_weight``·Σz² ((R,) weight; 0 on runs without sensor terms)."""
    w = 2 * prior_weight.view(-1, 1, 1)
    k = gravity_factor(p)
    return {"z_gain": GAIN_SD * (d_tension * f).sum(dim=1, keepdim=True) + w * p["z_gain"],
            "z_offset": OFFSET_SD * f_scale * d_tension.sum(dim=1, keepdim=True)
            + w * p["z_offset"],
            "z_gravity": -GRAVITY_SD * (d_residual * gtf).sum(dim=1, keepdim=True) / (k * k)
            + w * p["z_gravity"]}


def physical(held: dict[str, np.ndarray], f_scale: np.ndarray) -> dict[str, list[float]]:
    """One run's fitted corrections (``held``: the trainer's z / STEP_GAIN) in the units a
    user reads: the factor and the newtons added to each loadcell's reading, the factor on
    each joint's gravity torque."""
    z = {k: STEP_GAIN * v.astype(np.float64) for k, v in held.items()}
    return {"tension_scale_n": f_scale.ravel().tolist(),
            "tension_gain": (1 + GAIN_SD * z["z_gain"].ravel()).tolist(),
            "tension_offset_n": (OFFSET_SD * f_scale.ravel() * z["z_offset"].ravel()).tolist(),
            # the factor on τ that Gᵀf'/k + τ = 0 implies: τ·k balances Gᵀf'
            "gravity_scale": (1 + GRAVITY_SD * z["z_gravity"].ravel()).tolist()}


def line(fitted: dict[str, list[float]], muscles: list[str], joints: list[str],
         most: int = 4) -> str:
    """One line for ``pimbs train``: the fitted corrections a prior SD or more from none,
    largest first (a consistent sensor error the recording carries), or that there were
    none."""
    entries: list[tuple[float, str]] = []
    for name, g in zip(muscles, fitted["tension_gain"], strict=True):
        z = (g - 1) / GAIN_SD
        entries.append((abs(z), f"{name} loadcell ×{g:.3f}"))
    for name, o, s in zip(muscles, fitted["tension_offset_n"], fitted["tension_scale_n"],
                          strict=True):
        entries.append((abs(o / (OFFSET_SD * s)), f"{name} loadcell {o:+.3g} N"))
    for name, k in zip(joints, fitted["gravity_scale"], strict=True):
        entries.append((abs((k - 1) / GRAVITY_SD), f"{name} gravity ×{k:.3f}"))
    big = sorted((e for e in entries if e[0] >= 1.0), reverse=True)[:most]
    if not big:
        return ("sensor terms: every loadcell gain and offset and every gravity scale "
                "fitted within one prior SD of none")
    return ("sensor terms fitted beyond one prior SD (the torque balance's consistent "
            "errors, not the body schema's): " + ", ".join(text for _, text in big))
