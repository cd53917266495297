"""`pimbs diagnose` on a population of drawn arms: what it names against what was concealed.

For every arm of a split of a population (``benchmarks/population.py``) this diagnoses, as a
user with the recording, its clean reference and the robot description would
(``pimbs_learn.diagnosis.run.diagnose(real, reference, robot)``):

* the arm's recording (its concealed truth: the manifest's ``truth``), against a clean
  reference of the same poses with **its own sensor noise** (``OUT/twins``; the
  population's reference files draw the same noise as the recording, scaled, which a
  user's simulated reference never does and which hides noise-made false alarms behind
  the reference check);
* its **null twin**: the same arm, sensors, noise and seed with the concealed effects (and
  on MuJoCo the plant file's changes) removed, written into ``OUT/twins`` — the population
  alone holds too few recordings without effects to measure false alarms;
* with ``--kinds narrow narrow-null``, a **narrow recording** of the same arm (and its null
  twin): a user's first, quick session — ``NARROW_ROWS`` poses drawn in the middle
  ``NARROW_BAND`` of every joint's range, every muscle held at its own floor (the AL-Map) —
  which excites little and so leaves effects confounded that the population's 230 wide ATL
  rows separate; this is where the confounded answers and their separating poses are
  measured (the population's own recordings were never called "either");
* for every recording the diagnosis calls confounded ("either A or B", or "unexplained"
  with the loadcells' hysteresis among the candidates: a name that rests on guessed
  branches), the **separating poses** it proposes (``--poses-out``), collected on the
  same arm with the same concealed effects and sensors (PIMBS's simulator, or MuJoCo as
  the plant with the same plant file) into ``OUT/settle``, and both recordings diagnosed
  together;
* for every other recording whose rest is not noise and that proposes poses (the poses
  farthest from the recorded ones, ``design.unseen_poses``), the same: counted apart from
  the confounded cases, as **rests asked** (there was no rival to tell apart).

Scoring (decided before any run, see docs/diagnosis-notebook.md "On a population of drawn
arms"):

* **Targets** are concealed effects in the diagnosis' vocabulary
  (``pimbs_learn.diagnosis.model.EFFECTS``). Two MuJoCo plant-file changes *are* vocabulary
  effects and count as them: a body's mass (``link_mass``, the same name on both
  simulators) and the tendons' friction loss (``plant_tendon_friction`` → ``tendon_friction``:
  friction along the tendon's path that makes the reading depend on the direction the
  tendon last moved, which is what ``tendon_friction`` means to a user; the capstan is its
  model, MuJoCo's friction loss another).
* **Nuisances**, for which naming nothing or "unexplained" is right and naming any effect is
  wrong: the sensors (noise, motor heating, latency, hysteresis; every recording), and the
  plant physics outside the vocabulary (a joint's friction loss, a joint spring, a muscle's
  sites moved = another routing, which the diagnosis learns as the body schema).
* A recording **with targets** is, by the names the diagnosis gives (``effects``; the
  muscles and joints are reported, not scored): *wrong* if it names an effect outside the
  targets; else *exact* if it names them all and calls nothing "either"; else, naming a
  subset of them, *either* if it says "either A or B" (with whether a missing target is
  among the options), *unexplained* if it says what is left is not explained, *missed*
  otherwise.
* A recording **without targets** (nulls: clean twins and recordings with nuisances only)
  *names something* if it names an effect or says "either A or B" (both claim physics that
  is not there); "unexplained" and nothing are right.
* A confounded case is **resolved** when the two recordings together name exactly the
  targets (nothing, for a null) and call nothing "either".

Outputs: one JSON line per recording in ``OUT/diagnosis-SPLIT.jsonl`` (recordings already
there are skipped, so an interrupted pass resumes), and the confusion tables per simulator
on stdout (``--summary`` prints them from the file alone).

    OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python benchmarks/population_diagnosis.py \\
        --population population --split dev --out population/diagnosis --jobs 2
    .venv/bin/python benchmarks/population_diagnosis.py --summary \\
        population/diagnosis/diagnosis-dev.jsonl
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import sys
import time
from collections import Counter
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pimbs_learn.diagnosis.inputs import DiagnosisInputError  # noqa: E402
from pimbs_learn.diagnosis.model import EFFECTS  # noqa: E402

# The split, fixed before any diagnosis ran: even seeds 0-38 develop (the arms the learning
# work develops on); odd seeds 41-79 judge (odd seeds 1-39 and even 40-78: neither). Once the
# judging split had been looked at, odd seeds 1-39 became a second judging split (``judge2``,
# the same layout of families and simulators), for a rule changed after that look. Once
# both had been looked at, a third judging split of 40 arms never drawn before, seeds 80-119
# (``benchmarks/population.py --arms 40 --seed0 80``: 30 on PIMBS's simulator, 10 with
# MuJoCo as the plant), for rules changed after both looks. After the third had been looked
# at, a fourth of arms no diagnosis had seen: seeds 120-199 (``--seed0 120`` and ``--seed0
# 160``, 40 arms each, drawn for the learning work; diagnose each population with
# ``--split judge4``: the seeds it holds are judged). After the fourth, a fifth: seeds
# 200-245 (``--arms 40 --seed0 200``, which drew 46), for the pose designer's changes. After
# the fifth, a sixth: seeds 246-285 (``--arms 40 --seed0 246``), for the noise estimate of
# several recordings.
SPLITS = {"dev": [s for s in range(0, 39) if s % 2 == 0],
          "judge": [s for s in range(41, 80) if s % 2 == 1],
          "judge2": [s for s in range(1, 40) if s % 2 == 1],
          "judge3": list(range(80, 120)),
          "judge4": list(range(120, 200)),
          "judge5": list(range(200, 246)),
          "judge6": list(range(246, 286)),
          "judge7": list(range(286, 326)),
          "judge8": list(range(326, 366)),
          "judge9": list(range(366, 406)),
          "judge10": list(range(406, 446)),
          "judge11": list(range(446, 486)),
          "judge12": list(range(486, 526)),
          "judge13": list(range(526, 566)),
          "judge14": list(range(566, 606)),
          "judge15": list(range(606, 646)),
          "judge16": list(range(646, 686)),
          "judge17": list(range(686, 726)),
          "judge18": list(range(726, 766))}
AS_TARGET = {"plant_tendon_friction": "tendon_friction"}  # plant physics that is vocabulary
NUISANCES = ("plant_joint_friction", "plant_joint_stiffness", "routing")
SETTLE_SEED = 1000  # the settling session's noise seed: arm seed + this
REFERENCE_NOISE = 10_000  # a reference's noise seed: its recording's seed + this
# The narrow session, fixed before any narrow recording was diagnosed: 100 poses in the
# middle quarter of every joint's range, the AL-Map's floors, its own seed stream.
NARROW_ROWS = 100
NARROW_BAND = 0.25
NARROW_SEED = 2000  # the narrow session's seed: arm seed + this
VERSION = 1         # of what this script writes


def targets(effects: list[dict[str, Any]]) -> list[str]:
    """The vocabulary effects a recording conceals (sorted names, one per effect kind)."""
    out = set()
    for e in effects:
        name = AS_TARGET.get(e["name"], e["name"])
        if name in EFFECTS:
            out.add(name)
        elif e["name"] not in NUISANCES:
            raise ValueError(f"concealed effect {e['name']!r} is neither a target nor a "
                             "nuisance: decide how it counts")
    return sorted(out)


def nuisances(effects: list[dict[str, Any]]) -> list[str]:
    return sorted(e["name"] for e in effects if e["name"] in NUISANCES)


# ------------------------------------------------------------------------- conditions
def conditions(truth: dict[str, Any], effects: bool = True):
    """The manifest's truth as ``pimbs_sim.conditions.Conditions`` (``effects=False``: the
    null twin's, same sensors and noise)."""
    from pimbs_sim.conditions import Conditions
    from pimbs_sim.sensors import SensorModel, SensorNoise, ThermalModel

    s = truth["sensors"]
    sensors = SensorModel(noise=SensorNoise(**s["noise"]), thermal=ThermalModel(**s["thermal"]),
                          latency_s=s["latency_s"], read_after_s=s["read_after_s"],
                          hysteresis_n=s["hysteresis_n"])
    cond = Conditions(truth["simulator"], sensors, truth["noise"],
                      tuple(truth["effects"]) if effects else ())
    if effects and json.loads(json.dumps(cond.to_json())) != truth:
        raise ValueError("the manifest's truth does not round-trip through Conditions")
    return cond


