"""A CAN board described by data: the lab's ``.dbc`` plus a short mapping (a profile file).

No code per board: the profile says which DBC message and signal carry position, tension,
temperature and faults, which messages set position or tension, how frame ids derive from
the board id, and the units. It is checked against the DBC when it is loaded, and every
mistake is a ``ProfileError`` naming the file, the line and the signal.

    profile: my-lab-board                # a name for logs and `pimbs scan`
    dbc: my_board.dbc                    # relative to this file
    nodes:                               # frame id = DBC id + (board_id + offset) * stride
      motor: {stride: 1}
      loadcell: {stride: 1, offset: 16}  # the loadcell is another node on the bus
    status:                              # signal value = SI value * per_si
      position: {node: motor, message: MOTOR_STATUS, signal: position_mm, per_si: 1000}
      tension: {node: loadcell, message: LOADCELL, signal: force_n, per_si: 1,
                rail: [-2000, 2000]}     # readings at a rail are saturated (default: DBC range)
      temperature: {node: motor, message: MOTOR_STATUS, signal: temp_c}      # optional
      counter: {node: motor, message: MOTOR_STATUS, signal: alive}           # optional
      version: {node: motor, message: VERSION, signals: [major, minor]}      # optional
      faults:                            # optional; kind: motor, encoder, overheat, ...
        - {node: motor, message: MOTOR_STATUS, signal: error, kind: motor,
           bits: {0x100: {name: OVERTEMP, kind: overheat}}}   # optional: named error bits
      state: {node: motor, message: HEARTBEAT, signal: state,  # optional: a board that must
              armed: 8, names: {1: IDLE, 8: CLOSED_LOOP}}       # be armed (setup frames) and
                                         # report `armed` before the host commands it
    commands:                            # frames per command; the string `value` is the
      length:                            # command in SI times per_si
        - {node: motor, message: MOTOR_CMD, signals: {mode: 1, target: value}, per_si: 1000}
      tension:
        - {node: motor, message: MOTOR_CMD, signals: {mode: 2, target: value}, per_si: 1}
      relax: ...                         # optional: default = tension at the relax target
      stop: ...                          # optional: default = length at the last reading
    setup: [...]                         # optional frames sent at start-up (e.g. enable)
    watchdog: {timeout_s: 0.5, action: relax}   # optional: what the board does by itself
                                         # when commands stop: relax | idle (motor off)
    winding: [position]                  # quantities a muscle's `direction: -1` negates
                                         # (default [position]; [position, tension] where
                                         # the tension is the motor's own torque)

Untrusted files never run code: the mapping is YAML data, read with the safe loader, and
placeholders are the single word ``value``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cantools
import yaml

from pimbs_hw.protocol.board import (
    BoardLimits,
    BoardProtocol,
    Capabilities,
    RawFrame,
    Update,
)
from pimbs_hw.protocol.codec import Fault

QUANTITIES = ("position", "tension", "temperature", "counter")
FAULT_KINDS = {f.name.lower(): f for f in Fault if f not in (Fault.STOPPED,
                                                              Fault.UNCONFIGURED)}
DEFAULT_PERIOD_S = 0.02


class ProfileError(ValueError):
    """A profile that does not fit its DBC; names the file, the line and the signal."""


class _Map(dict):
    """A YAML mapping that remembers the line of each key (1-based)."""

    line = 0
    lines: dict[str, int]


class _Loader(yaml.SafeLoader):
    pass


def _construct_map(loader: _Loader, node: yaml.MappingNode) -> _Map:
    mapping = _Map(loader.construct_mapping(node, deep=True))
    mapping.line = node.start_mark.line + 1
    mapping.lines = {k.value: v.start_mark.line + 1 for k, v in node.value
                     if isinstance(k, yaml.ScalarNode)}
    return mapping


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_map)


@dataclass(frozen=True)
class Node:
    name: str
    stride: int
    offset: int

    def frame_id(self, dbc_id: int, board_id: int) -> int:
        return dbc_id + (board_id + self.offset) * self.stride


@dataclass(frozen=True)
class Reading:
    """Where one status quantity lives."""

    node: str
    message: str
    signal: str
    per_si: float = 1.0
    rail: tuple[float, float] | None = None
    kind: Fault | None = None  # fault readings: the fault a nonzero value raises
    bits: tuple[tuple[int, str, Fault], ...] = ()  # fault readings: named bits, their fault


@dataclass(frozen=True)
class CommandFrame:
    """One frame of a command: constant signals, and ``value_signal`` = SI x per_si."""

    node: str
    message: str
    constants: dict[str, float]
    value_signal: str | None
    per_si: float
    kind: str | None = None  # the quantity the value is: position | tension


@dataclass
class Profile:
    """A validated profile: the DBC database and the mapping."""

    name: str
    path: Path
    db: Any  # cantools Database
    nodes: dict[str, Node]
    status: dict[str, Reading]
    faults: list[Reading]
    commands: dict[str, list[CommandFrame]]
    setup: list[CommandFrame]
    version: tuple[str, str, tuple[str, ...]] | None = None  # node, message, signals
    watchdog: tuple[float, str] | None = None  # (timeout s, "relax" | "idle")
    periods: dict[str, float] = field(default_factory=dict)  # message -> cycle time, s
    state: Reading | None = None  # the board's state machine (armed state: ``armed``)
    armed: int | None = None
    state_names: dict[int, str] = field(default_factory=dict)
    winding: tuple[str, ...] = ("position",)

    @property
    def capabilities(self) -> Capabilities:
        return Capabilities(board_watchdog=self.watchdog is not None, board_limits=False,
                            temperature="temperature" in self.status,
                            counter="counter" in self.status, checksum=False,
                            configure=False, version=self.version is not None)

    def status_period_s(self) -> float:
        """Cycle time of the position message (from the DBC's GenMsgCycleTime)."""
        return self.periods.get(self.status["position"].message, DEFAULT_PERIOD_S)

    def status_messages(self) -> dict[tuple[str, str], list[Reading]]:
        """(node, message) -> readings it carries (what a board sends)."""
        out: dict[tuple[str, str], list[Reading]] = {}
        for r in [*self.status.values(), *self.faults,
                  *([self.state] if self.state is not None else [])]:
            out.setdefault((r.node, r.message), []).append(r)
        if self.version is not None:
            out.setdefault(self.version[:2], [])
        return out

    def protocol(self, indices: Sequence[int], specs: Sequence) -> ProfileProtocol:
        return ProfileProtocol(self, indices, specs)


class _Checker:
    """Validation with errors that name file, line and what to fix."""

    def __init__(self, path: Path, db) -> None:
        self.path, self.db = path, db

    def fail(self, where: _Map | None, key: str, problem: str) -> ProfileError:
        line = (where.lines.get(key.rsplit(".", 1)[-1], where.line)
                if isinstance(where, _Map) else 0)
        return ProfileError(f"{self.path}:{line}: {key}: {problem}")

    def message(self, entry: _Map, key: str):
        name = entry.get("message")
        try:
            return self.db.get_message_by_name(name)
        except KeyError:
            known = ", ".join(m.name for m in self.db.messages)
            raise self.fail(entry, f"{key}.message", f"the DBC has no message {name!r} "
                            f"(it has: {known})") from None

    def signal(self, entry: _Map, key: str, name: Any, msg) -> str:
        if name not in {s.name for s in msg.signals}:
            known = ", ".join(s.name for s in msg.signals)
            raise self.fail(entry, f"{key}.signal", f"message {msg.name} has no signal "
                            f"{name!r} (it has: {known})")
        return name

    def node(self, entry: _Map, key: str, nodes: dict[str, Node]) -> str:
        name = entry.get("node")
        if name not in nodes:
            raise self.fail(entry, f"{key}.node", f"unknown node {name!r}; declare it under "
                            f"nodes: ({', '.join(nodes) or 'none declared'})")
        return name

    def number(self, entry: _Map, key: str, name: str, default: float | None = None,
               positive: bool = False) -> float:
        value = entry.get(name, default)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(
                value) or (positive and value == 0):
            raise self.fail(entry, f"{key}.{name}", f"expected a {'nonzero ' if positive else ''}"
                            f"finite number, got {value!r}")
        return float(value)


def _load_yaml(path: Path) -> _Map:
    try:
        text = path.read_text()
    except OSError as exc:
        raise ProfileError(f"{path}: cannot read the profile ({exc.strerror}); check the "
                           f"`protocol:` path in the robot description") from exc
    try:
        raw = yaml.load(text, Loader=_Loader)  # noqa: S506 - SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise ProfileError(f"{path}:{mark.line + 1 if mark else 0}: not valid YAML: "
                           f"{getattr(exc, 'problem', exc)}") from exc
    if not isinstance(raw, _Map):
        raise ProfileError(f"{path}:1: expected a mapping with profile, dbc, nodes, status, "
                           "commands")
    return raw


