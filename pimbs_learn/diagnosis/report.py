"""The diagnosis as data (JSON) and as text: effects with parameters and evidence, the fit."""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from pimbs_learn.diagnosis.confound import (
    MAX_INFLATION,
    PER_MUSCLE,
    RIDGE_SHARE,
    Rival,
    Verdict,
)
from pimbs_learn.diagnosis.detect import detectable_text
from pimbs_learn.diagnosis.leftover import leftover_text
from pimbs_learn.diagnosis.model import (
    Fit,
    Physics,
    Samples,
    apply_effects,
    hysteresis,
    link_place,
    schema_jacobian,
)
from pimbs_learn.diagnosis.select import P_VALUE, Candidate


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
            entry = params.setdefault(link_place(physics, unit, joints), {})
            if unit.part in ("link", "distal"):
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


MAX_EITHER = 4  # more explanations than this that fit alike: "unexplained", with where


def _explanation(effect: str, units: list, fit: Fit, lr: float, delta_bic: float,
                 physics: Physics, data: Samples, joints: list[str], muscles: list[str]
                 ) -> dict:
    cand = Candidate(effect, units, fit, lr, len(units), float(chi2.sf(lr, len(units))),
                     delta_bic, {}, None)
    params, names_m, names_j = parameters(cand, physics, joints, muscles, fit)
    if effect != "joint_offset":
        names_j = effect_joints(cand, physics, data, joints, fit)
    return {"name": effect, "muscles": names_m, "joints": names_j, "parameters": params,
            "likelihood_ratio": lr, "df": len(units), "delta_bic": float(delta_bic)}


def ambiguity_entry(verdict: Verdict, physics: Physics, data: Samples, joints: list[str],
                    muscles: list[str], final: Fit) -> dict:
    """An effect the selection picked whose evidence does not survive its confounders: every
    explanation that fits, each with its own fit and how much better or worse it is."""
    a = verdict.named
    options = [_explanation(a.effect, a.units, final, verdict.lr, verdict.delta_bic, physics,
                            data, joints, muscles)]
    for r in verdict.rivals:
        entry = _explanation(r.effect, r.units, r.fit, r.lr, r.delta_bic, physics, data,
                             joints, muscles)
        held = r.heldout
        entry["beside_the_first"] = {
            "likelihood_ratio_of_first_given_this": r.lr_named_given,
            "likelihood_ratio_of_this_given_first": r.lr_given_named,
            "heldout_gain_of_first_given_this": None if held is None else held.gain,
            "heldout_likelihood_ratio_of_first_given_this": None if held is None else held.lr,
            "heldout_z_of_first_given_this": None if held is None else held.z,
            "heldout_rows_better_with_first": None if held is None else held.improved,
            "standard_error_widening_of_first_given_this": r.inflation,
            "first_given_this_along_a_ridge": r.ridge}
        options.append(entry)
    best = max(o["delta_bic"] for o in options)
    for o in options:
        o["delta_bic_behind_best"] = best - o["delta_bic"]
    return {"either": options,
            "meaning": "each explanation alone fits the mismatch; what the first adds beside "
                       "another is not confirmed (likelihood ratio, BIC and held-out rows) "
                       "or is a small remainder along a direction the recording barely holds "
                       f"(under {RIDGE_SHARE:.0%} of the first's likelihood ratio, with "
                       "the error of the first's amount widened more than "
                       f"{MAX_INFLATION:g}-fold when both are fitted), so this recording "
                       "cannot tell which it is"}


def disputed_entry(verdict: Verdict, recordings: list[str]) -> dict:
    """An effect the recordings disagree on: one prefers it, another a rival."""
    return {"why": "the recordings disagree on what explains the mismatch",
            "candidates": [verdict.named.effect, *(c[0] for c in verdict.contradictions)],
            "per_recording": [
                {"rival": effect, "units": [u.label for u in units],
                 "likelihood_ratio_of_first_over_rival": dict(zip(recordings, per,
                                                                  strict=True))}
                for effect, units, per in verdict.contradictions]}


