"""`diagnose()`: from recordings to a named, fitted, cross-validated account of the mismatch."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa

from pimbs_learn.diagnosis.confound import judge, springs_in_place
from pimbs_learn.diagnosis.detect import detectable
from pimbs_learn.diagnosis.fit import cross_validate, fit_effects
from pimbs_learn.diagnosis.inputs import (
    MIN_SAMPLES,
    DiagnosisInputError,
    build_physics,
    combine,
    pair,
    too_few_samples,
)
from pimbs_learn.diagnosis.leftover import leftover
from pimbs_learn.diagnosis.locate import locate
from pimbs_learn.diagnosis.model import EFFECTS, apply_effects, evaluate, sensor_units
from pimbs_learn.diagnosis.report import (
    ambiguity_entry,
    branch_entry,
    disputed_entry,
    effect_entry,
    factor_entry,
    rest_entry,
    spring_entry,
    spring_fit,
    unexplained,
)
from pimbs_learn.diagnosis.select import select_effects
from pimbs_recording.format import Recording, read_recording, write_recording

Source = str | Path | Recording
DESIGN_POSES = 30  # poses proposed to settle an ambiguity: a few minutes on a real arm
FIT_METRIC = ("mean squared held-out residual of lengths and torques, each channel "
              "divided by its noise level under the model without effects (5-fold CV)")


def _propose(entry: dict, design, *args) -> None:
    """``entry["separating_poses"]`` = ``design(*args)`` (``design.separating_poses``,
    ``design.branch_telling_poses`` or ``design.unseen_poses``), or None with the reason
    where the arm could not hold an explanation's poses."""
    from pimbs_arm.model import InfeasiblePoseError

    try:
        entry["separating_poses"] = design(*args)
    except InfeasiblePoseError as exc:  # an explanation the arm could not hold
        entry["separating_poses"] = None
        entry["separating_poses_note"] = f"no poses proposed: {exc}"