def _load_dbc(path: Path, raw: _Map):
    if not isinstance(raw.get("dbc"), str):
        raise ProfileError(f"{path}:{raw.line}: dbc: name the board's .dbc file "
                           "(relative to this profile)")
    dbc = path.parent / raw["dbc"]
    try:
        return cantools.database.load_file(str(dbc), database_format="dbc", strict=True)
    except (OSError, cantools.database.UnsupportedDatabaseFormatError, ValueError) as exc:
        raise ProfileError(f"{path}:{raw.lines.get('dbc', raw.line)}: dbc: cannot load "
                           f"{dbc}: {' '.join(str(exc).split())}") from exc


def load_profile(path: str | Path) -> Profile:
    """Read and validate a ``*.profile.yaml`` and its DBC."""
    path = Path(path)
    raw = _load_yaml(path)
    db = _load_dbc(path, raw)
    check = _Checker(path, db)
    nodes_raw = raw.get("nodes")
    if not isinstance(nodes_raw, _Map) or not nodes_raw:
        raise check.fail(raw, "nodes", "declare the board's nodes, e.g. "
                         "`nodes: {motor: {stride: 1}}`")
    nodes = {}
    for name, entry in nodes_raw.items():
        if not isinstance(entry, _Map):
            raise check.fail(nodes_raw, f"nodes.{name}", "expected {stride: N, offset: K}")
        stride, offset = entry.get("stride", 1), entry.get("offset", 0)
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in (stride, offset)):
            raise check.fail(entry, f"nodes.{name}.stride", "stride and offset must be "
                             "integers (frame id = DBC id + (board_id + offset) * stride)")
        nodes[name] = Node(name, stride, offset)
    status_raw = raw.get("status")
    if not isinstance(status_raw, _Map):
        raise check.fail(raw, "status", "say where position and tension are read")
    status: dict[str, Reading] = {}
    for quantity in QUANTITIES:
        entry = status_raw.get(quantity)
        if entry is None:
            if quantity in ("position", "tension"):
                raise check.fail(status_raw, f"status.{quantity}", "required: "
                                 "{node, message, signal, per_si}")
            continue
        status[quantity] = _reading(check, entry, status_raw, f"status.{quantity}", nodes)
    faults = []
    for k, entry in enumerate(status_raw.get("faults") or []):
        key = f"status.faults[{k}]"
        reading = _reading(check, entry, status_raw, key, nodes)
        kind = entry.get("kind")
        if kind not in FAULT_KINDS:
            raise check.fail(entry, f"{key}.kind", f"unknown fault kind {kind!r}; use one of "
                             f"{', '.join(FAULT_KINDS)}")
        faults.append(Reading(reading.node, reading.message, reading.signal,
                              kind=FAULT_KINDS[kind],
                              bits=_bits(check, entry, key, FAULT_KINDS[kind])))
    version = None
    if (entry := status_raw.get("version")) is not None:
        node = check.node(entry, "status.version", nodes)
        msg = check.message(entry, "status.version")
        names = entry.get("signals")
        if not isinstance(names, list) or not names:
            raise check.fail(entry, "status.version.signals", "list the version's signals")
        version = (node, msg.name, tuple(check.signal(entry, "status.version", n, msg)
                                         for n in names))
    commands_raw = raw.get("commands")
    if not isinstance(commands_raw, _Map):
        raise check.fail(raw, "commands", "say which frames set length and tension")
    commands = {}
    for kind in ("length", "tension", "relax", "stop"):
        frames = commands_raw.get(kind)
        if frames is None:
            if kind in ("length", "tension"):
                raise check.fail(commands_raw, f"commands.{kind}", "required: a list of frames")
            continue
        commands[kind] = _frames(check, frames, commands_raw, f"commands.{kind}", nodes,
                                 needs_value=kind in ("length", "tension"),
                                 quantity="tension" if kind in ("tension", "relax")
                                 else "position")
    setup = _frames(check, raw.get("setup") or [], raw, "setup", nodes,
                    needs_value=False)
    name = raw.get("profile") or path.name.removesuffix(".profile.yaml")
    periods = {m.name: m.cycle_time / 1000.0 for m in db.messages if m.cycle_time}
    watchdog = None
    if (entry := raw.get("watchdog")) is not None:
        if not isinstance(entry, _Map) or entry.get("action") not in ("relax", "idle"):
            raise check.fail(entry if isinstance(entry, _Map) else raw, "watchdog.action",
                             "say what the board does when commands stop: relax or idle")
        watchdog = (check.number(entry, "watchdog", "timeout_s", positive=True),
                    entry["action"])
    state, armed, names = _state(check, status_raw, nodes)
    winding = raw.get("winding", ["position"])
    if not (isinstance(winding, list) and set(winding) <= {"position", "tension"}):
        raise check.fail(raw, "winding", "list the quantities a muscle's direction negates: "
                         "[position] or [position, tension]")
    return Profile(str(name), path, db, nodes, status, faults, commands, setup, version,
                   watchdog, periods, state, armed, names, tuple(winding))


