"""Controller FMU ``controller_dlqr``: feedforward + discrete-time LQR (1 ms zero-order-hold design).

Same interface as ``controller`` (:mod:`flexarm_controller_base`);
``gain_set`` names the weights (``gamma_1`` → ``dlqr-gamma1``).
"""

from __future__ import annotations

from flexarm_controller_base import ControllerSlave
from flexarm_fmu_base import pin_module_namespace

pin_module_namespace(globals())  # pythonfmu 0.7.0 drops a reference per instantiation (see there)


class FlexarmControllerDLQR(ControllerSlave):
    """Feedforward + discrete LQR (``flexarm.control`` mode ``"ff+fb"``, ``dlqr-<gain_set>`` gains)."""

    MODE = "ff+fb"
    DISCRETE = True
    description = "Sandia two-link flexible arm: feedforward + scheduled discrete-time LQR controller"
