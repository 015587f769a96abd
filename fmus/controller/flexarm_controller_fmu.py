"""Controller FMU ``controller``: the paper's feedforward + scheduled LQR tracking law (FMI 2.0 co-simulation).

Interface and behaviour: :mod:`flexarm_controller_base` and ``docs/fmu-interface.md``.
"""

from __future__ import annotations

from flexarm_controller_base import ControllerSlave
from flexarm_fmu_base import pin_module_namespace

pin_module_namespace(globals())  # pythonfmu 0.7.0 drops a reference per instantiation (see there)


class FlexarmController(ControllerSlave):
    """Feedforward + LQR feedback (``flexarm.control`` mode ``"ff+fb"``), gains from ``gain_set``."""

    MODE = "ff+fb"
    description = "Sandia two-link flexible arm: feedforward + scheduled LQR tracking controller"
