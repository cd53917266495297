"""Fault injection for the simulated boards: ``--fault KIND[:MUSCLE][@TRIGGER]``.

KIND      silent-board, drop-frames, corrupt-frames, overheat, saturate-loadcell, bus-off,
          drive-fault (the motor driver faults and stays faulted: an ODrive axis disarms to
          IDLE with DRV_FAULT and cannot be re-armed; a PIMBS board reports a motor fault; a
          CiA 402 drive enters Fault), lost-heartbeat (CiA 402 drives: the heartbeat stops),
          lost-sync (CiA 402 drives: SYNC no longer reaches the drive)
MUSCLE    muscle name (``m2``); omit or ``*`` for bus-wide kinds (bus-off) or every muscle
TRIGGER   ``12``  sample index of the collection (``MockArm.set_sample``)
          ``2.5s`` seconds after the mock started
          ``300c`` board cycles (mock ticks) after start
          omitted: active from the start
A fault, once triggered, stays active: a real board that went silent does not come back.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

KINDS = ("silent-board", "drop-frames", "corrupt-frames", "overheat", "saturate-loadcell",
         "bus-off", "drive-fault", "lost-heartbeat", "lost-sync")
_SPEC = re.compile(r"^(?P<kind>[a-z-]+)(?::(?P<muscle>[^@]+))?(?:@(?P<trigger>[0-9.]+[sc]?))?$")


class FaultSpecError(ValueError):
    """A ``--fault`` spec that cannot be understood."""


@dataclass(frozen=True)
class FaultSpec:
    kind: str
    muscle: str | None  # None: every muscle / the bus
    sample: int | None = None
    seconds: float | None = None
    cycles: int | None = None

    def active(self, sample: int, seconds: float, cycles: int) -> bool:
        """Whether the trigger has been reached (all unset: from the start)."""
        return ((self.sample is None or sample >= self.sample)
                and (self.seconds is None or seconds >= self.seconds)
                and (self.cycles is None or cycles >= self.cycles))

    def hits(self, muscle: str) -> bool:
        return self.muscle is None or self.muscle == muscle


def parse_fault(spec: str, muscles: tuple[str, ...] | None = None) -> FaultSpec:
    """Parse one ``--fault`` value; ``muscles`` (if given) validates the muscle name."""
    match = _SPEC.match(spec.strip())
    form = "KIND[:MUSCLE][@SAMPLE | @SECONDSs | @CYCLESc], e.g. overheat:m2@10"
    if match is None:
        raise FaultSpecError(f"cannot parse fault '{spec}'; the form is {form}")
    kind, muscle, trigger = match["kind"], match["muscle"], match["trigger"]
    if kind not in KINDS:
        raise FaultSpecError(f"unknown fault kind '{kind}' in '{spec}'; choose one of "
                             f"{', '.join(KINDS)}")
    if muscle in (None, "*", "all"):
        muscle = None
    elif muscles is not None and muscle not in muscles:
        raise FaultSpecError(f"unknown muscle '{muscle}' in '{spec}'; this robot has "
                             f"{', '.join(muscles)}")
    if trigger is None:
        return FaultSpec(kind, muscle)
    try:
        if trigger.endswith("s"):
            return FaultSpec(kind, muscle, seconds=float(trigger[:-1]))
        if trigger.endswith("c"):
            return FaultSpec(kind, muscle, cycles=int(trigger[:-1]))
        return FaultSpec(kind, muscle, sample=int(trigger))
    except ValueError:
        raise FaultSpecError(f"bad trigger '@{trigger}' in '{spec}'; the form is {form}") from None


def parse_faults(specs: list[str] | tuple[str, ...] | str | None,
                 muscles: tuple[str, ...] | None = None) -> tuple[FaultSpec, ...]:
    """Parse several specs (a list, or one comma-separated string)."""
    if specs is None:
        return ()
    if isinstance(specs, str):
        specs = [s for s in specs.split(",") if s.strip()]
    return tuple(s if isinstance(s, FaultSpec) else parse_fault(s, muscles) for s in specs)
