"""Controller FMU ``controller_ff``: feedforward only, the trajectory's torques replayed open loop.

Same interface as ``controller`` (:mod:`flexarm_controller_base`); the
measurements are read but do not affect the torques, and ``gain_set`` /
``schedule_period`` are checked but unused.
"""

from __future__ import annotations

from flexarm_controller_base import ControllerSlave
from flexarm_fmu_base import pin_module_namespace

pin_module_namespace(globals())  # pythonfmu 0.7.0 drops a reference per instantiation (see there)


class FlexarmControllerFF(ControllerSlave):
    """Feedforward only (``flexarm.control`` mode ``"ff"``)."""

    MODE = "ff"
    description = "Sandia two-link flexible arm: feedforward-only (open-loop) controller"