def _bits(check: _Checker, entry: _Map, key: str, default: Fault
          ) -> tuple[tuple[int, str, Fault], ...]:
    raw = entry.get("bits")
    if raw is None:
        return ()
    if not isinstance(raw, _Map):
        raise check.fail(entry, f"{key}.bits", "expected {bit value: {name: NAME, kind: K}}")
    out = []
    for bit, spec in raw.items():
        kind = spec.get("kind") if isinstance(spec, _Map) else None
        if not (isinstance(bit, int) and isinstance(spec, _Map) and isinstance(
                spec.get("name"), str) and (kind is None or kind in FAULT_KINDS)):
            raise check.fail(raw, f"{key}.bits", f"{bit!r}: expected {{name: NAME, kind: one "
                             f"of {', '.join(FAULT_KINDS)}}}")
        out.append((bit, spec["name"], FAULT_KINDS[kind] if kind else default))
    return tuple(out)


def _state(check: _Checker, raw: _Map, nodes: dict[str, Node]
           ) -> tuple[Reading | None, int | None, dict[int, str]]:
    entry = raw.get("state")
    if entry is None:
        return None, None, {}
    if not isinstance(entry, _Map):
        raise check.fail(raw, "status.state", "expected {node, message, signal, armed, names}")
    node = check.node(entry, "status.state", nodes)
    msg = check.message(entry, "status.state")
    signal = check.signal(entry, "status.state", entry.get("signal"), msg)
    armed = entry.get("armed")
    names = entry.get("names") or {}
    if not isinstance(armed, int) or not isinstance(names, dict) or not all(
            isinstance(k, int) and isinstance(v, str) for k, v in names.items()):
        raise check.fail(entry, "status.state.armed", "give the state value the board must report "
                         "before it is commanded (armed: N) and names: {N: NAME}")
    return Reading(node, msg.name, signal), armed, dict(names)


