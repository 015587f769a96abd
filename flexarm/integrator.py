"""Time integration of the stiff arm model over a communication step.

The bracket springs put eigenvalues near 2π·21 kHz into the model; any
explicit scheme at a 1 ms step diverges, and generic implicit solvers with a
finite-difference Jacobian spend most of their time rebuilding it. We use a
linearly implicit, L-stable Rosenbrock method (RODAS4, order 4) with the
exact analytic Jacobian of :mod:`flexarm._kernels`, in a fixed number of
equal substeps per step: each substep costs one Jacobian, one 11×11 matrix
inverse and six right-hand sides, with no Newton iteration. L-stability
damps the (physically negligible, ~1e-6 rad) bracket vibrations instead of
resolving them; the 8 Hz and 20 Hz link modes are resolved to order 4.
Fixed substeps make every run deterministic (bit-for-bit repeatable), which
the FMUs' get/set-state and the sweeps rely on.
"""

from __future__ import annotations

import math

import numpy as np

from . import _kernels as kern
from .model import N_STATE, ArmModel, N

#: Default RODAS4 substeps per 1 ms communication step (see README: accuracy).
DEFAULT_SUBSTEPS = 2


class IntegrationError(RuntimeError):
    """The state became non-finite or the error estimate exploded."""


def advance(model: ArmModel, z, tau, dt: float, substeps: int = DEFAULT_SUBSTEPS) -> tuple[np.ndarray, float]:
    """Advance the state z (shape (22,)) by dt seconds with constant torque tau (N·m).

    Returns the new state and the largest embedded error estimate of the
    substeps (a diagnostic, in the state's units).
    """
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"dt: must be a finite step > 0 s, got {dt!r}")
    if int(substeps) < 1:
        raise ValueError(f"substeps: must be an integer >= 1, got {substeps!r}")
    tau = np.ascontiguousarray(tau, dtype=float)
    if tau.shape != (2,) or not np.isfinite(tau).all():
        raise ValueError(f"tau: must be two finite torques in N·m, got {tau!r}")
    z = np.ascontiguousarray(z, dtype=float)
    z_new, err = kern.advance(z, tau, float(dt), int(substeps), model.mass_coefficients, model.stiffness,
                              model.j2p, model.j2d, kern.RODAS4_A, kern.RODAS4_C, kern.RODAS4_GAMMA)
    if not np.isfinite(z_new).all():
        raise IntegrationError("state became non-finite")
    return z_new, float(err)


class PlantSimulator:
    """The arm as a stepping simulator: state, time and a 1 ms `step`.

    Parameters
    ----------
    model : ArmModel
    z0 : array_like, shape (22,)
        Initial state (angles rad, rates rad/s).
    substeps : int
        RODAS4 substeps per step.
    """

    def __init__(self, model: ArmModel, z0, substeps: int = DEFAULT_SUBSTEPS):
        self.model = model
        self.substeps = int(substeps)
        self.z = np.array(z0, dtype=float)
        if self.z.shape != (N_STATE,):
            raise ValueError(f"z0: expected shape ({N_STATE},), got {self.z.shape}")
        self.time = 0.0
        self.last_error = 0.0

    @property
    def theta(self) -> np.ndarray:
        return self.z[:N]

    @property
    def omega(self) -> np.ndarray:
        return self.z[N:]

    def step(self, tau, dt: float = 1e-3) -> np.ndarray:
        """Advance by dt (s) with torque tau held constant; returns the new state."""
        self.z, self.last_error = advance(self.model, self.z, tau, dt, self.substeps)
        self.time += dt
        return self.z


def simulate(model: ArmModel, z0, torques, dt: float = 1e-3, substeps: int = DEFAULT_SUBSTEPS) -> np.ndarray:
    """Open-loop run with piecewise-constant torques.

    Parameters
    ----------
    torques : array_like, shape (n_steps, 2)
        Torque held over each step, N·m.

    Returns
    -------
    ndarray, shape (n_steps + 1, 22)
        States at t = 0, dt, ..., n_steps·dt.
    """
    torques = np.asarray(torques, dtype=float)
    out = np.empty((len(torques) + 1, N_STATE))
    out[0] = z0
    z = np.asarray(z0, dtype=float)
    for k, tau in enumerate(torques):
        z, _ = advance(model, z, tau, dt, substeps)
        out[k + 1] = z
    return out
