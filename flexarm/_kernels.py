"""Numerical kernels of the 11-element chain, gathered: dynamics, Jacobian, RODAS4, Gauss, exponential and RK4 steps.

The kernels live in two modules by concern: the equations of motion (with the small dense solvers and the
kinematics of element ends) in :mod:`flexarm._dynamics_kernels`, the time steppers in
:mod:`flexarm._integrator_kernels`. This module re-exports both under one name, the one the plant, the
tests and :func:`flexarm.model.numpy_kernels` use. Set ``FLEXARM_NO_NUMBA=1`` to force the NumPy path.
"""

from __future__ import annotations

from ._dynamics_kernels import (
    HAVE_NUMBA,
    _jit,
    acceleration,
    acceleration_jacobian,
    assemble,
    chain_kinematics,
    input_forces,
    lu_factor,
    lu_solve,
    spd_solve,
    spd_solve_columns,
    stage_derivative,
    state_derivative,
    tangent_matrices,
    trig_differences,
)
from ._integrator_kernels import (
    _PADE13,
    _THETA13,
    GAUSS_A,
    GAUSS_A2,
    GAUSS_C,
    GAUSS_FLOOR,
    GAUSS_MAX_ITER,
    GAUSS_TOL,
    RODAS4_A,
    RODAS4_ANGLE_TOL,
    RODAS4_C,
    RODAS4_GAMMA,
    RODAS4_MAX_HALVINGS,
    _rodas4_step_vectorised,
    _stage_system,
    advance,
    advance_exponential,
    advance_gauss,
    advance_rk4,
    expm,
    exponential_euler_step,
    gauss_step,
    rodas4_step,
)

if HAVE_NUMBA:
    from ._integrator_kernels import (
        _rodas4_step_loops as _rodas4_step_loops,  # the compiled RODAS4 step (NumPy: the vectorised one)
    )

__all__ = [
    "HAVE_NUMBA", "acceleration", "acceleration_jacobian", "assemble", "chain_kinematics", "input_forces",
    "lu_factor", "lu_solve", "spd_solve", "spd_solve_columns", "stage_derivative", "state_derivative",
    "tangent_matrices", "trig_differences", "GAUSS_A", "GAUSS_A2", "GAUSS_C", "GAUSS_FLOOR", "GAUSS_MAX_ITER",
    "GAUSS_TOL", "RODAS4_A", "RODAS4_ANGLE_TOL", "RODAS4_C", "RODAS4_GAMMA", "RODAS4_MAX_HALVINGS", "advance",
    "advance_exponential", "advance_gauss", "advance_rk4", "exponential_euler_step", "expm", "gauss_step",
    "rodas4_step", "_PADE13", "_THETA13", "_jit", "_rodas4_step_vectorised", "_stage_system",
]
