"""The Rosales et al. controller: pure, no I/O. See ``law`` for the equations."""

from offboard.controller.law import (
    ControlOutput,
    LawMemory,
    LawOutput,
    RosalesController,
    TrackingReference,
    law_step,
)
from offboard.controller.params import (
    PAPER_CONTROLLER_FILE,
    ActionLimits,
    ControllerGains,
    ControllerParams,
    load_controller,
)

__all__ = [
    "PAPER_CONTROLLER_FILE",
    "ActionLimits",
    "ControlOutput",
    "ControllerGains",
    "ControllerParams",
    "LawMemory",
    "LawOutput",
    "RosalesController",
    "TrackingReference",
    "law_step",
    "load_controller",
]
