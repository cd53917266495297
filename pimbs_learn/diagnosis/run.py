"""`diagnose()`: from recordings to a named, fitted, cross-validated account of the mismatch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from pimbs_learn.diagnosis.detect import detectable
from pimbs_learn.diagnosis.fit import cross_validate, fit_effects
from pimbs_learn.diagnosis.inputs import (
    MIN_SAMPLES,
    DiagnosisInputError,
    build_physics,
    pair,
    too_few_samples,
)
from pimbs_learn.diagnosis.leftover import leftover
from pimbs_learn.diagnosis.locate import locate
from pimbs_learn.diagnosis.model import EFFECTS, apply_effects, evaluate
from pimbs_learn.diagnosis.report import effect_entry
from pimbs_learn.diagnosis.select import select_effects
from pimbs_recording.format import Recording, read_recording, write_recording

FIT_METRIC = ("mean squared held-out residual of lengths and torques, each channel "
              "divided by its noise level under the model without effects (5-fold CV)")


def diagnose(real: str | Path | Recording, reference: str | Path | Recording | None = None,
             robot: str | Path | None = None, effects: tuple[str, ...] = EFFECTS,
             progress=None) -> tuple[dict, dict]:
    """Diagnose ``real`` against a paired ``reference`` recording and/or a robot description.

    Returns (result, internals): ``result`` is the JSON-ready report; ``internals`` holds
    the fitted objects for plots and for writing a corrected recording.
    """
    real_rec = real if isinstance(real, Recording) else read_recording(real)
    ref_rec = (reference if isinstance(reference, Recording) or reference is None
               else read_recording(reference))
    if ref_rec is None and robot is None:
        raise DiagnosisInputError("give --reference SIM.parquet (same commanded poses) or "
                                  "--robot NAME|PATH (the robot description)")
    arm, kappa = None, None
    if robot is not None:
        from pimbs_arm.model import ArmModel

        arm = ArmModel.load(robot)
        if list(arm.joints) != real_rec.joints or list(arm.muscles) != real_rec.muscles:
            raise DiagnosisInputError(
                f"{real_rec.path} does not match robot {arm.robot.name}: recording joints "
                f"{real_rec.joints}, muscles {real_rec.muscles}; description joints "
                f"{list(arm.joints)}, muscles {list(arm.muscles)}")
        if ref_rec is None:
            kappa = -1.0 / arm.K  # PIMBS' own sign convention (l = h − Δn)
    paired = pair(real_rec, ref_rec, arm)
    if paired.real.n < MIN_SAMPLES:
        raise too_few_samples(real_rec.path, paired.real.n)
    physics, model_info = build_physics(paired, kappa)
    data = paired.real
    null = fit_effects(physics, data, [], key="full")
    named, tried, cv_null, final = select_effects(physics, data, null, effects, progress,
                                                  paired.reference)
    # held-out score of the final model on the null model's noise scale (the "before")
    cv_final = (cross_validate(physics, data, final.units, (null.sigma_len, null.sigma_tau),
                               x0=final.params) if named else cv_null)

    r_len, r_tau = evaluate(physics, null, data, key="full")
    location = locate(physics, null, data, r_len, r_tau, paired.joints, paired.muscles,
                      paired.reference)
    entries = [effect_entry(cand, physics, data, paired.joints, paired.muscles, final)
               for cand in named]
    result = {
        "real": str(real_rec.path), "reference": None if ref_rec is None else str(ref_rec.path),
        "robot": None if arm is None else arm.robot.name,
        "rows": data.n, "joints": paired.joints, "muscles": paired.muscles,
        "effects": entries,
        "fit": {"metric": FIT_METRIC, "before": cv_null["score"], "after": cv_final["score"],
                "torque_rms_Nm": {"before": cv_null["torque_rms"],
                                  "after": cv_final["torque_rms"]},
                "length_rms_m": {"before": cv_null["length_rms"],
                                 "after": cv_final["length_rms"]}},
        "location": location,
        "residual": leftover(physics, final, data, paired.joints, paired.muscles,
                             paired.reference),
        "detectable": detectable(physics, data, final, paired.joints, paired.muscles, effects),
        "candidates": [{"name": c.effect, "units": [u.label for u in c.units],
                        "likelihood_ratio": c.lr, "df": c.df, "delta_bic": float(c.delta_bic),
                        "rank_delta_bic": _finite(c.rank_bic),
                        "cv_gain": _finite(c.cv_gain), "cv_z": _finite(c.cv_z),
                        "named": any(c.effect == n.effect and set(c.units) <= set(n.units)
                                     for n in named)} for c in tried],
        "model": {**model_info, "noise_torque_Nm": null.sigma_tau.tolist(),
                  "noise_length_m": null.sigma_len.tolist()},
    }
    internals = {"physics": physics, "data": data, "null": null, "final": final,
                 "paired": paired, "recording": real_rec}
    return result, internals


def _finite(x: float) -> float | None:
    """JSON has no NaN: a statistic that was not computed is null."""
    return float(x) if np.isfinite(x) else None


def write_corrected(internals: dict, path: str | Path) -> None:
    """The real recording with the named effects undone: true tensions, angles, gravity.

    Rows are those paired with the reference; extra columns and metadata are kept, and the
    metadata says what was corrected, so training on it is traceable.
    """
    physics, data, final = internals["physics"], internals["data"], internals["final"]
    rec: Recording = internals["recording"]
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
