"""Controller FMU ``controller_fb``: scheduled LQR feedback about the trajectory, no feedforward.

Same interface as ``controller`` (:mod:`flexarm_controller_base`).
"""

from __future__ import annotations

from flexarm_controller_base import ControllerSlave
from flexarm_fmu_base import pin_module_namespace

pin_module_namespace(globals())  # pythonfmu 0.7.0 drops a reference per instantiation (see there)


class FlexarmControllerFB(ControllerSlave):
    """Feedback only (``flexarm.control`` mode ``"fb"``), gains from ``gain_set``."""

    MODE = "fb"
    description = "Sandia two-link flexible arm: feedback-only scheduled LQR controller"