def _reading(check: _Checker, entry: Any, parent: _Map, key: str, nodes: dict[str, Node]
             ) -> Reading:
    if not isinstance(entry, _Map):
        raise check.fail(parent, key, "expected {node, message, signal}")
    node = check.node(entry, key, nodes)
    msg = check.message(entry, key)
    signal = check.signal(entry, key, entry.get("signal"), msg)
    per_si = check.number(entry, key, "per_si", 1.0, positive=True)
    rail = entry.get("rail")
    if rail is not None:
        if not (isinstance(rail, list) and len(rail) == 2
                and all(isinstance(v, int | float) for v in rail)):
            raise check.fail(entry, f"{key}.rail", "expected [low, high] in signal units")
        rail = (float(rail[0]), float(rail[1]))
    else:
        sig = msg.get_signal_by_name(signal)
        if sig.minimum is not None and sig.maximum is not None and sig.minimum < sig.maximum:
            rail = (float(sig.minimum), float(sig.maximum))
    return Reading(node, msg.name, signal, per_si, rail)


def _frames(check: _Checker, entries: Any, parent: _Map, key: str,
            nodes: dict[str, Node], *, needs_value: bool,
            quantity: str | None = None) -> list[CommandFrame]:
    if not isinstance(entries, list):
        raise check.fail(parent, key, "expected a list of frames")
    frames, has_value = [], False
    for k, entry in enumerate(entries):
        sub = f"{key}[{k}]"
        if not isinstance(entry, _Map):
            raise check.fail(parent, key, f"[{k}] expected {{node, message, signals}}")
        node = check.node(entry, sub, nodes)
        msg = check.message(entry, sub)
        signals = entry.get("signals") or {}
        if not isinstance(signals, _Map):
            raise check.fail(entry, f"{sub}.signals", "expected {signal: number or value}")
        constants, value_signal = {}, None
        for name, v in signals.items():
            check.signal(signals, f"{sub}.signals.{name}", name, msg)
            if v == "value":
                value_signal = name
            elif isinstance(v, int | float) and not isinstance(v, bool):
                constants[name] = float(v)
            else:
                raise check.fail(signals, f"{sub}.signals.{name}", f"{v!r} is neither a "
                                 "number nor the placeholder `value`")
        missing = {s.name for s in msg.signals} - set(signals)
        if missing:
            raise check.fail(entry, f"{sub}.signals", f"message {msg.name} also needs "
                             f"{', '.join(sorted(missing))} (give each a number)")
        has_value |= value_signal is not None
        frames.append(CommandFrame(node, msg.name, constants, value_signal,
                                   check.number(entry, sub, "per_si", 1.0, positive=True),
                                   quantity))
    if needs_value and not has_value:
        raise check.fail(parent, key, "no frame carries the command: set one signal to "
                         "`value`")
    return frames