def description_mjcf(line: dict[str, Any], pop: Path) -> Path:
    """The MJCF the muscle file names (the description, which is the null twin's plant)."""
    import yaml

    desc = pop / line["description"]
    return desc.with_name(yaml.safe_load(desc.read_text())["mjcf"])


def record(line: dict[str, Any], pop: Path, cond, plant: Path | None, seed: int,
           poses=None, map_kind: str | None = None) -> tuple[dict, dict]:
    """(columns, metadata) of a recording of the arm under ``cond`` on its simulator."""
    from pimbs_arm.model import ArmModel
    from pimbs_sim.simulate import simulate

    arm = ArmModel.load(pop / line["description"])
    n = line["samples"] if poses is None else len(poses.poses)
    map_kind = map_kind or line["map"]
    if line["simulator"] == "ours":
        data, meta = simulate(arm, n, map_kind, seed=seed, effects=cond.sim_effects(),
                              noise=cond.noise, sensors=cond.sensors, poses=poses)
    else:
        from pimbs_hw.mock.mujoco_recording import record_plant

        data, meta, _ = record_plant(arm, plant, n, map_kind, seed=seed,
                                     effects=cond.sim_effects(), sensors=cond.sensors,
                                     noise=cond.noise, poses=poses)
    meta["created"] = "2026-01-01T00:00:00Z"
    meta["generator"] = "pimbs population"
    return data, meta


