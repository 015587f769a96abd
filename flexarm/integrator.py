"""Time integration of the stiff arm model over a communication step.

The bracket springs put eigenvalues near 2π·21 kHz into the model; any
explicit scheme at a 1 ms step diverges. Two schemes, both with the exact
analytic Jacobian of :mod:`flexarm._kernels` and a fixed number of equal
substeps per step (deterministic, bit-for-bit repeatable, which the FMUs'
get/set-state and the sweeps rely on):

``rodas4``
    Linearly implicit, L-stable Rosenbrock method (order 4): one Jacobian,
    one 11×11 LU and six right-hand sides per substep. L-stability DAMPS
    the bracket modes (5.6, 13, 21 kHz) it cannot resolve: at 0.5 ms
    substeps they lose most of their amplitude in a few ms, so an unstable
    bracket mode of a closed loop can look stable. The 8 and 20 Hz modes
    are resolved to order 4 (decay added below 1e-4 1/s).
``exponential``
    Exponential Rosenbrock-Euler, z⁺ = z + h φ1(hJ) f(z) (order 2), exact
    for the linearised dynamics: it adds NO numerical damping to any mode
    and does not shift any frequency, so the closed loop's true stability
    (the exact zero-order-hold discretisation) shows. Costs a 23×23 matrix
    exponential per substep.

docs/model.md gives the numerical damping per mode of each scheme and their
cost per 1 ms step.
"""

from __future__ import annotations

import math

import numpy as np

from . import _kernels as kern
from .model import N_STATE, ArmModel, N

#: Default substeps per 1 ms communication step (both schemes; docs/model.md: accuracy).
DEFAULT_SUBSTEPS = 2
#: The integration schemes, in the order of the plant FMU's ``integrator`` enumeration (1, 2).
INTEGRATORS = ("rodas4", "exponential")
DEFAULT_INTEGRATOR = "rodas4"


class IntegrationError(RuntimeError):
    """The state became non-finite or the error estimate exploded."""


def check_integrator(integrator: str) -> str:
    """The scheme's name, or ValueError naming the allowed ones."""
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator: must be one of {', '.join(INTEGRATORS)}, got {integrator!r}")
    return integrator


def advance(model: ArmModel, z, tau, dt: float, substeps: int = DEFAULT_SUBSTEPS,
            integrator: str = DEFAULT_INTEGRATOR) -> tuple[np.ndarray, float]:
    """Advance the state z (shape (22,)) by dt seconds with constant torque tau (N·m).

    Parameters
    ----------
    integrator : {"rodas4", "exponential"}
        Scheme (see the module notes).

    Returns the new state and, for RODAS4, the largest embedded error estimate
    of the substeps (a diagnostic, in the state's units; 0 for the exponential
    scheme, which has no embedded estimate).
    """
    check_integrator(integrator)
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"dt: must be a finite step > 0 s, got {dt!r}")
    if int(substeps) < 1:
        raise ValueError(f"substeps: must be an integer >= 1, got {substeps!r}")
    tau = np.ascontiguousarray(tau, dtype=float)
    if tau.shape != (2,) or not np.isfinite(tau).all():
        raise ValueError(f"tau: must be two finite torques in N·m, got {tau!r}")
    z = np.ascontiguousarray(z, dtype=float)
    try:
        if integrator == "exponential":
            z_new = kern.advance_exponential(z, tau, float(dt), int(substeps), model.mass_coefficients,
                                             model.stiffness, model.j2p, model.j2d, model.damping)
            err = 0.0
        else:
            z_new, err = kern.advance(z, tau, float(dt), int(substeps), model.mass_coefficients,
                                      model.stiffness, model.j2p, model.j2d, model.damping, kern.RODAS4_A,
                                      kern.RODAS4_C, kern.RODAS4_GAMMA)
    except (ValueError, ZeroDivisionError, np.linalg.LinAlgError) as exc:
        # Absurd torques or steps overflow the stage systems to inf/NaN before the state does: the
        # kernels' factorisations then report a singular or indefinite matrix.
        raise IntegrationError(f"state or stage system became non-finite ({exc})") from exc
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
        Substeps per step.
    integrator : {"rodas4", "exponential"}
    """

    def __init__(self, model: ArmModel, z0, substeps: int = DEFAULT_SUBSTEPS, integrator: str = DEFAULT_INTEGRATOR):
        self.model = model
        self.substeps = int(substeps)
        self.integrator = check_integrator(integrator)
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
        self.z, self.last_error = advance(self.model, self.z, tau, dt, self.substeps, self.integrator)
        self.time += dt
        return self.z


def simulate(model: ArmModel, z0, torques, dt: float = 1e-3, substeps: int = DEFAULT_SUBSTEPS,
             integrator: str = DEFAULT_INTEGRATOR) -> np.ndarray:
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
        z, _ = advance(model, z, tau, dt, substeps, integrator)
        out[k + 1] = z
    return out


def rodas4_stability(z: complex) -> complex:
    """RODAS4's stability function R(z) (one step of y' = λy, z = λh), with the coefficients the kernel uses."""
    a, c, gamma = kern.RODAS4_A, kern.RODAS4_C, kern.RODAS4_GAMMA
    g = 1.0 / gamma
    ks: list[complex] = []
    u = 1.0 + 0.0j
    for stage in range(6):
        if stage == 0:
            f = z * u
        else:
            u = (1.0 + sum(a[stage, j] * ks[j] for j in range(stage))) if stage < 5 else u + ks[4]
            f = z * u + sum(c[stage, j] * ks[j] for j in range(stage))
        ks.append(f / (g - z))
    return u + ks[5]


def numerical_decay_rate(frequency_hz: float, integrator: str = DEFAULT_INTEGRATOR,
                         substeps: int = DEFAULT_SUBSTEPS, dt: float = 1e-3) -> float:
    """Decay rate (1/s) that the scheme adds to an undamped linear mode of frequency `frequency_hz`.

    A free mode then decays as exp(−rate·t) in the simulation while the model says it should not.
    RODAS4: −ln|R(iωh)|/h with h = dt/substeps. Exponential Rosenbrock-Euler: 0 (exact for linear
    dynamics; round-off only).
    """
    check_integrator(integrator)
    if integrator == "exponential":
        return 0.0
    h = dt / int(substeps)
    return float(-math.log(abs(rodas4_stability(1j * 2 * math.pi * float(frequency_hz) * h))) / h)
