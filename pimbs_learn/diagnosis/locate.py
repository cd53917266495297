"""Where the real arm disagrees with the model: residuals broken down by what matters.

Works on the residuals of the null model (body schema learned, nothing else). The torque
residual of a sample is turned into the *implied tension error* of each muscle — the
loadcell error that muscle alone would need to explain it — so a bad loadcell, friction
or drift points at its muscle; those errors are then split by approach direction,
temperature and time, and the torque residual by joint and joint range.
"""

from __future__ import annotations

import numpy as np

from pimbs_learn.diagnosis.model import Fit, Physics, Samples, apply_effects, schema_jacobian


def implied_tension_error(physics: Physics, fit: Fit, data: Samples,
                          r_tau: np.ndarray) -> np.ndarray:
    """(B, M): tension error of muscle j alone that best explains each torque residual."""
    state = apply_effects(physics, data, fit.units, fit.params)
    jac = schema_jacobian(physics, state.theta, fit.weights)  # (B, M, N)
    # r = −G_jᵀ e_j  →  e_j = −G_j·r / |G_j|²
    return -np.einsum("bmn,bn->bm", jac, r_tau) / np.maximum(np.sum(jac**2, axis=2), 1e-12)


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    if np.std(a) < 1e-15 or np.std(b) < 1e-15:
        return 0.0
    return float(np.corrcoef(a, b)[0, 1])


def locate(physics: Physics, fit: Fit, data: Samples, r_len: np.ndarray, r_tau: np.ndarray,
           joints: list[str], muscles: list[str], reference: Samples | None = None) -> dict:
    """A JSON-ready breakdown of the mismatch (null-model residuals)."""
    err = implied_tension_error(physics, fit, data, r_tau)
    z_tau = r_tau / fit.sigma_tau
    out: dict = {"joints": [], "muscles": [], "joint_range": [], "time": []}
    tau_rms = np.sqrt(np.mean(r_tau**2, axis=0))
    for k, name in enumerate(joints):
        out["joints"].append({"joint": name, "torque_rms_Nm": float(tau_rms[k]),
                              "share": float(tau_rms[k] ** 2 / max(np.sum(tau_rms**2), 1e-30))})
        theta = data.theta[:, k]
        edges = np.quantile(theta, [0, 1 / 3, 2 / 3, 1])
        for lo, hi, label in zip(edges[:-1], edges[1:], ("low", "middle", "high"), strict=True):
            sel = (theta >= lo) & (theta <= hi)
            out["joint_range"].append({
                "joint": name, "part": label, "from_rad": float(lo), "to_rad": float(hi),
                "torque_rms_Nm": float(np.sqrt(np.mean(r_tau[sel] ** 2)))})
    for j, name in enumerate(muscles):
        a = data.approach[:, j]
        lengthening, shortening = err[a > 0, j], err[a < 0, j]
        entry = {
            "muscle": name,
            "implied_tension_error_rms_N": float(np.sqrt(np.mean(err[:, j] ** 2))),
            "implied_tension_error_mean_N": float(np.mean(err[:, j])),
            "length_rms_m": float(np.sqrt(np.mean(r_len[:, j] ** 2))),
            "approach": {
                "lengthening_mean_N": float(lengthening.mean()) if lengthening.size else None,
                "shortening_mean_N": float(shortening.mean()) if shortening.size else None},
            "temperature_corr": _corr(err[:, j], data.temperature[:, j]),
            "tension_corr": _corr(err[:, j], data.tension[:, j]),
        }
        if reference is not None:
            entry["vs_reference"] = {
                "tension_diff_mean_N": float(np.mean(data.tension[:, j]
                                                     - reference.tension[:, j])),
                "length_diff_rms_m": float(np.sqrt(np.mean((data.length[:, j]
                                                            - reference.length[:, j]) ** 2)))}
        out["muscles"].append(entry)
    quarters = np.array_split(np.argsort(data.time), 4)
    for part in quarters:
        out["time"].append({"from_s": float(data.time[part].min()),
                            "to_s": float(data.time[part].max()),
                            "torque_rms_whitened": float(np.sqrt(np.mean(z_tau[part] ** 2)))})
    out["summary"] = summarise(out)
    return out


def summarise(loc: dict) -> list[str]:
    """The few findings a person should read first."""
    lines = []
    joints = sorted(loc["joints"], key=lambda e: -e["share"])
    if joints:
        j = joints[0]
        lines.append(f"torque mismatch is largest at {j['joint']} "
                     f"({j['torque_rms_Nm']:.3g} N·m RMS, {100 * j['share']:.0f} % of it)")
    muscles = sorted(loc["muscles"], key=lambda e: -e["implied_tension_error_rms_N"])
    for m in muscles[:2]:
        ap = m["approach"]
        text = (f"{m['muscle']}: implied tension error {m['implied_tension_error_rms_N']:.3g} N "
                f"RMS (mean {m['implied_tension_error_mean_N']:+.3g} N)")
        if ap["lengthening_mean_N"] is not None and ap["shortening_mean_N"] is not None:
            text += (f", lengthening {ap['lengthening_mean_N']:+.3g} N vs shortening "
                     f"{ap['shortening_mean_N']:+.3g} N")
        text += f", corr. with temperature {m['temperature_corr']:+.2f}"
        lines.append(text)
    ranges = sorted(loc["joint_range"], key=lambda e: -e["torque_rms_Nm"])
    if ranges:
        r = ranges[0]
        lines.append(f"worst joint range: {r['joint']} {r['part']} third "
                     f"[{r['from_rad']:+.2f}, {r['to_rad']:+.2f}] rad, "
                     f"{r['torque_rms_Nm']:.3g} N·m RMS")
    t = loc["time"]
    if t and t[-1]["torque_rms_whitened"] > 1.5 * max(t[0]["torque_rms_whitened"], 1e-12):
        lines.append("the mismatch grows over the recording (drift with time or heat)")
    return lines