def cached(path: Path, settings: list[Any], make: Callable[[], tuple[dict, dict]],
           reuse: bool = True) -> Path:
    """``path``, the recording ``make()`` returns (columns, metadata), written unless it is
    already there for the same ``settings`` (a ``.key`` file beside it holds their hash)."""
    from pimbs_recording.format import write_recording

    key = hashlib.sha256(json.dumps([VERSION, *settings]).encode()).hexdigest()[:16]
    stamp = path.with_suffix(".key")
    if reuse and path.is_file() and stamp.is_file() and stamp.read_text() == key:
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    data, meta = make()
    write_recording(path, data, meta)
    stamp.write_text(key)
    return path


def null_twin(line: dict[str, Any], pop: Path, twins: Path) -> Path:
    """The arm's recording with nothing concealed (cached by its settings)."""
    plant = description_mjcf(line, pop) if line["simulator"] == "mujoco" else None
    return cached(twins / f"{line['arm']}.null.parquet",
                  [line["key"], line["sha256"]["description"]],
                  lambda: record(line, pop, conditions(line["truth"], effects=False), plant,
                                 line["seed"]))


def reference_of(line: dict[str, Any], pop: Path, folder: Path, seed: int,
                 poses=None, stem: str | None = None, map_kind: str | None = None) -> Path:
    """The clean reference of the recording made at ``seed`` (of ``poses``, or of the seed's
    plan): the description on PIMBS's simulator, the same poses, noise of its own."""
    from pimbs_arm.model import ArmModel
    from pimbs_sim.simulate import simulate

    def make() -> tuple[dict, dict]:
        arm = ArmModel.load(pop / line["description"])
        n = line["samples"] if poses is None else len(poses.poses)
        data, meta = simulate(arm, n, map_kind or line["map"], seed=seed,
                              noise_seed=seed + REFERENCE_NOISE, poses=poses)
        meta["created"] = "2026-01-01T00:00:00Z"
        return data, meta

    return cached(folder / f"{stem or line['arm']}.reference.parquet",
                  [line["key"], line["sha256"]["description"], seed, REFERENCE_NOISE], make,
                  reuse=poses is None)  # chosen poses: not part of the key, never reused


class NoNarrowSession(RuntimeError):
    """An arm whose muscles at their floors hold too few poses near the middle of its ranges
    for a narrow session."""


