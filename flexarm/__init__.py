"""flexarm: the Sandia two-link flexible arm as a plain Python library (no FMI).

Modules: :mod:`parameters` (parameter files), :mod:`model` (dynamics and
kinematics), :mod:`modes` (modal analysis), :mod:`integrator` (1 ms plant
step), :mod:`calibration` (fit the unknown parameters), :mod:`sensors`
(encoders, tachometers, strain gauges, accelerometers, filters, noise).
"""

from .model import (
    ArmModel,
    joint_angles,
    joint_velocities,
    reconstruct_angles,
    rigid_configuration,
    strain_gauge_angles,
)
from .parameters import ArmParameters, ParameterError, load_parameters

__all__ = [
    "ArmModel", "ArmParameters", "ParameterError", "joint_angles", "joint_velocities", "load_parameters",
    "reconstruct_angles", "rigid_configuration", "strain_gauge_angles",
]
__version__ = "0.1.0"
