"""The diagnosis as data (JSON) and as text: effects with parameters and evidence, the fit."""

from __future__ import annotations

import numpy as np

from pimbs_learn.diagnosis.detect import detectable_text
from pimbs_learn.diagnosis.leftover import leftover_text
from pimbs_learn.diagnosis.model import Fit, Physics, Samples, apply_effects, schema_jacobian
from pimbs_learn.diagnosis.select import Candidate


def _se(fit: Fit, i: int) -> float | None:
    if fit.cov is None or not np.isfinite(fit.cov[i, i]):
        return None
    return float(np.sqrt(max(fit.cov[i, i], 0.0)))


def _param(fit: Fit, unit) -> tuple[float, float | None]:
    i = fit.units.index(unit)
    return float(fit.params[i]), _se(fit, i)


def parameters(cand: Candidate, physics: Physics, joints: list[str],
               muscles: list[str], fit: Fit | None = None) -> tuple[dict, list[str], list[str]]:
    """Physical parameters of a named effect (from ``fit``, the joint fit of all named
    effects, else the effect's own), and the muscles and joints it involves."""
    fit, params = fit or cand.fit, {}
    names_m, names_j = [], []
    for unit in cand.units:
        value, se = _param(fit, unit)
        if cand.effect == "tension_offset":
            params[muscles[unit.index]] = {"offset_N": value, "se": se}
        elif cand.effect == "tendon_friction":
            params[muscles[unit.index]] = {"mu": value, "se": se,
                                           "meaning": "loadcell reads f·exp(−a·mu), "
                                                      "a = +1 lengthening"}
        elif cand.effect == "elastic_stiffness":
            ratio = 1.0 / (1.0 + value)
            k_model = 1.0 / abs(physics.kappa[unit.index])
            params[muscles[unit.index]] = {
                "stiffness_ratio": ratio, "se": None if se is None else se * ratio**2,
                "K_model": float(k_model), "K_estimated": float(k_model * ratio)}
        elif cand.effect == "tension_gain":
            params[muscles[unit.index]] = {"gain": value, "se": se,
                                           "meaning": "loadcell reads (1 + gain)·f"}
        elif cand.effect == "thermal_drift" and unit.part == "common":
            params["all muscles (common)"] = {
                "coefficient_N_per_C": value, "se": se,
                "reference_temperature_C": [float(t) for t in physics.temp_zero],
                "meaning": "every loadcell reads f + coefficient·(T − its reference); "
                           "per-muscle entries add to it"}
            names_m.extend(muscles)
        elif cand.effect == "thermal_drift":
            params[muscles[unit.index]] = {
                "coefficient_N_per_C": value, "se": se,
                "reference_temperature_C": float(physics.temp_zero[unit.index]),
                "meaning": "loadcell reads f + coefficient·(T − reference), zero where it "
                           "was zeroed"}
        elif cand.effect == "joint_offset":
            params[joints[unit.index]] = {"offset_rad": value, "se": se,
                                          "meaning": "joint sensor reads true angle + offset"}
        elif cand.effect == "link_mass":
            key = f"links beyond {joints[unit.index]}"
            entry = params.setdefault(key, {})
            if unit.part == "distal":
                entry.update({"mass_scale": 1.0 + value, "se": se})
            else:
                entry.setdefault("proximal_shares", {})[joints[int(
                    unit.part.removeprefix("level"))]] = value
        if cand.effect == "joint_offset":
            names_j.append(joints[unit.index])
        elif cand.effect != "link_mass" and unit.part != "common":
            names_m.append(muscles[unit.index])
    return params, sorted(set(names_m), key=muscles.index), sorted(set(names_j),
                                                                   key=joints.index)


def effect_joints(cand: Candidate, physics: Physics, data: Samples, joints: list[str],
                  final: Fit) -> list[str]:
    """Joints whose torque the effect changes noticeably (≥ 20 % of the largest)."""
    without = np.array([0.0 if u in cand.units else p
                        for u, p in zip(final.units, final.params, strict=True)])
    before = apply_effects(physics, data, final.units, without)
    after = apply_effects(physics, data, final.units, final.params)
    jac = schema_jacobian(physics, after.theta, final.weights)
    change = (np.einsum("bmn,bm->bn", jac, after.tension - before.tension)
              + (after.tau - before.tau))
    rms = np.sqrt(np.mean(change**2, axis=0))
    if rms.max() <= 0:
        return []
    return [j for j, r in zip(joints, rms, strict=True) if r >= 0.2 * rms.max()]


def effect_entry(cand: Candidate, physics: Physics, data: Samples, joints: list[str],
                 muscles: list[str], final: Fit) -> dict:
    """One named effect: parameters from the joint fit ``final``, evidence from its round."""
    params, names_m, names_j = parameters(cand, physics, joints, muscles, final)
    if cand.effect != "joint_offset":
        names_j = effect_joints(cand, physics, data, joints, final)
    return {
        "name": cand.effect,
        "muscles": names_m,
        "joints": names_j,
        "parameters": params,
        "evidence": {
            "likelihood_ratio": cand.lr, "df": cand.df, "p_value": cand.p_value,
            "delta_bic": float(cand.delta_bic), "cv_gain": cand.cv_gain, "cv_z": cand.cv_z,
            "heldout_before": cand.cv_before["score"], "heldout_after": cand.cv_after["score"],
        },
    }


def text_report(result: dict) -> str:
    lines = [f"PIMBS diagnosis of {result['real']}"
             + (f" against {result['reference']}" if result.get("reference") else
                f" against robot description {result.get('robot')}"),
             f"  {result['rows']} paired samples, {len(result['joints'])} joints, "
             f"{len(result['muscles'])} muscles; body schema: degree-"
             f"{result['model']['schema_degree']} polynomial, {result['model']['schema']}", "",
             "Where it disagrees (before any effect is modelled):"]
    lines += [f"  - {s}" for s in result["location"]["summary"]]
    lines.append("")
    if not result["effects"]:
        lines.append("No significant missing physics: no candidate passed the "
                     "likelihood-ratio, BIC and cross-validation tests (see below whether "
                     "this recording could have seen one).")
    else:
        lines.append("Missing physics, most significant first:")
        for i, e in enumerate(result["effects"], 1):
            ev = e["evidence"]
            # the units its parameters belong to: muscles, or joints for a joint offset or a
            # link mass (the JSON's "joints" of a muscle effect are the joints it loads)
            who = ", ".join(e["muscles"] or e["joints"])
            lines.append(f"  {i}. {e['name']} ({who})  ΔBIC {ev['delta_bic']:.0f}, "
                         f"p {ev['p_value']:.1e}, held-out gain {100 * ev['cv_gain']:.0f} %")
            for unit, values in e["parameters"].items():
                shown = ", ".join(f"{k} {v:.4g}" for k, v in values.items()
                                  if isinstance(v, float) and k != "se")
                se = values.get("se")
                lines.append(f"       {unit}: {shown}" + (f" (± {se:.2g})" if se else ""))
    if "residual" in result:
        lines += [""] + leftover_text(result["residual"])
    if "detectable" in result:
        lines += [""] + detectable_text(result["detectable"], not result["effects"])
    fit = result["fit"]
    lines += ["", f"Held-out fit ({fit['metric']}): before {fit['before']:.4g} → after "
                  f"{fit['after']:.4g}",
              f"  torque RMS {fit['torque_rms_Nm']['before']:.4g} → "
              f"{fit['torque_rms_Nm']['after']:.4g} N·m;  length RMS "
              f"{fit['length_rms_m']['before']:.3g} → {fit['length_rms_m']['after']:.3g} m"]
    return "\n".join(lines)
