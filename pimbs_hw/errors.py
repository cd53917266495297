"""Exception roots of the hardware layer (safety stops live in ``pimbs_hw.safety``)."""

from __future__ import annotations


class HardwareError(RuntimeError):
    """Anything the hardware layer reports; callers may catch this one type."""


class PortError(HardwareError):
    """A port could not be opened; the message names the port and what to do about it."""

    def __init__(self, port: str, message: str, problem: str | None = None) -> None:
        self.port = port
        self.problem = problem or message  # what went wrong, without advice (for re-wording)
        super().__init__(message)
