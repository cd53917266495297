"""The ``temperature`` column for boards that report none (a CiA 402 drive whose EDS has no
temperature object): the recording format needs finite values, so those muscles get a
fixed fill, and the metadata says which muscles and what the value is (as ``pimbs import``
does for a log without temperatures). Nothing else is invented: a board that reports a
temperature is recorded as reported.
"""

from __future__ import annotations

import numpy as np

TEMPERATURE_FILL_C = 25.0


def unreported(robot) -> list[str]:
    """Muscles whose board protocol reports no temperature."""
    from pimbs_hw.protocol.profiles import protocols_for

    return [robot.muscles[i].name for p in protocols_for(robot)
            if not p.capabilities.temperature for i in p.indices]


def temperature_note(robot) -> str:
    """The recording's ``temperature`` metadata: where the column's values come from."""
    missing = unreported(robot)
    if not missing:
        return "from the boards"
    return (f"not reported by the boards of {', '.join(missing)}: every value there is "
            f"{TEMPERATURE_FILL_C:g} (a fill), so thermal effects cannot be diagnosed for them")


def filled(temperature: np.ndarray) -> np.ndarray:
    """The reading with the fill where a board reported no temperature (NaN)."""
    return np.where(np.isfinite(temperature), temperature, TEMPERATURE_FILL_C)


def hottest(value: float) -> str:
    """The summary's hottest temperature, or that no board reported one."""
    return f"{value:.1f} °C" if np.isfinite(value) else "not reported"
