"""What a population arm's recording conceals: its sensors and the physics its model lacks.

Drawn from the arm's seed, recorded as ground truth in the population's manifest and nowhere
in the recording itself, so a learner or a diagnosis sees only what a lab would see.

* **Sensors** (every recording; ``pimbs_sim.sensors``): white-noise scale 0.7–1.5× the
  defaults; motor heating 0.03–0.10 °C per N held with a time constant of 120–600 s; a
  loadcell/encoder filter of 0–0.35 s read 1 s after the pose is reached (up to 6 % of the
  previous pose's reading left in); loadcell hysteresis of 0–1.5 N.
* **Concealed physics** (on ``CONCEALED_SHARE`` of recordings, one effect or two): on both
  simulators the effects of ``pimbs_sim.effects`` (capstan friction of the readings
  μ 0.05–0.15; one loadcell's offset ±8–25 N or gain ±10–25 %; thermal drift ±0.3–1 N/°C;
  one joint's encoder offset ±0.02–0.06 rad; springs K ×0.5–0.75 or ×1.4–2.0; one link
  ×0.6–0.8 or ×1.25–1.6 as heavy). On MuJoCo as the plant also what the plant file says and
  the description does not (``plant_changes``): tendon friction loss (2–8 N, every tendon),
  one joint's friction loss or a passive spring (stiffness and spring reference), a link's
  mass, and one muscle's sites moved 3–6 mm on the link it pulls (``routing``).

Each effect is a JSON-able dict: ``name``, ``magnitude`` (SI units, see ``UNITS``), where it
acts (``muscles``, ``joints``, ``link``) and ``where`` (``loadcell``, ``encoder``,
``physics`` or ``plant file``).
"""

from __future__ import annotations

import copy
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pimbs_sim.effects import Effect
from pimbs_sim.population import ArmSpec
from pimbs_sim.sensors import SensorModel, SensorNoise, ThermalModel

SIMULATORS = ("ours", "mujoco")
CONCEALED_SHARE = 0.7  # of recordings with concealed physics (the rest: none)
TWO_SHARE = 0.35       # of those with two effects at once
COMMON = ("tendon_friction", "tension_offset", "tension_gain", "thermal_drift", "link_mass",
          "joint_offset", "elastic_stiffness")
PLANT_ONLY = ("routing", "plant_tendon_friction", "plant_joint_friction",
              "plant_joint_stiffness")
PLANT_FILE = ("link_mass", "routing", "plant_tendon_friction", "plant_joint_friction",
              "plant_joint_stiffness")  # on MuJoCo: written into the plant MJCF
UNITS = {"tendon_friction": "capstan mu", "tension_offset": "N", "tension_gain": "gain error",
         "thermal_drift": "N/degC", "link_mass": "mass scale", "joint_offset": "rad",
         "elastic_stiffness": "K scale", "routing": "m (site shift)",
         "plant_tendon_friction": "N (tendon frictionloss)",
         "plant_joint_friction": "N*m (joint frictionloss)",
         "plant_joint_stiffness": "N*m/rad (joint stiffness)"}


@dataclass(frozen=True)
class Conditions:
    """One recording's concealed truth: how its sensors read and what physics it hides."""

    simulator: str
    sensors: SensorModel
    noise: float                          # scale of the white noise
    effects: tuple[dict[str, Any], ...]   # ground truth, JSON-able

    def sim_effects(self) -> tuple[Effect, ...]:
        """The effects the simulator applies itself (``pimbs_sim.effects``); on MuJoCo the
        plant file's are left out (``write_plant`` puts them in the file)."""
        out = []
        for e in self.effects:
            if self.simulator == "mujoco" and e["name"] in PLANT_FILE:
                continue
            out.append(Effect(name=e["name"], magnitude=e["magnitude"],
                              muscles=tuple(e.get("muscles", ())),
                              joints=tuple(e.get("joints", ())), link=e.get("link")))
        return tuple(out)

    def plant_changes(self) -> tuple[dict[str, Any], ...]:
        return tuple(e for e in self.effects
                     if self.simulator == "mujoco" and e["name"] in PLANT_FILE)

    def to_json(self) -> dict[str, Any]:
        return {"simulator": self.simulator, "sensors": self.sensors.to_json(),
                "noise": self.noise, "effects": list(self.effects)}