def diagnose(real: Source | list[Source], reference: Source | list[Source] | None = None,
             robot: str | Path | None = None, effects: tuple[str, ...] = EFFECTS,
             progress=None, design_poses: int = DESIGN_POSES) -> tuple[dict, dict]:
    """Diagnose ``real`` against a paired ``reference`` recording and/or a robot description.

    ``real`` may be several recordings of one arm (a first session and the poses collected
    to settle what it could not tell apart), each with its own reference (same order) or
    all paired with the robot description. Returns (result, internals): ``result`` is the
    JSON-ready report; ``internals`` holds the fitted objects for plots and for writing a
    corrected recording. With a robot description, explanations the recordings cannot
    tell apart come with ``design_poses`` poses that would (``design``).
    """
    reals = [_read(r) for r in (real if isinstance(real, list | tuple) else [real])]
    refs = reference if isinstance(reference, list | tuple) else (
        [] if reference is None else [reference])
    refs = [_read(r) for r in refs]
    if not refs and robot is None:
        raise DiagnosisInputError("give --reference SIM.parquet (same commanded poses) or "
                                  "--robot NAME|PATH (the robot description)")
    if refs and len(refs) != len(reals):
        raise DiagnosisInputError(
            f"{len(reals)} recordings and {len(refs)} references: give one --reference per "
            "recording, in the same order (`pimbs simulate --poses-file` makes the one for a "
            "poses file), or none and --robot")
    for i, rec in enumerate(reals):  # a copy would count its rows twice as evidence
        for other in reals[:i]:
            if rec.table.equals(other.table):
                raise DiagnosisInputError(
                    f"{other.path} and {rec.path} hold the same rows: give each session once")
    arm, kappa = None, None
    if robot is not None:
        from pimbs_arm.model import ArmModel

        arm = ArmModel.load(robot)
        for rec in reals:
            if list(arm.joints) != rec.joints or list(arm.muscles) != rec.muscles:
                raise DiagnosisInputError(
                    f"{rec.path} does not match robot {arm.robot.name}: recording joints "
                    f"{rec.joints}, muscles {rec.muscles}; description joints "
                    f"{list(arm.joints)}, muscles {list(arm.muscles)}")
        # the file states the elasticity (PIMBS' own sign convention, l = h − Δn); a
        # reference tells it only where each muscle's tension varies apart from its pose:
        # fitted on a session held at its floors it takes in what the real arm's effects
        # do to the stretch (a 20 N offset on the elbow's triceps came out at 8 N)
        kappa = -1.0 / arm.K
    least = MIN_SAMPLES if len(reals) == 1 else 1  # together, the rows must be enough
    paired = combine([pair(rec, refs[i] if refs else None, arm, least)
                      for i, rec in enumerate(reals)])
    if paired.real.n < MIN_SAMPLES:
        raise too_few_samples(" + ".join(str(r.path) for r in reals), paired.real.n)
    physics, model_info = build_physics(paired, kappa, arm)
    data = paired.real
    null = fit_effects(physics, data, sensor_units(data), key="full")  # the sensors' own
    named, tried, cv_null, final = select_effects(physics, data, null, effects, progress,
                                                  paired.reference)
    # held-out score of the final model on the null model's noise scale (the "before")
    cv_final = (cross_validate(physics, data, final.units, (null.sigma_len, null.sigma_tau),
                               x0=final.params) if named else cv_null)
    # each named effect against its confounders: the others refitted in its place
    verdicts = [judge(physics, data, final, cand, effects) for cand in named]
    named_ok = [v for v in verdicts if v.identified]
    sure = [v.named for v in named_ok]
    unsure = [v for v in verdicts if v.rivals and not v.contradictions]
    disputed = [v for v in verdicts if v.contradictions]
    guessed = [v for v in verdicts if v.branch_bound]
    impossible = [v for v in verdicts if v.impossible]
    sprung = [v for v in verdicts if v.outside is not None]
    corrected = final
    if len(named_ok) < len(verdicts):  # --corrected undoes the identified
        units = [*null.units, *(u for c in sure for u in c.units)]
        corrected = fit_effects(physics, data, units, key="full", x0=np.array(
            [final.params[final.units.index(u)] for u in units]))

    r_len, r_tau = evaluate(physics, null, data, key="full")
    location = locate(physics, null, data, r_len, r_tau, paired.joints, paired.muscles,
                      paired.reference)
    entries = [effect_entry(v.named, physics, data, paired.joints, paired.muscles, final)
               | ({"spring_fits_alike": spring_fit(v.spring_alike, paired.joints)}
                  if v.spring_alike else {})
               for v in named_ok]
    ambiguous = [ambiguity_entry(v, physics, data, paired.joints, paired.muscles, final)
                 for v in unsure]
    guessed_entries = [branch_entry(v, paired.muscles, final) for v in guessed]
    factor_entries = [factor_entry(v, paired.muscles) for v in impossible]
    spring_entries = [spring_entry(v, paired.joints, paired.muscles) for v in sprung]
    residual = leftover(physics, springs_in_place(physics, data, final, verdicts), data,
                        paired.joints, paired.muscles, paired.reference)
    rest = rest_entry(residual)
    if arm is not None and design_poses > 0:
        from pimbs_learn.diagnosis.design import (
            branch_telling_poses,
            separating_poses,
            unseen_poses,
        )

        noise = model_info.get("noise_estimate")
        # a factor no arm has is taken up where tension follows pose: the same steps of
        # every wire's tension that tell the loadcells' branches show its stretch apart
        for design, group, out in ((separating_poses, unsure, ambiguous),
                                   (branch_telling_poses, guessed, guessed_entries),
                                   (branch_telling_poses, impossible, factor_entries)):
            for v, entry in zip(group, out, strict=True):
                _propose(entry, design, arm, physics, data, v, design_poses, noise)
        # a rest beside an unsettled question is often what that question leaves: its
        # poses come first; alone, it is asked where the recording has not been
        if rest and not any(e.get("separating_poses") for e in
                            (*ambiguous, *guessed_entries, *factor_entries)):
            _propose(rest, unseen_poses, arm, physics, data, design_poses, noise)
        # a name a joint spring fits about as well is named: its question is asked only
        # where nothing above asks for a session
        if not any(e.get("separating_poses") for e in
                   (*ambiguous, *guessed_entries, *factor_entries, *([rest] if rest else []))):
            for v, entry in zip(named_ok, entries, strict=True):
                if v.spring_alike is not None:
                    _propose(entry["spring_fits_alike"], separating_poses, arm, physics, data,
                             replace(v, rivals=[v.spring_alike]), design_poses, noise)
    sources = [str(r.path) for r in reals]
    result = {
        "real": sources[0], "reference": str(refs[0].path) if refs else None,
        "robot": None if arm is None else arm.robot.name,
        **({"recordings": [{"real": s, "reference": str(refs[i].path) if refs else None}
                           for i, s in enumerate(sources)]} if len(reals) > 1 else {}),
        "rows": data.n, "joints": paired.joints, "muscles": paired.muscles,
        "effects": entries,
        "ambiguous": ambiguous,
        "unexplained": unexplained(ambiguous, rest, location,
                                   [disputed_entry(v, sources) for v in disputed]
                                   + guessed_entries + factor_entries + spring_entries),
        "fit": {"metric": FIT_METRIC, "before": cv_null["score"], "after": cv_final["score"],
                "torque_rms_Nm": {"before": cv_null["torque_rms"],
                                  "after": cv_final["torque_rms"]},
                "length_rms_m": {"before": cv_null["length_rms"],
                                 "after": cv_final["length_rms"]}},
        "location": location,
        "residual": residual,
        "detectable": detectable(physics, data, final, paired.joints, paired.muscles, effects),
        "candidates": [{"name": c.effect, "units": [u.label for u in c.units],
                        "likelihood_ratio": c.lr, "df": c.df, "delta_bic": float(c.delta_bic),
                        "rank_delta_bic": _finite(c.rank_bic),
                        "cv_gain": _finite(c.cv_gain), "cv_z": _finite(c.cv_z),
                        "named": any(c.effect == n.effect and set(c.units) <= set(n.units)
                                     for n in sure)} for c in tried],
        "model": {**model_info, "noise_torque_Nm": null.sigma_tau.tolist(),
                  "noise_length_m": null.sigma_len.tolist(), "sensors": _sensors(final)},
    }
    internals = {"physics": physics, "data": data, "null": null, "final": final,
                 "corrected": corrected, "paired": paired, "recording": reals[0],
                 "recordings": reals, "verdicts": verdicts}
    return result, internals


