"""Which topics, message types and fields of a log hold which quantities.

The default is the convention in ``docs/recording-format.md``:

* ``/joint_states`` (``sensor_msgs/JointState``): ``position`` = joint angles, by ``name``
  (names the robot does not drive are ignored);
* ``/muscle_states`` (``sensor_msgs/JointState``): ``name`` = muscle names, ``position`` =
  motor-side length (m), ``effort`` = tension (N);
* ``/muscle_temperature`` (``std_msgs/Float64MultiArray``, optional): ``data`` in the robot's
  muscle order (°C).

A ``--map`` YAML file overrides any part, per quantity (``theta``, ``length``, ``tension``,
``temperature``): ``topic``, ``type``, ``field``, ``names`` (the field with the names, for
JointState-like messages) or ``order`` (the names of an array's elements, in order),
``rename`` (log name -> robot name), ``scale`` and ``offset`` (value = raw·scale + offset,
scalar or one per joint/muscle in the robot's order); ``temperature: null`` says the log has
none. Top-level ``clock: log | header`` picks the time base (the recorder's receive time, one
clock for all topics, or the messages' ``header.stamp``), ``settle`` the held-pose criterion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

QUANTITIES = ("theta", "length", "tension", "temperature")
JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT_ARRAY = "std_msgs/msg/Float64MultiArray"


class MappingError(ValueError):
    """A mapping file (or the default convention applied to a log) is wrong; names the fix."""


@dataclass(frozen=True)
class Channel:
    """Where one quantity is in the log."""

    topic: str
    type: str
    field: str
    names: str | None = "name"  # field holding the element names (None: use ``order``)
    order: tuple[str, ...] | None = None  # element names of an array message, in order
    rename: dict[str, str] = field(default_factory=dict)
    scale: float | tuple[float, ...] = 1.0
    offset: float | tuple[float, ...] = 0.0


@dataclass(frozen=True)
class SettleRule:
    """The collection's settle criterion (``pimbs collect``'s defaults) plus how long a
    pose must be held to count."""

    window: float = 0.1  # s
    tension_tol: float = 1.0  # N
    length_tol: float = 3e-5  # m
    theta_tol: float = 5e-4  # rad
    min_hold: float = 0.5  # s a quiet stretch must last to be a held pose
    min_readings: int = 4


@dataclass(frozen=True)
class LogMapping:
    channels: dict[str, Channel | None]
    clock: str = "log"
    settle: SettleRule = SettleRule()
    temperature_fill: float = 25.0  # °C written when the log has no temperatures
    source: str = "default convention"

    def meta(self) -> dict[str, Any]:
        """The mapping as it was applied, for the recording's metadata."""
        chans = {}
        for name, ch in self.channels.items():
            chans[name] = None if ch is None else {
                "topic": ch.topic, "type": ch.type, "field": ch.field, "names": ch.names,
                "order": list(ch.order) if ch.order else None, "rename": dict(ch.rename),
                "scale": ch.scale, "offset": ch.offset}
        return {"source": self.source, "clock": self.clock, "channels": chans,
                "settle": self.settle.__dict__.copy()}


DEFAULT = LogMapping(channels={
    "theta": Channel("/joint_states", JOINT_STATE, "position"),
    "length": Channel("/muscle_states", JOINT_STATE, "position"),
    "tension": Channel("/muscle_states", JOINT_STATE, "effort"),
    "temperature": Channel("/muscle_temperature", FLOAT_ARRAY, "data", names=None),
})


def normalize_type(name: str) -> str:
    """``sensor_msgs/JointState`` (ROS 1 style) -> ``sensor_msgs/msg/JointState``."""
    parts = name.strip().split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else name.strip()


def load_mapping(path: Path | None) -> LogMapping:
    """The default convention, overridden by the YAML file at ``path``."""
    if path is None:
        return DEFAULT
    try:
        raw = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise MappingError(f"{path}: cannot read the mapping ({exc}); fix the YAML") from exc
    if not isinstance(raw, dict):
        raise MappingError(f"{path}: expected a mapping with keys {', '.join(QUANTITIES)}, "
                           "clock, settle")
    unknown = sorted(set(raw) - {*QUANTITIES, "clock", "settle", "temperature_fill"})
    if unknown:
        raise MappingError(f"{path}: unknown key(s) {unknown}; allowed: "
                           f"{', '.join(QUANTITIES)}, clock, settle, temperature_fill")
    channels = dict(DEFAULT.channels)
    for name in QUANTITIES:
        if name in raw:
            channels[name] = _channel(raw[name], DEFAULT.channels[name], path, name)
    if channels["theta"] is None or channels["length"] is None or channels["tension"] is None:
        raise MappingError(f"{path}: theta, length and tension cannot be null (only "
                           "temperature is optional)")
    clock = raw.get("clock", "log")
    if clock not in ("log", "header"):
        raise MappingError(f"{path}: clock: {clock!r}; use 'log' (recorder time) or "
                           "'header' (header.stamp)")
    settle = raw.get("settle") or {}
    if not isinstance(settle, dict) or set(settle) - set(SettleRule.__dataclass_fields__):
        raise MappingError(f"{path}: settle: expected a mapping of "
                           f"{', '.join(SettleRule.__dataclass_fields__)}")
    rule = replace(SettleRule(), **{k: _number(v, path, f"settle.{k}") for k, v in
                                    settle.items()})
    fill = _number(raw.get("temperature_fill", 25.0), path, "temperature_fill")
    return LogMapping(channels=channels, clock=clock, settle=rule, temperature_fill=fill,
                      source=str(path))


def _channel(raw: Any, default: Channel, path: Path, name: str) -> Channel | None:
    if raw is None:
        return None
    if not isinstance(raw, dict):
        raise MappingError(f"{path}: {name}: expected a mapping (topic, type, field, names, "
                           "order, rename, scale, offset) or null")
    allowed = {"topic", "type", "field", "names", "order", "rename", "scale", "offset"}
    if set(raw) - allowed:
        raise MappingError(f"{path}: {name}: unknown key(s) {sorted(set(raw) - allowed)}; "
                           f"allowed: {', '.join(sorted(allowed))}")
    ch = replace(default, **{k: v for k, v in raw.items() if k in ("topic", "field")})
    if "type" in raw:
        ch = replace(ch, type=normalize_type(str(raw["type"])))
    if "order" in raw:
        order = raw["order"]
        if not isinstance(order, list) or not all(isinstance(o, str) for o in order):
            raise MappingError(f"{path}: {name}.order: expected a list of names")
        ch = replace(ch, order=tuple(order), names=None)
    if "names" in raw:
        ch = replace(ch, names=raw["names"])
    if "rename" in raw:
        if not isinstance(raw["rename"], dict):
            raise MappingError(f"{path}: {name}.rename: expected {{log_name: robot_name}}")
        ch = replace(ch, rename={str(k): str(v) for k, v in raw["rename"].items()})
    for key in ("scale", "offset"):
        if key in raw:
            value = raw[key]
            ch = replace(ch, **{key: tuple(_number(v, path, f"{name}.{key}") for v in value)
                                if isinstance(value, list) else _number(value, path,
                                                                        f"{name}.{key}")})
    return ch


def _number(value: Any, path: Path, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise MappingError(f"{path}: {where}: expected a finite number, got {value!r}")
    return float(value)
