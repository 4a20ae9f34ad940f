"""Input signals, flight-test manoeuvres and the autopilot hold.

Signals are small composable objects evaluated by step index (not by
``simulation/sim-time-sec``, which ``run_ic()`` does not reset).
"""

from maneuvers.signals import Constant, Sampled, Signal, Step, Sum, multistep
from maneuvers.library import Doublet2311, GearTransition, Maneuver, MANEUVERS, Recorded, make_maneuver
from maneuvers.autopilot import HoldAutopilot, HoldGains

__all__ = [
    "Constant",
    "Sampled",
    "Signal",
    "Step",
    "Sum",
    "multistep",
    "Doublet2311",
    "GearTransition",
    "Maneuver",
    "MANEUVERS",
    "Recorded",
    "make_maneuver",
    "HoldAutopilot",
    "HoldGains",
]
