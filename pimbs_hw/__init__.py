"""PIMBS hardware layer: board protocol, transports, arm driver, safety, simulated arm.

Entry point for collection code: ``open_arm`` (see ``pimbs_hw.connect``).
"""

from pimbs_hw.connect import is_simulated, open_arm
from pimbs_hw.driver import ArmDriver, ArmState
from pimbs_hw.errors import HardwareError, PortError
from pimbs_hw.safety import SafetyLimits, SafetyStop

__all__ = ["ArmDriver", "ArmState", "HardwareError", "PortError", "SafetyLimits", "SafetyStop",
           "is_simulated", "open_arm"]
