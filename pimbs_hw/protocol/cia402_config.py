"""A CiA 402 drive file (``*.cia402.yaml``): which EDS, and which objects carry what.

A muscle whose ``protocol`` names such a file is driven by a CANopen servo drive with the
CiA 402 profile, node id = the muscle's ``board_id``. The file is data, read with YAML's
safe loader, checked against the drive's own EDS (parsed by the ``canopen`` package) when
it is loaded; every mistake is a ``DriveFileError`` naming the file, the EDS, the object
(index:subindex) and what is missing.

    eds: my-drive.eds                  # the maker's EDS, relative to this file
    host_node_id: 127                  # the host's heartbeat producer id (not a drive's id)
    heartbeat_ms: 50                   # the drives' heartbeat producer time (0x1017)
    status_period_ms: 10               # how often the drives report (TPDOs)
    sync_period_us: 1000               # SYNC period for cyclic synchronous modes (0x1006)
    objects:                           # object = "0xINDEX:SUB"; value = SI x per_si
      tension:  {actual: "0x6077:0", target: "0x6071:0", per_si: 10}   # e.g. per mille / N
      position: {actual: "0x6064:0", target: "0x607A:0", per_si: 1e5}  # counts per metre
      temperature: {actual: "0x2200:1", per_si: 1}                     # optional

Drives that run a cyclic synchronous mode (CSP/CST, chosen from 0x6502) get SYNC every
``sync_period_us`` (1 ms, the cycle industrial drives expect; written to 0x1006 and 0x60C2),
targets in synchronous RPDOs (taken at the next SYNC) and TPDOs every
``status_period_ms / sync_period_us``-th SYNC; other drives get event-driven PDOs (event
timer ``status_period_ms``). A status period that is no whole number of SYNC periods, or more
than 240 of them (CiA 301's largest cyclic transmission type), is refused.

Tension is the drive's torque through the pulley (a loadcell on the drive's analogue input
is named the same way, by its object). ``position.target`` may be omitted for a drive that
has no 0x607A: length control is then refused with a message naming the EDS.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import canopen
import yaml

# the CiA 402 objects every drive needs (index: what the host uses it for)
REQUIRED = {0x6040: "Controlword", 0x6041: "Statusword", 0x6060: "Modes of operation",
            0x6061: "Modes of operation display"}
COMMS = {0x1001: "Error register", 0x1017: "Producer heartbeat time",
         0x1018: "Identity object"}
SYNC_PERIOD_US = 1000  # 1 kHz: the cycle most drives expect in cyclic synchronous modes
MAX_SYNC_EVERY = 240  # CiA 301: TPDO transmission types 1..240 = every n-th SYNC
_OBJECT = re.compile(r"^0x([0-9A-Fa-f]{4}):(?:0x)?([0-9A-Fa-f]{1,2})$")
_COMMENTS = re.compile(r"(?ims)^\[Comments\][^\[]*")


class DriveFileError(ValueError):
    """A drive file or EDS that cannot drive a muscle; one line, naming what and where."""


@dataclass(frozen=True)
class ObjectRef:
    index: int
    subindex: int
    per_si: float = 1.0

    @property
    def key(self) -> tuple[int, int]:
        return self.index, self.subindex

    def __str__(self) -> str:
        return f"0x{self.index:04X}:{self.subindex:02X}"


@dataclass(frozen=True)
class DriveFile:
    path: Path
    eds: Path
    host_node_id: int
    heartbeat_ms: int
    status_period_ms: int
    sync_period_us: int
    tension_actual: ObjectRef
    tension_target: ObjectRef
    position_actual: ObjectRef
    position_target: ObjectRef | None
    temperature: ObjectRef | None

    @property
    def name(self) -> str:
        return f"cia402 ({self.eds.name})"

    @property
    def sync_every(self) -> int:
        """SYNCs per status period: the cyclic TPDO transmission type under SYNC."""
        return self.status_period_ms * 1000 // self.sync_period_us

    def object_dictionary(self, node_id: int) -> canopen.ObjectDictionary:
        """The drive's object dictionary for ``node_id`` (``$NODEID`` resolved)."""
        return read_eds(self.eds, node_id)


def read_eds(eds: Path, node_id: int) -> canopen.ObjectDictionary:
    """Parse ``eds`` with canopen; a broken file is one ``DriveFileError`` line.

    The ``[Comments]`` section is dropped first: it is free text, and canopen requires its
    keys to be spelt ``Line1..`` exactly (CiA 306) while some makers write ``Lines1..``.
    """
    try:
        text = eds.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise DriveFileError(f"{eds}: cannot read the EDS ({exc.strerror}); give the path of "
                             "your drive's EDS file") from None
    source = io.StringIO(_COMMENTS.sub("", text))
    source.name = str(eds) if eds.suffix.lower() in (".eds", ".dcf") else f"{eds}.eds"
    try:
        return canopen.import_od(source, node_id)
    except Exception as exc:  # noqa: BLE001 - configparser/canopen raise many kinds
        said = " ".join(str(exc).split())
        raise DriveFileError(f"{eds}: not a readable EDS ({type(exc).__name__}: {said})") \
            from None