def draw_conditions(spec: ArmSpec, simulator: str) -> Conditions:
    """The sensors and concealed physics of ``spec``'s recording on ``simulator``, drawn
    from the arm's seed (stream ``[seed, 7]``)."""
    if simulator not in SIMULATORS:
        raise ValueError(f"simulator must be one of {', '.join(SIMULATORS)}, not {simulator!r}")
    if simulator == "mujoco" and spec.family != "mujoco":
        raise ValueError(f"{spec.name} is a {spec.family} arm; only an MJCF runs on MuJoCo")
    rng = np.random.default_rng([spec.seed, 7])
    sensors = SensorModel(
        noise=SensorNoise(),
        thermal=ThermalModel(gain=round(float(rng.uniform(0.03, 0.10)), 4),
                             time_constant=round(float(rng.uniform(120.0, 600.0)), 1)),
        latency_s=round(float(rng.uniform(0.0, 0.35)), 4), read_after_s=1.0,
        hysteresis_n=round(float(rng.uniform(0.0, 1.5)), 3))
    noise = round(float(rng.uniform(0.7, 1.5)), 3)
    count = 0
    if rng.random() < CONCEALED_SHARE:
        count = 2 if rng.random() < TWO_SHARE else 1
    pool = list(COMMON) + (list(PLANT_ONLY) if simulator == "mujoco" else [])
    names = rng.choice(pool, size=count, replace=False).tolist() if count else []
    effects = tuple(_draw_effect(str(n), spec, simulator, rng) for n in names)
    return Conditions(simulator, sensors, noise, effects)


def _sign(rng: np.random.Generator) -> float:
    return float(rng.choice([-1.0, 1.0]))


def _draw_effect(name: str, spec: ArmSpec, simulator: str, rng: np.random.Generator
                 ) -> dict[str, Any]:
    """One effect's magnitude and place (see the module docstring for the ranges)."""
    muscle = str(rng.choice(spec.muscles))
    k = int(rng.integers(spec.dof))
    joint = spec.joints[k]
    gravity = max(float(spec.params["gravity_bound"][k]), 1.0)  # N·m, at least 1
    where = "plant file" if simulator == "mujoco" and name in PLANT_FILE else {
        "tendon_friction": "loadcell", "tension_offset": "loadcell",
        "tension_gain": "loadcell", "thermal_drift": "loadcell", "joint_offset": "encoder",
    }.get(name, "physics")
    e: dict[str, Any] = {"name": name, "unit": UNITS[name], "where": where}
    if name == "tendon_friction":
        e["magnitude"] = rng.uniform(0.05, 0.15)
    elif name == "tension_offset":
        e.update(magnitude=_sign(rng) * rng.uniform(8.0, 25.0), muscles=[muscle])
    elif name == "tension_gain":
        e.update(magnitude=_sign(rng) * rng.uniform(0.10, 0.25), muscles=[muscle])
    elif name == "thermal_drift":
        e["magnitude"] = _sign(rng) * rng.uniform(0.3, 1.0)
    elif name == "link_mass":
        scale = rng.uniform(1.25, 1.6) if rng.random() < 0.5 else rng.uniform(0.6, 0.8)
        e.update(magnitude=scale, link=spec.params["links"][k]["name"])
    elif name == "joint_offset":
        e.update(magnitude=_sign(rng) * rng.uniform(0.02, 0.06), joints=[joint])
    elif name == "elastic_stiffness":
        e["magnitude"] = rng.uniform(0.5, 0.75) if rng.random() < 0.5 else rng.uniform(1.4, 2.0)
    elif name == "plant_tendon_friction":
        e["magnitude"] = rng.uniform(2.0, 8.0)
    elif name == "plant_joint_friction":
        e.update(magnitude=rng.uniform(0.03, 0.08) * gravity, joints=[joint])
    elif name == "plant_joint_stiffness":
        half = spec.params["joints"][k]["half_range"]
        e.update(magnitude=rng.uniform(0.1, 0.3) * gravity / half, joints=[joint],
                 springref=round(float(rng.uniform(-0.5, 0.5) * half), 4))
    elif name == "routing":
        direction = rng.normal(size=3)
        e.update(magnitude=rng.uniform(0.003, 0.006), muscles=[muscle],
                 direction=[round(float(v), 4) for v in direction / np.linalg.norm(direction)])
    else:
        raise ValueError(f"unknown concealed effect {name!r}")
    e["magnitude"] = round(float(e["magnitude"]), 5)
    return e