def narrow_plan(line: dict[str, Any], pop: Path):
    """The narrow session's poses (module docstring): seeded, each one held by the muscles at
    their own floors; a draw that cannot be held is drawn again."""
    import numpy as np

    from pimbs_arm.model import ArmModel
    from pimbs_arm.poses import PosePlan, feasible

    arm = ArmModel.load(pop / line["description"])
    lo, hi = arm.joint_range.T
    mid, half = (lo + hi) / 2, (hi - lo) * NARROW_BAND / 2
    f_floor = np.array([m.f_floor for m in arm.robot.muscles])
    rng = np.random.default_rng([line["seed"], NARROW_SEED])
    poses: list[np.ndarray] = []
    for _ in range(50 * NARROW_ROWS):
        theta = rng.uniform(mid - half, mid + half)
        if feasible(arm, theta, f_floor):
            poses.append(theta)
            if len(poses) == NARROW_ROWS:
                break
    else:
        raise NoNarrowSession(f"fewer than {NARROW_ROWS} holdable poses in the middle "
                              f"{NARROW_BAND:.0%} of the ranges")
    floors = np.tile(f_floor, (NARROW_ROWS, 1))
    return PosePlan(poses=np.array(poses), floors=floors, drawn_floors=np.zeros_like(floors),
                    replaced=())


def narrow(line: dict[str, Any], pop: Path, twins: Path, effects: bool
           ) -> tuple[Path, Any, Path | None, Path]:
    """The narrow recording (``effects``: with the arm's concealed truth, else its null
    twin), cached like the twins; (recording, conditions, plant, reference)."""
    kind = "narrow" if effects else "narrow-null"
    cond = conditions(line["truth"], effects=effects)
    plant = None
    if line["simulator"] == "mujoco":
        plant = pop / line["plant"] if effects else description_mjcf(line, pop)
    seed = line["seed"] + NARROW_SEED
    plan = narrow_plan(line, pop)
    path = cached(twins / f"{line['arm']}.{kind}.parquet",
                  [line["key"], kind, NARROW_ROWS, NARROW_BAND],
                  lambda: record(line, pop, cond, plant, seed, plan, map_kind="al"))
    reference = reference_of(line, pop, twins, seed, plan, f"{line['arm']}.{kind}",
                             map_kind="al")
    return path, cond, plant, reference


PROBES = ("plant_tendon_friction", "plant_joint_friction", "plant_joint_stiffness", "routing")