def find_object(od: canopen.ObjectDictionary, ref: ObjectRef):
    """The EDS entry of ``ref``, or None."""
    if ref.index not in od:
        return None
    obj = od[ref.index]
    if isinstance(obj, canopen.objectdictionary.ODVariable):
        return obj if ref.subindex == 0 else None
    return obj[ref.subindex] if ref.subindex in obj else None


def _ref(path: Path, where: str, text: Any, per_si: Any = 1.0) -> ObjectRef:
    match = _OBJECT.match(str(text).strip())
    if match is None:
        raise DriveFileError(f"{path}: {where}: {text!r} is not an object; write it as "
                             "\"0xINDEX:SUB\", e.g. \"0x6077:0\"")
    try:
        scale = float(per_si)
    except (TypeError, ValueError):
        scale = float("nan")
    if not scale or scale != scale:
        raise DriveFileError(f"{path}: {where}: per_si must be a nonzero number, "
                             f"got {per_si!r}")
    return ObjectRef(int(match.group(1), 16), int(match.group(2), 16), scale)


def _check(path: Path, eds: Path, od, ref: ObjectRef, what: str, *, write: bool) -> None:
    entry = find_object(od, ref)
    if entry is None:
        raise DriveFileError(f"{path}: EDS {eds.name} has no object {ref} ({what}); pick the "
                             "object your drive uses for it from its EDS")
    if not entry.pdo_mappable:
        raise DriveFileError(f"{path}: EDS {eds.name}: object {ref} ({what}, {entry.name}) "
                             "cannot be mapped into a PDO (PDOMapping=0)")
    if write and not entry.writable:
        raise DriveFileError(f"{path}: EDS {eds.name}: object {ref} ({what}, {entry.name}) is "
                             f"not writable (AccessType={entry.access_type})")


def load_drive_file(path: str | Path) -> DriveFile:
    """Read and check a ``*.cia402.yaml`` against its EDS (see the module docstring)."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise DriveFileError(f"{path}: cannot read the drive file ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f" line {mark.line + 1}" if mark is not None else ""
        raise DriveFileError(f"{path}:{line} is not valid YAML "
                             f"({getattr(exc, 'problem', exc)})") from None
    if not isinstance(data, dict) or "eds" not in data or "objects" not in data:
        raise DriveFileError(f"{path}: a drive file needs `eds:` (the drive's EDS file) and "
                             "`objects:` (tension, position, optional temperature)")
    eds = (path.parent / str(data["eds"])).resolve()
    od = read_eds(eds, 1)
    for index, name in {**REQUIRED, **COMMS}.items():
        if index not in od:
            raise DriveFileError(f"{path}: EDS {eds.name} has no object 0x{index:04X}:00 "
                                 f"({name}); a CiA 402 drive over CANopen needs it")
    objects = data["objects"] or {}
    for key in ("tension", "position"):
        if not isinstance(objects.get(key), dict) or "actual" not in objects[key]:
            raise DriveFileError(f"{path}: objects.{key} needs `actual:` (the object the "
                                 f"drive reports the {key} in)")
    tension, position = objects["tension"], objects["position"]
    if "target" not in tension:
        raise DriveFileError(f"{path}: objects.tension needs `target:` (e.g. \"0x6071:0\", "
                             "Target torque)")
    refs = {
        "tension_actual": _ref(path, "objects.tension.actual", tension["actual"],
                               tension.get("per_si", 1.0)),
        "tension_target": _ref(path, "objects.tension.target", tension["target"],
                               tension.get("per_si", 1.0)),
        "position_actual": _ref(path, "objects.position.actual", position["actual"],
                                position.get("per_si", 1.0)),
        "position_target": (_ref(path, "objects.position.target", position["target"],
                                 position.get("per_si", 1.0)) if "target" in position else None),
        "temperature": (_ref(path, "objects.temperature.actual",
                             objects["temperature"].get("actual"),
                             objects["temperature"].get("per_si", 1.0))
                        if isinstance(objects.get("temperature"), dict) else None),
    }
    for key, ref in refs.items():
        if ref is not None:
            _check(path, eds, od, ref, key.replace("_", " "), write=key.endswith("target"))
    host = int(data.get("host_node_id", 127))
    if not 1 <= host <= 127:
        raise DriveFileError(f"{path}: host_node_id must be 1..127, got {host}")
    status_ms = _whole(path, data, "status_period_ms", 10, 1, 60_000)
    sync_us = _whole(path, data, "sync_period_us", SYNC_PERIOD_US, 100, 1_000_000)
    every, left = divmod(status_ms * 1000, sync_us)
    if left or not 1 <= every <= MAX_SYNC_EVERY:
        raise DriveFileError(f"{path}: status_period_ms {status_ms} must be 1 to "
                             f"{MAX_SYNC_EVERY} whole SYNC periods (sync_period_us {sync_us}): "
                             "a TPDO goes out every n-th SYNC; e.g. 10 ms with 1000 us")
    return DriveFile(path, eds, host, int(data.get("heartbeat_ms", 50)), status_ms, sync_us,
                     **refs)


def _whole(path: Path, data: dict, key: str, default: int, lo: int, hi: int) -> int:
    value = data.get(key, default)
    if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
        raise DriveFileError(f"{path}: {key} must be a whole number from {lo} to {hi}, "
                             f"got {value!r}")
    return value