def _on_muscles(named: Candidate, muscles: list[str]) -> str:
    """The muscles of an effect that acts per loadcell, as words (" on m1, m2"; "" else)."""
    on = sorted({muscles[u.index] for u in named.units if u.index >= 0}
                ) if named.effect in PER_MUSCLE else []
    return " on " + ", ".join(on) if on else ""


def branch_entry(verdict: Verdict, muscles: list[str], final: Fit) -> dict:
    """An effect that fits only with loadcell branches the readings cannot tell
    (``confound.branch_bound``): the mismatch is reported, not the name."""
    h = hysteresis(final)
    effect = verdict.named.effect
    return {"why": (f"{effect}{_on_muscles(verdict.named, muscles)} fits only where the "
                    "loadcells' branches are guessed (readings that moved less than their "
                    f"{h:.2f} N hysteresis can hide), and hysteresis on a wrong guess looks "
                    "like it; poses that load and unload each wire by several newtons "
                    "would tell"),
            "candidates": [effect, "loadcell_hysteresis"]}


FACTOR_OF = {"elastic_stiffness": "the wires' elasticity", "tension_gain": "the loadcells' gain"}


def factor_entry(verdict: Verdict, muscles: list[str]) -> dict:
    """An effect that fits only with a factor no arm has (``factors_not_positive``): the
    mismatch is reported, not the name."""
    fit, effect = verdict.fit, verdict.named.effect
    factors = [1.0 + float(fit.params[fit.units.index(u)]) for u in verdict.impossible]
    on = ", ".join(sorted(muscles[u.index] for u in verdict.impossible))
    span = (f"{factors[0]:.2f}" if len(factors) == 1
            else f"{min(factors):.2f} to {max(factors):.2f}")
    return {"why": (f"{effect} fits only with {FACTOR_OF[effect]} scaled by {span} on {on}, "
                    "not clearly above zero: no muscle has that, and the body schema, a drift "
                    "or guessed loadcell branches may move these readings instead"),
            "candidates": [effect, "body_schema"]}


def spring_fit(spring: Rival, joints: list[str]) -> dict:
    """A passive joint spring fitted in a name's place (``confound.outside_rival``)."""
    fit = spring.fit
    rate, torque = (float(fit.params[fit.units.index(u)]) for u in spring.units)
    return {"joint": joints[spring.units[0].index], "rate_Nm_per_rad": rate,
            "rate_se": _se(fit, fit.units.index(spring.units[0])),
            "rest_angle_rad": -torque / rate, "likelihood_ratio": spring.lr,
            "delta_bic": float(spring.delta_bic),
            "likelihood_ratio_of_effect_given_spring": spring.lr_named_given}


def _spring_words(s: dict) -> str:
    return (f"a passive spring at {s['joint']} ({s['rate_Nm_per_rad']:.3g} N·m/rad"
            + (f" ± {s['rate_se']:.2g}" if s["rate_se"] else "")
            + f" pulling toward {s['rest_angle_rad']:.3g} rad)")


def spring_entry(verdict: Verdict, joints: list[str], muscles: list[str]) -> dict:
    """An effect a passive joint spring explains clearly better (``confound.outside_rival``):
    the spring is outside the effects named here, so the mismatch is reported with it, and
    neither is named."""
    a = verdict.named
    spring = spring_fit(verdict.outside, joints)
    return {"why": (f"{a.effect}{_on_muscles(a, muscles)} fits, but "
                    f"{_spring_words(spring)} fits clearly better (ΔBIC "
                    f"{spring['delta_bic']:.0f} against {verdict.delta_bic:.0f}) and leaves "
                    "nothing for it: a joint spring (a cover, cables, a joint's stop) is not "
                    "among the effects named here"),
            "joint_spring": spring, "instead_of": a.effect}


def rest_entry(residual: dict) -> dict | None:
    """What the fitted effects leave, where it is not noise (``leftover``): the channels and
    what each depends on; None where it is noise."""
    if residual["consistent_with_noise"]:
        return None
    return {"why": "what is left after the fitted effects is not noise",
            "where": [f"{s['channel']} depends on "
                      + ", ".join(w["factor"] for w in s["depends_on"][:3])
                      for s in residual["structure"]]}


