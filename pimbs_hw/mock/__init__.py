"""Simulated muscle boards: the arm model behind the real board protocol, with faults."""

from pimbs_hw.mock.arm import MockArm, MockSnapshot
from pimbs_hw.mock.effects import EffectStack, MockEffect
from pimbs_hw.mock.faults import KINDS as FAULT_KINDS
from pimbs_hw.mock.faults import FaultSpec, FaultSpecError, parse_fault, parse_faults

__all__ = ["FAULT_KINDS", "EffectStack", "FaultSpec", "FaultSpecError", "MockArm", "MockEffect",
           "MockSnapshot", "parse_fault", "parse_faults"]