class ProfileProtocol(BoardProtocol):
    """``BoardProtocol`` for the muscles ``indices`` whose boards a ``Profile`` describes."""

    def __init__(self, profile: Profile, indices: Sequence[int], specs: Sequence) -> None:
        super().__init__(indices, [s.board_id for s in specs])
        self.profile = profile
        self.name = profile.name
        self.capabilities = profile.capabilities
        self.status_period_s = profile.status_period_s()
        self.muscle_names = {i: s.name for i, s in zip(indices, specs, strict=True)}
        # a muscle wound the other way round negates what the motor shaft measures
        self.sign = {i: float(getattr(s, "direction", 1)) for i, s in zip(indices, specs,
                                                                          strict=True)}
        self._board = dict(zip(indices, self.board_ids, strict=True))
        self._relax = dict.fromkeys(indices, 0.0)
        self._last_position = dict.fromkeys(indices, math.nan)
        self._rx: dict[int, tuple[Any, int, list[Reading]]] = {}  # frame id -> msg, muscle
        self._version_id: dict[int, int] = {}
        for (node, message), readings in profile.status_messages().items():
            msg = profile.db.get_message_by_name(message)
            for i in indices:
                fid = profile.nodes[node].frame_id(msg.frame_id, self._board[i])
                if fid in self._rx and self._rx[fid][1] != i:
                    raise ProfileError(
                        f"{profile.path}: nodes: frame id 0x{fid:X} of {message} is shared by "
                        f"muscles {self.muscle_names[self._rx[fid][1]]} and "
                        f"{self.muscle_names[i]}: their board ids collide under this stride")
                self._rx[fid] = (msg, i, readings)

    def frame_ids(self, i: int) -> list[int]:
        """Every status frame id of muscle ``i`` (``pimbs scan`` listens for these)."""
        return [fid for fid, (_, j, _) in self._rx.items() if j == i]

    def _sign(self, i: int, quantity: str | None) -> float:
        return self.sign[i] if quantity in self.profile.winding else 1.0

    def ids_used(self, i: int) -> set[int]:
        """Every CAN id muscle ``i``'s board owns. A node addressed by blocks (ODrive:
        node_id << 5 | cmd_id) owns its whole block, used or not by PIMBS; otherwise the ids
        of every message of the DBC."""
        p, out = self.profile, set()
        top = max(m.frame_id for m in p.db.messages)
        for node in p.nodes.values():
            if node.stride > top:
                base = node.frame_id(0, self._board[i])
                out.update(range(base, base + node.stride))
            else:
                out.update(node.frame_id(m.frame_id, self._board[i]) for m in p.db.messages)
        return out

    def armed(self, state: int | None) -> bool:
        return self.profile.state is None or state == self.profile.armed

    @property
    def has_state(self) -> bool:
        return self.profile.state is not None

    def state_text(self, state: int | None, error: int | None) -> str:
        p = self.profile
        if p.state is None:
            return ""
        if state is None:
            return f"no {p.state.signal} reported yet"
        text = f"{p.state.signal} {p.state_names.get(state, '?')} ({state})"
        for r in p.faults:
            if r.bits and error is not None:
                names = [n for bit, n, _ in r.bits if error & bit]
                text += f", {r.signal} 0x{error:08X}" + (f" {'|'.join(names)}" if names else "")
        return text

    def _encode(self, i: int, frame: CommandFrame, si_value: float) -> RawFrame:
        p = self.profile
        msg = p.db.get_message_by_name(frame.message)
        signals = dict(frame.constants)
        if frame.value_signal is not None:
            signals[frame.value_signal] = si_value * frame.per_si * self._sign(i, frame.kind)
        try:
            data = msg.encode(signals, strict=True)
        except (cantools.database.EncodeError, ValueError, KeyError) as exc:
            raise ValueError(f"muscle {self.muscle_names[i]}: {frame.message}: cannot encode "
                             f"{signals}: {exc}") from exc
        return p.nodes[frame.node].frame_id(msg.frame_id, self._board[i]), data

    def setup(self, i: int, limits: BoardLimits) -> list[RawFrame]:
        self._relax[i] = limits.relax_tension_n  # the board knows no relax: the host does
        return [self._encode(i, f, 0.0) for f in self.profile.setup]

    def configured(self, faults: Fault) -> bool:
        return True

    def command(self, i: int, kind: str, value: float = 0.0) -> list[RawFrame]:
        commands = self.profile.commands
        if kind == "relax" and "relax" not in commands:
            kind, value = "tension", self._relax[i]
        elif kind == "stop" and "stop" not in commands:
            if not math.isfinite(self._last_position[i]):
                kind, value = "tension", self._relax[i]  # nothing read yet: relax instead
            else:
                kind, value = "length", self._last_position[i]
        return [self._encode(i, f, value) for f in commands[kind]]

    def decode(self, arbitration_id: int, data: bytes) -> list[Update]:
        entry = self._rx.get(arbitration_id)
        if entry is None:
            return []
        msg, i, readings = entry
        try:
            values = msg.decode(data, decode_choices=False, scaling=True)
        except Exception:  # noqa: BLE001 - wrong length etc.: CAN's CRC passed, so the
            return []      # sender is another device using this id; not ours to judge
        fields: dict[str, Any] = {}
        faults = Fault(0)
        saturated = False
        state = error = None
        for r in readings:
            v = float(values[r.signal])
            if r is self.profile.state:
                state = int(v)
                continue
            if r.kind is not None:
                if v:  # each named bit raises its own fault; any other bit the reading's
                    code = int(v)
                    known = 0
                    for bit, _, kind in r.bits:
                        known |= bit
                        if code & bit:
                            faults |= kind
                    if code & ~known:
                        faults |= r.kind
                if r.bits:
                    error = int(v)
                continue
            if r.rail is not None and r is self.profile.status.get("tension") and not (
                    r.rail[0] < v < r.rail[1]):
                saturated = True
            quantity = next(q for q, s in self.profile.status.items() if s is r)
            fields[quantity] = v / r.per_si * self._sign(i, quantity)
        if any(r.kind is not None for r in readings):
            fields["faults"] = faults
        version = None
        if self.profile.version and msg.name == self.profile.version[1]:
            version = ".".join(str(int(values[s])) for s in self.profile.version[2])
        if "position" in fields:
            self._last_position[i] = fields["position"]
        return [Update(i, position_m=fields.get("position"), tension_n=fields.get("tension"),
                       temperature_c=fields.get("temperature"), faults=fields.get("faults"),
                       counter=(int(fields["counter"]) & 0xF if "counter" in fields else None),
                       saturated=saturated, version=version, state=state, error_code=error)]

    def describe(self) -> str:
        return f"profile {self.name}"

    def unreachable(self, watchdog_s: float) -> str:
        dog = self.profile.watchdog
        if dog is None:
            return (f"{self.name} boards: holding their last command (they have no watchdog; "
                    "cut their power to relax the arm)")
        if dog[1] == "idle":
            return (f"{self.name} boards: motors idled by their own watchdog within {dog[0]:g} s"
                    " (wires slack)")
        return f"{self.name} boards: relaxed by their own watchdog within {dog[0]:g} s"