def probe(line: dict[str, Any], pop: Path, twins: Path) -> tuple[Path, Any, Path]:
    """A development probe of the plant physics the population rarely draws: the arm's
    sensors, noise and seed on MuJoCo, with one plant-file change and nothing else (which
    one cycles with the seed; drawn from the stream ``[seed, 8]`` with the population's
    ranges). Only for arms recorded on MuJoCo."""
    from types import SimpleNamespace

    import numpy as np

    from pimbs_sim.conditions import Conditions, _draw_effect, write_plant

    name = PROBES[(line["seed"] // 8) % len(PROBES)]
    spec = SimpleNamespace(muscles=line["muscles"], joints=line["joints"], dof=line["dof"],
                           params=line["params"])
    effect = _draw_effect(name, spec, "mujoco", np.random.default_rng([line["seed"], 8]))
    twins.mkdir(parents=True, exist_ok=True)
    plant = write_plant(description_mjcf(line, pop), (effect,),
                        twins / f"{line['arm']}.probe.xml")
    base = conditions(line["truth"], effects=False)
    cond = Conditions("mujoco", base.sensors, base.noise, (effect,))
    path = cached(twins / f"{line['arm']}.probe.parquet", [line["key"], effect],
                  lambda: record(line, pop, cond, plant, line["seed"]))
    return path, cond, plant


# --------------------------------------------------------------------------- scoring
def answer(result: dict[str, Any]) -> dict[str, Any]:
    """What a diagnosis says, reduced to what is scored (and where, for the reader)."""
    return {"named": sorted({e["name"] for e in result["effects"]}),
            "where": {e["name"]: e["muscles"] + e["joints"] for e in result["effects"]},
            "either": [sorted({o["name"] for o in a["either"]}) for a in result["ambiguous"]],
            "unexplained": [u["why"] for u in result["unexplained"]]}


def outcome(said: dict[str, Any], want: list[str]) -> str:
    """One word for a diagnosis against the targets (module docstring)."""
    named, want_set = set(said["named"]), set(want)
    if not want_set:
        if named or said["either"]:
            return "named"
        return "unexplained" if said["unexplained"] else "nothing"
    if named - want_set:
        return "wrong"
    if named == want_set and not said["either"]:
        return "exact"
    if said["either"]:
        return "either"
    return "unexplained" if said["unexplained"] else "missed"


def truth_in_either(said: dict[str, Any], want: list[str]) -> bool:
    missing = set(want) - set(said["named"])
    return bool(missing) and any(missing & set(e) for e in said["either"])


# ------------------------------------------------------------------------ one recording
class StaleRecording(RuntimeError):
    """A population recording whose poses today's pose plan of its seed no longer draws."""


def check_poses_match(real: Path, reference: Path) -> None:
    """``StaleRecording`` when the stored recording commands a pose that today's reference of
    its seed does not: the population was generated by a pose plan that has changed since
    (a pose it replaced, or not, differently), and the pair cannot be diagnosed.

    A recording that holds fewer rows than planned (the MuJoCo plant could not hold some
    poses, and the collection went on without them) is scored on the rows it holds, paired
    by sample id as ``pimbs diagnose`` pairs any recording with its reference."""
    import numpy as np

    from pimbs_recording.format import read_recording

    a, b = read_recording(real), read_recording(reference)
    extra = np.setdiff1d(a.sample, b.sample)
    _, ia, ib = np.intersect1d(a.sample, b.sample, return_indices=True)
    moved = np.flatnonzero(~np.isclose(a.theta_command[ia], b.theta_command[ib]).all(axis=1))
    if extra.size or moved.size:
        at = int(extra[0]) if extra.size else int(a.sample[ia][moved[0]])
        raise StaleRecording(f"its poses differ from today's plan of its seed at sample {at}: "
                             "regenerate the population to score it")


def diagnose_one(line: dict[str, Any], pop: Path, out: Path, twins: Path, kind: str,
                 settle: bool) -> dict[str, Any]:
    """Diagnose the recording (``kind`` "recording") or the null twin of one arm; then, if
    it is confounded, collect the separating poses and diagnose both together."""
    from pimbs_learn.diagnosis.run import diagnose

    t_cpu, t_wall = time.process_time(), time.perf_counter()
    robot = pop / line["description"]
    mujoco = line["simulator"] == "mujoco"
    if kind == "recording":
        real, cond = pop / line["recording"], conditions(line["truth"])
        plant = pop / line["plant"] if mujoco else None
    elif kind == "probe":
        real, cond, plant = probe(line, pop, twins)
    elif kind in ("narrow", "narrow-null"):
        real, cond, plant, reference = narrow(line, pop, twins, kind == "narrow")
    else:
        real, cond = null_twin(line, pop, twins), conditions(line["truth"], effects=False)
        plant = description_mjcf(line, pop) if mujoco else None
    truth = list(cond.effects)
    t_made = time.process_time() - t_cpu
    if not kind.startswith("narrow"):
        reference = reference_of(line, pop, twins, line["seed"])
    if kind == "recording":
        check_poses_match(real, reference)
    c0 = time.process_time()
    result, _ = diagnose(real, reference, robot=robot)
    said = answer(result)
    want = targets(truth)
    rec: dict[str, Any] = {
        "arm": line["arm"], "seed": line["seed"], "kind": kind,
        "simulator": line["simulator"], "family": line["family"], "dof": line["dof"],
        "n_muscles": line["n_muscles"], "rows": result["rows"], "truth": truth,
        "targets": want, "nuisances": nuisances(truth), **said,
        "outcome": outcome(said, want), "truth_in_either": truth_in_either(said, want),
        "cpu_s": round(time.process_time() - c0, 2)}
    asked = [u for u in result["unexplained"] if u.get("separating_poses")]
    if settle and (said["either"] or asked):
        rec["settle"] = settle_one(line, pop, out, kind, result, real, reference, want, cond,
                                   plant)
        # an unexplained entry with candidates is a question between explanations; a rest
        # without any is not
        rec["settle"]["confounded"] = bool(said["either"]
                                           or any(u.get("candidates") for u in asked))
    rec["cpu_s_total"] = round(time.process_time() - t_cpu, 2)
    rec["cpu_s_twin"] = round(t_made, 2) if kind != "recording" else 0.0
    rec["wall_s"] = round(time.perf_counter() - t_wall, 2)
    return rec


def settle_one(line: dict[str, Any], pop: Path, out: Path, kind: str, result: dict,
               real: Path, reference: Path, want: list[str], cond, plant: Path | None
               ) -> dict[str, Any]:
    """Collect the proposed poses on the same arm (same concealed effects, sensors, plant)
    and diagnose the first and the new recording together, each with its reference."""
    from pimbs_arm.model import ArmModel
    from pimbs_arm.poses_file import read_pose_plan
    from pimbs_learn.diagnosis.design import design_csv
    from pimbs_learn.diagnosis.run import diagnose
    from pimbs_recording.format import write_recording

    csv, count = design_csv(result)
    if not count:
        return {"poses": 0, "resolved": False, "note": "no poses proposed"}
    folder = out / "settle"
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"{line['arm']}.{kind}"
    design = folder / f"{stem}.poses.csv"
    design.write_text(csv)
    arm = ArmModel.load(pop / line["description"])
    plan = read_pose_plan(design, arm)  # as `pimbs collect --poses-file` reads it
    seed = line["seed"] + SETTLE_SEED
    c0 = time.process_time()
    data, meta = record(line, pop, cond, plant, seed, plan)
    real2 = folder / f"{stem}.parquet"
    write_recording(real2, data, meta)
    ref2 = reference_of(line, pop, folder, seed, plan, stem)
    c1 = time.process_time()
    both, _ = diagnose([real, real2], [reference, ref2], robot=pop / line["description"])
    said = answer(both)
    return {"poses": count, "expected_lr": [a["separating_poses"]["expected_likelihood_ratio"]
                                            for a in result["ambiguous"]
                                            + result["unexplained"]
                                            if a.get("separating_poses")],
            **said, "outcome": outcome(said, want),
            "resolved": outcome(said, want) == ("exact" if want else "nothing"),
            "cpu_s_record": round(c1 - c0, 2), "cpu_s": round(time.process_time() - c1, 2)}


# --------------------------------------------------------------------------- summary
ORDER_EFFECTS = ("exact", "wrong", "missed", "either", "unexplained")
ORDER_NULLS = ("nothing", "unexplained", "named")


SESSIONS = {"population": ("recording", "null"), "narrow": ("narrow", "narrow-null")}


def summary(lines: list[dict[str, Any]]) -> str:
    """Confusion tables per session and simulator (markdown); the development probes apart."""
    out = []
    for session, kinds in SESSIONS.items():
        rows = [r for r in lines if r["kind"] in kinds]
        for sim in ("ours", "mujoco"):
            part = [r for r in rows if r["simulator"] == sim]
            if part:
                out.append(_tables(part, sim, session))
    probes = [r for r in lines if r["kind"] == "probe"]
    if probes:
        out.append(_probes(probes))
    return "\n".join(out)


def _tables(rows: list[dict[str, Any]], sim: str, session: str) -> str:
    """The confusion tables of one session's recordings on one simulator."""
    title = "PIMBS's simulator" if sim == "ours" else "MuJoCo as the plant"
    what = "" if session == "population" else f", {session} session"
    out = [f"\n### {title}{what} ({len(rows)} recordings)\n"]
    out.append("| recordings with effects | n | " + " | ".join(ORDER_EFFECTS)
               + " | truth among the options |")
    out.append("|---|---|" + "---|" * (len(ORDER_EFFECTS) + 1))
    for label, keep in (("single effect", lambda r: len(r["targets"]) == 1),
                        ("two effects", lambda r: len(r["targets"]) >= 2),
                        ("all", lambda r: len(r["targets"]) >= 1)):
        group = [r for r in rows if keep(r)]
        if not group:
            continue
        c = Counter(r["outcome"] for r in group)
        either = [r for r in group if r["outcome"] == "either"]
        out.append(f"| {label} | {len(group)} | "
                   + " | ".join(_share(c[k], len(group)) for k in ORDER_EFFECTS)
                   + f" | {sum(r['truth_in_either'] for r in either)}/{len(either)} |")
    out.append("\n| recordings without effects | n | " + " | ".join(ORDER_NULLS) + " |")
    out.append("|---|---|" + "---|" * len(ORDER_NULLS))
    for label, keep in (("null twins", lambda r: r["kind"].endswith("null")),
                        (f"{session}, none concealed",
                         lambda r: not r["kind"].endswith("null") and not r["nuisances"]),
                        (f"{session}, plant nuisances only",
                         lambda r: not r["kind"].endswith("null") and r["nuisances"]),
                        ("all", lambda r: True)):
        group = [r for r in rows if not r["targets"] and keep(r)]
        if not group:
            continue
        c = Counter(r["outcome"] for r in group)
        out.append(f"| {label} | {len(group)} | "
                   + " | ".join(_share(c[k], len(group)) for k in ORDER_NULLS) + " |")
    for label, group in (("confounded cases", _confounded(rows, True)),
                         ("rests asked where the recording had not been",
                          _confounded(rows, False))):
        if group:
            c = Counter(r["settle"]["outcome"] for r in group)
            res = sum(r["settle"]["resolved"] for r in group)
            out.append(f"\n{label}: {len(group)}; resolved by their poses "
                       f"{_share(res, len(group))} (after: "
                       + ", ".join(f"{k} {v}" for k, v in sorted(c.items())) + ")")
    wrong = Counter(n for r in rows for n in r["named"] if n not in r["targets"])
    if wrong:
        out.append("effects named wrongly: " + ", ".join(f"{k} {v}"
                                                      for k, v in wrong.most_common()))
    cpu = sorted(r["cpu_s"] for r in rows)
    out.append(f"CPU per diagnosis: median {cpu[len(cpu) // 2]:.1f} s, max {cpu[-1]:.1f} s;"
               f" per recording with twin and settling: "
               f"{sum(r['cpu_s_total'] for r in rows) / len(rows):.1f} s on average")
    return "\n".join(out)


def _probes(probes: list[dict[str, Any]]) -> str:
    """The development probes, one row each."""
    out = ["\n### Development probes: one plant-file change on MuJoCo\n",
           "| arm | concealed | counts as | named | either | outcome | settled |",
           "|---|---|---|---|---|---|---|"]
    for r in sorted(probes, key=lambda r: r["arm"]):
        e = r["truth"][0]
        out.append(f"| {r['arm']} | {e['name']} {e['magnitude']:g} | "
                   f"{', '.join(r['targets']) or 'nuisance'} | {', '.join(r['named']) or '–'}"
                   f" | {' / '.join(' or '.join(x) for x in r['either']) or '–'} | "
                   f"{r['outcome']} | {r.get('settle', {}).get('outcome', '–')} |")
    return "\n".join(out)


def _confounded(rows: list[dict[str, Any]], confounded: bool) -> list[dict[str, Any]]:
    """The settled rows that were confounded (``confounded``), or rests asked."""
    return [r for r in rows if r.get("settle")
            and r["settle"].get("confounded", True) == confounded]


def _share(k: int, n: int) -> str:
    return f"{k} ({100 * k / n:.0f} %)" if n else "–"


def bars(lines: list[dict[str, Any]]) -> str:
    """The done bar, per session and simulator."""
    out = []
    for (session, kinds), sim in itertools.product(SESSIONS.items(), ("ours", "mujoco")):
        rows = [r for r in lines if r["simulator"] == sim and r["kind"] in kinds]
        eff = [r for r in rows if r["targets"]]
        nul = [r for r in rows if not r["targets"]]
        conf = _confounded(rows, True)
        if not rows:
            continue
        exact = sum(r["outcome"] == "exact" for r in eff)
        wrong = sum(r["outcome"] == "wrong" for r in eff)
        named = sum(r["outcome"] == "named" for r in nul)
        res = sum(r["settle"]["resolved"] for r in conf)
        out.append(f"{session}, {sim}: exact {exact}/{len(eff)} (bar ≥ 90 %), wrong "
                   f"{wrong}/{len(eff)} (≤ 5 %), nulls naming something {named}/{len(nul)} "
                   "(≤ 1 in 20), "
                   f"confounded resolved {res}/{len(conf)} (≥ 80 %)")
    return "\n".join(out)


# ------------------------------------------------------------------------------ main
def read_lines(path: Path) -> list[dict[str, Any]]:
    if not path.is_file():
        return []
    return [json.loads(s) for s in path.read_text().splitlines() if s.strip()]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--population", type=Path, help="folder with manifest.jsonl")
    ap.add_argument("--split", choices=sorted(SPLITS))
    ap.add_argument("--out", type=Path, help="folder for twins, settling sessions, results")
    ap.add_argument("--twins", type=Path, help="folder of the null twins and references "
                    "(default OUT/twins; they depend on the population only, so passes may "
                    "share them)")
    ap.add_argument("--arms", nargs="*", help="only these arms (armNNN) of the split")
    ap.add_argument("--kinds", nargs="*", default=["recording", "null"],
                    choices=["recording", "null", "probe", "narrow", "narrow-null"],
                    help="probe: on the development split's MuJoCo arms, one plant-file "
                    "change alone (the population rarely draws them); narrow, narrow-null: "
                    "a short session in the middle of the ranges at the AL-Map's floors, "
                    "with and without the concealed effects")
    ap.add_argument("--no-settle", action="store_true", help="skip the separating poses")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--summary", type=Path, help="print the tables of a results file")
    a = ap.parse_args()
    if a.summary:
        if not a.summary.is_file():
            ap.error(f"{a.summary}: no such results file (a pass writes OUT/diagnosis-SPLIT.jsonl)")
        lines = read_lines(a.summary)
        print(summary(lines))
        print("\n" + bars(lines))
        return
    if not (a.population and a.split and a.out):
        ap.error("--population, --split and --out are needed (or --summary FILE)")
    if "probe" in a.kinds and a.split != "dev":
        ap.error("--kinds probe is for the development split only (--split dev)")
    pop, out = a.population.resolve(), a.out.resolve()
    twins = (a.twins or out / "twins").resolve()
    results = out / f"diagnosis-{a.split}.jsonl"
    if not (pop / "manifest.jsonl").is_file():
        ap.error(f"{pop}: no manifest.jsonl; draw a population there first with "
                 f"benchmarks/population.py --out {pop}")
    manifest = {d["arm"]: d for d in read_lines(pop / "manifest.jsonl")}
    arms = [manifest[f"arm{s:03d}"] for s in SPLITS[a.split] if f"arm{s:03d}" in manifest]
    if not arms:
        seeds = SPLITS[a.split]
        ap.error(f"{pop} holds no arm of the {a.split} split (seeds {seeds[0]}-{seeds[-1]}); "
                 "choose the split its seeds belong to")
    if a.arms:
        unknown = sorted(set(a.arms) - {d["arm"] for d in arms})
        if unknown:
            ap.error(f"not arms of the {a.split} split in {pop}: {', '.join(unknown)}")
        arms = [d for d in arms if d["arm"] in set(a.arms)]
    out.mkdir(parents=True, exist_ok=True)
    done = {(r["arm"], r["kind"]) for r in read_lines(results)}
    no_narrow = set()
    for d in arms if {"narrow", "narrow-null"} & set(a.kinds) else ():
        try:
            narrow_plan(d, pop)
        except NoNarrowSession as exc:
            no_narrow.add(d["arm"])
            print(f"{d['arm']}: no narrow session ({exc})", flush=True)
    todo = [(d, k) for d in arms for k in a.kinds
            if (d["arm"], k) not in done
            and not (k.startswith("narrow") and d["arm"] in no_narrow)
            and (k in ("recording", "narrow") or (
                k in ("null", "narrow-null") and d["truth"]["effects"]) or (
                k == "probe" and d["simulator"] == "mujoco"))]
    todo.sort(key=lambda t: t[0]["simulator"] != "mujoco")  # the slow ones first
    print(f"{len(arms)} arms of the {a.split} split; {len(todo)} recordings to diagnose, "
          f"{len(done)} already in {results}", flush=True)
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        futures = {pool.submit(diagnose_one, d, pop, out, twins, k, not a.no_settle): (d, k)
                   for d, k in todo}
        for future in as_completed(futures):
            try:
                r = future.result()
            # a stored recording that no longer matches, or one the diagnosis refuses (a
            # plant that held too few of the poses): reported, not scored
            except (StaleRecording, DiagnosisInputError) as exc:
                d, k = futures[future]
                print(f"{d['arm']} {k}: not scored ({exc})", flush=True)
                continue
            with results.open("a") as fh:
                fh.write(json.dumps(r) + "\n")
            settled = r.get("settle", {})
            print(f"{r['arm']} {r['kind']:9s} {r['simulator']:6s} want {r['targets'] or '-'} "
                  f"named {r['named'] or '-'} either {r['either'] or '-'} -> {r['outcome']}"
                  + (f"; settled: {settled.get('outcome')}" if settled else "")
                  + f" ({r['cpu_s']:.0f} s CPU)", flush=True)
    print(f"{len(todo)} recordings in {time.perf_counter() - t0:.0f} s wall")
    lines = [r for r in read_lines(results) if r["arm"] in {d["arm"] for d in arms}]
    print(summary(lines))
    print("\n" + bars(lines))


if __name__ == "__main__":
    main()