def unexplained(ambiguous: list[dict], rest: dict | None, location: dict,
                disputed: list[dict] = ()) -> list[dict]:
    """Mismatch no identifiable effect accounts for, with where it is: effects the
    recordings disagree on (``disputed``), ambiguities with more explanations than can be
    listed, and structure left after every fitted explanation (``rest_entry``)."""
    out = [{**d, "where": location["summary"]} for d in disputed]
    for amb in ambiguous:
        if len(amb["either"]) > MAX_EITHER:
            out.append({"why": f"{len(amb['either'])} effects explain it about equally",
                        "candidates": [o["name"] for o in amb["either"]],
                        "where": location["summary"]})
    return out + ([rest] if rest else [])


def _option_line(o: dict) -> list[str]:
    who = ", ".join(o["muscles"] + o["joints"])
    lines = [f"{o['name']} ({who})  ΔBIC {o['delta_bic']:.0f}"
             + (f", {o['delta_bic_behind_best']:.0f} behind the best"
                if o["delta_bic_behind_best"] > 0.5 else ", the best fit")]
    lines += _parameter_lines(o["parameters"])
    return lines


def _parameter_lines(parameters: dict) -> list[str]:
    out = []
    for unit, values in parameters.items():
        shown = ", ".join(f"{k} {v:.4g}" for k, v in values.items()
                          if isinstance(v, float) and k != "se")
        se = values.get("se")
        out.append(f"       {unit}: {shown}" + (f" (± {se:.2g})" if se else ""))
    return out


def ambiguity_text(result: dict) -> list[str]:
    lines = []
    for amb in result.get("ambiguous", []):
        if len(amb["either"]) > MAX_EITHER:
            continue  # listed as unexplained
        first, *others = amb["either"]
        lines.append("Cannot tell apart: each explains the mismatch, and this recording does "
                     "not separate them:")
        for i, o in enumerate(amb["either"]):
            head, *rest = _option_line(o)
            lines.append(f"  {'either' if i == 0 else '    or'} {head}")
            lines += rest
        for o in others:
            b = o["beside_the_first"]
            held = b["heldout_likelihood_ratio_of_first_given_this"]
            added = b["likelihood_ratio_of_first_given_this"]
            wider = b["standard_error_widening_of_first_given_this"]
            lines.append(f"  beside {o['name']}, {first['name']} adds a likelihood ratio of "
                         f"{added:.0f}"
                         + ("" if held is None else f", {held:.0f} on held-out rows")
                         + f"; naming needs {chi2.isf(P_VALUE, first['df']):.0f}"
                         + ("" if held is None else " in both"))
            if b["first_given_this_along_a_ridge"]:
                lines.append(f"    but fitted together its amount is {wider:.0f}× less certain,"
                             f" and that is under {RIDGE_SHARE:.0%} of the "
                             f"{first['likelihood_ratio']:.0f} it explains alone:")
                lines.append("    the two slide along one direction the recording barely holds")
        poses = amb.get("separating_poses")
        if poses:
            lines.append(f"  {len(poses['poses'])} poses that would tell them apart "
                         f"(expected likelihood ratio {poses['expected_likelihood_ratio']:.0f}"
                         f" between them): collect them with `pimbs collect --poses-file "
                         f"FILE` (written by --poses-out) and diagnose both recordings "
                         "together")
        elif "separating_poses" not in amb:
            lines.append("  give --robot to get the poses that would tell them apart")
        else:
            lines.append(f"  {amb.get('separating_poses_note', 'no poses proposed')}")
        lines.append("")
    for u in result.get("unexplained", []):
        lines.append(f"Unexplained ({u['why']}"
                     + (": " + ", ".join(u["candidates"]) if u.get("candidates") else "")
                     + "); where:")
        for d in u.get("per_recording", []):
            lines.append(f"  {u['candidates'][0]} against {d['rival']}, likelihood ratio per "
                         "recording: " + ", ".join(
                             f"{path} {lr:+.0f}" for path, lr in
                             d["likelihood_ratio_of_first_over_rival"].items()))
        lines += [f"  - {w}" for w in u["where"]]
        poses = u.get("separating_poses")
        if poses and "branch_step_N" not in poses:
            lines.append(f"  {len(poses['poses'])} poses farthest from the recorded ones would "
                         "show what it depends on: collect them in their order with `pimbs "
                         "collect --poses-file FILE` (written by --poses-out) and diagnose "
                         "both recordings together")
        elif poses:
            lines.append(f"  {len(poses['poses'])} poses, each loading or unloading every "
                         f"wire by more than {poses['branch_step_N']:.1f} N, would tell them "
                         "apart: collect them in their order with `pimbs collect --poses-file "
                         "FILE` (written by --poses-out) and diagnose both recordings together")
        lines.append("")
    return lines