def _sensors(fit) -> dict:
    """The sensors' own nuisances as fitted beside the named effects (``sensor_units``)."""
    names = {"sensor_lag": "lag_share", "loadcell_hysteresis": "hysteresis_N"}
    out = {names[u.effect]: float(p) for u, p in zip(fit.units, fit.params, strict=True)
           if u.effect in names}
    if out:
        out["meaning"] = ("each reading keeps lag_share of the previous one (a filter read "
                          "soon after the pose); a loadcell reads hysteresis_N lower when "
                          "its tension rose into the pose than when it fell")
    return out


def _read(source: Source) -> Recording:
    return source if isinstance(source, Recording) else read_recording(source)


def _finite(x: float) -> float | None:
    """JSON has no NaN: a statistic that was not computed is null."""
    return float(x) if np.isfinite(x) else None


def write_corrected(internals: dict, path: str | Path) -> None:
    """The real recording with the named effects undone: true tensions, angles, gravity.

    Only effects the recording identifies are undone: of two explanations it cannot tell
    apart, correcting either would be a guess. The sensors' lag and hysteresis, fitted
    beside every model (``model.sensor_units``), are undone too: they are how the boards
    read, not an explanation that competes with another.

    Rows are those paired with the reference; extra columns and metadata are kept, and the
    metadata says what was corrected, so training on it is traceable.
    """
    physics, data, final = internals["physics"], internals["data"], internals["corrected"]
    rec: Recording = internals["recording"]
    if len(internals.get("recordings", [rec])) > 1:
        raise DiagnosisInputError("--corrected writes one recording: diagnose it alone, or "
                                  "leave --corrected out")
    state = apply_effects(physics, data, final.units, final.params)
    keep = np.isin(rec.sample, data.sample)
    table = rec.table.filter(pa.array(keep))
    n, m = data.theta.shape[1], data.tension.shape[1]
    for name, values, width in (("tension", state.tension, m), ("theta", state.theta, n),
                                ("tau_gravity", state.tau, n)):
        arr = pa.FixedSizeListArray.from_arrays(pa.array(values.ravel()), width)
        table = table.set_column(table.column_names.index(name), name, arr)
    meta = {**rec.meta, "corrected_by": "pimbs diagnose",
            "corrections": [f"{u.label}={p:.6g}" for u, p in zip(final.units, final.params,
                                                                   strict=True)]}
    write_recording(path, table, meta)