def write_plant(description: Path, changes: tuple[dict[str, Any], ...], out: Path) -> Path:
    """The plant MJCF: the description ``description`` with ``changes`` written into it (a
    body's mass and inertia, sites moved, friction losses, joint springs). Without changes
    the description itself is the plant and is returned as it is."""
    if not changes:
        return description
    tree = ET.parse(description)
    root = tree.getroot()

    def named(tag: str, name: str) -> ET.Element:
        found = root.find(f".//{tag}[@name='{name}']")
        if found is None:
            raise ValueError(f"{description}: no <{tag} name='{name}'>")
        return found

    for c in changes:
        name = c["name"]
        if name == "link_mass":
            inertial = named("body", c["link"]).find("inertial")
            inertial.set("mass", f"{float(inertial.get('mass')) * c['magnitude']:.6g}")
            diag = [float(v) * c["magnitude"] for v in inertial.get("diaginertia").split()]
            inertial.set("diaginertia", " ".join(f"{v:.6g}" for v in diag))
        elif name == "plant_tendon_friction":
            for spatial in root.iter("spatial"):
                spatial.set("frictionloss", f"{c['magnitude']:g}")
        elif name == "plant_joint_friction":
            for j in c["joints"]:
                named("joint", j).set("frictionloss", f"{c['magnitude']:g}")
        elif name == "plant_joint_stiffness":
            for j in c["joints"]:
                named("joint", j).set("stiffness", f"{c['magnitude']:g}")
                named("joint", j).set("springref", f"{c['springref']:g}")
        elif name == "routing":
            _move_sites(root, c)
        else:
            raise ValueError(f"{name} is not written into a plant file")
    out.write_text(f"<!-- the plant of {description.name}: {describe(changes)} -->\n"
                   + ET.tostring(copy.deepcopy(root), encoding="unicode") + "\n")
    return out


def _move_sites(root: ET.Element, change: dict[str, Any]) -> None:
    """Shift the sites of one muscle on the links beyond its first crossing: the wire
    inserts elsewhere than the description says."""
    muscle = change["muscles"][0]
    spatial = root.find(f".//spatial[@name='{muscle}']")
    sites = [s.get("site") for s in spatial.findall("site")]
    bodies = {s.get("name"): b for b in root.iter("body") for s in b.findall("site")}
    shift = np.array(change["direction"]) * change["magnitude"]
    origin = bodies.get(sites[0])  # None: the world body
    for name in sites[1:]:
        body = bodies.get(name)
        if body is not None and body is not origin:
            site = body.find(f"site[@name='{name}']")
            pos = np.array([float(v) for v in site.get("pos").split()]) + shift
            site.set("pos", " ".join(f"{v:.6g}" for v in pos))


def describe(effects: tuple[dict[str, Any], ...] | list[dict[str, Any]]) -> str:
    """'none' or 'name:magnitude@place, ...' for one line of output."""
    if not effects:
        return "none"
    parts = []
    for e in effects:
        place = e.get("link") or "+".join(e.get("muscles", []) + e.get("joints", []))
        parts.append(f"{e['name']}:{e['magnitude']:g}" + (f"@{place}" if place else ""))
    return ", ".join(parts)
