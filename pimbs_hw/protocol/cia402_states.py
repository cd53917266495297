"""The CiA 402 power drive state machine as the host reads and drives it.

Statusword (0x6041) bit patterns and controlword (0x6040) commands as CiA 402-2 (IEC
61800-7-201) defines them; the host only ever reads a state from the statusword the drive
sent, never assumes one. Used by the host protocol (``cia402.py``) and ``pimbs scan``.
"""

from __future__ import annotations

# (mask, value, name): the first row whose masked bits match names the state
STATES = (
    (0x4F, 0x00, "Not ready to switch on"),
    (0x4F, 0x40, "Switch on disabled"),
    (0x6F, 0x21, "Ready to switch on"),
    (0x6F, 0x23, "Switched on"),
    (0x6F, 0x27, "Operation enabled"),
    (0x6F, 0x07, "Quick stop active"),
    (0x4F, 0x0F, "Fault reaction active"),
    (0x4F, 0x08, "Fault"),
)
OPERATION_ENABLED = "Operation enabled"
FAULT_STATES = ("Fault", "Fault reaction active")
# controlword commands (bits 0-3 and 7)
SHUTDOWN = 0x06  # -> Ready to switch on
SWITCH_ON = 0x07  # -> Switched on
ENABLE_OPERATION = 0x0F  # -> Operation enabled
QUICK_STOP = 0x02  # -> Quick stop active (from Operation enabled)
DISABLE_VOLTAGE = 0x00  # -> Switch on disabled
FAULT_RESET = 0x80  # rising edge of bit 7: Fault -> Switch on disabled
# modes of operation (0x6060 / 0x6061) and their bits in Supported drive modes (0x6502)
MODES = {1: "profile position", 4: "profile torque", 8: "cyclic synchronous position",
         9: "cyclic synchronous velocity", 10: "cyclic synchronous torque"}
MODE_BIT = {1: 0, 4: 3, 8: 7, 9: 8, 10: 9}
CYCLIC = frozenset({8, 9, 10})  # the cyclic synchronous modes: they run on the bus's SYNC
# error register (0x1001) bits (CiA 301)
ERROR_REGISTER = ("generic", "current", "voltage", "temperature", "communication",
                  "device profile", "reserved", "manufacturer")


def state_name(statusword: int) -> str:
    """The CiA 402 state a statusword reports."""
    for mask, value, name in STATES:
        if statusword & mask == value:
            return name
    return f"unknown (statusword 0x{statusword:04X})"


def error_bits(register: int) -> str:
    """Plain names of the error register bits that are set."""
    names = [n for k, n in enumerate(ERROR_REGISTER) if register >> k & 1]
    return ", ".join(names) if names else "none"


def pick_mode(supported: int, wanted: tuple[int, ...]) -> int | None:
    """The first of ``wanted`` (mode numbers) that 0x6502 says the drive supports."""
    return next((m for m in wanted if supported >> MODE_BIT[m] & 1), None)