def _schema_text(model: dict) -> str:
    """The body schema in words: the robot file's routing as it is (up to each muscle's
    constant), corrected by a polynomial, or a polynomial alone; and where it came from."""
    degree, anchored = model["schema_degree"], model["schema_from_robot_file"]
    form = ("the robot file's routing + a constant per muscle" if anchored and not degree else
            ("the robot file's routing + " if anchored else "") + f"degree-{degree} polynomial")
    return f"{form}, {model['schema']}"


def text_report(result: dict) -> str:
    recs = result.get("recordings") or [{"real": result["real"],
                                         "reference": result.get("reference")}]
    against = (" and ".join(r["reference"] for r in recs) if recs[0]["reference"] else
               f"robot description {result.get('robot')}")
    lines = [f"PIMBS diagnosis of {' and '.join(r['real'] for r in recs)} against {against}"
             + (" (together)" if len(recs) > 1 else ""),
             f"  {result['rows']} paired samples, {len(result['joints'])} joints, "
             f"{len(result['muscles'])} muscles; body schema: "
             + _schema_text(result["model"]), "",
             "Where it disagrees (before any effect is modelled):"]
    lines += [f"  - {s}" for s in result["location"]["summary"]]
    lines.append("")
    unsure = bool(result.get("ambiguous") or result.get("unexplained"))
    if not result["effects"] and unsure:
        parts = (["the explanations this recording cannot tell apart"]
                 * bool(result.get("ambiguous"))
                 + ["what no effect explains"] * bool(result.get("unexplained")))
        lines.append(f"No effect identified; below, {' and '.join(parts)}.")
    elif not result["effects"]:
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
            lines += _parameter_lines(e["parameters"])
            alike = e.get("spring_fits_alike")
            if alike:
                lines.append(f"       {_spring_words(alike)} fits about as well; a joint "
                             "spring is not among the effects named here, and this recording "
                             "does not tell it from this one")
                poses = alike.get("separating_poses")
                if poses:
                    lines.append(f"       {len(poses['poses'])} poses would tell them apart "
                                 "(expected likelihood ratio "
                                 f"{poses['expected_likelihood_ratio']:.0f}): collect them "
                                 "with `pimbs collect --poses-file FILE` (written by "
                                 "--poses-out) and diagnose both recordings together")
    more = ambiguity_text(result)
    if more:
        lines += [""] + more[:-1]
    if "residual" in result:
        lines += [""] + leftover_text(result["residual"])
    if "detectable" in result:
        lines += [""] + detectable_text(result["detectable"], not result["effects"]
                                        and not unsure)
    fit = result["fit"]
    lines += ["", f"Held-out fit ({fit['metric']}): before {fit['before']:.4g} → after "
                  f"{fit['after']:.4g}",
              f"  torque RMS {fit['torque_rms_Nm']['before']:.4g} → "
              f"{fit['torque_rms_Nm']['after']:.4g} N·m;  length RMS "
              f"{fit['length_rms_m']['before']:.3g} → {fit['length_rms_m']['after']:.3g} m"]
    return "\n".join(lines)
