"""The LQG's per-sample arithmetic, written once (issue 33 item 4): its Kalman filter, predictor and feedback.

The library's laws (:class:`flexarm.lqg.LqgController`, :class:`flexarm.lqg.PredictedTracking`) call these
functions on NumPy arrays; the native controller FMUs' C is generated from them, evaluated on CasADi symbols at
build time (:mod:`fmu_build.law_codegen`), as :mod:`flexarm.control_law`'s. The C keeps which sample and which
design point is which, and the order of the steps.

Matrix-vector products go through :func:`flexarm.law_ops.mat_vec`: NumPy's (BLAS) on numbers, compensated sums
in the generated C. Shapes: the error state x (22,) (11 angles, rad, and 11 rates, rad/s, about the trajectory),
the ten measurements (q1, q2, q̇1, q̇2, ε1..ε6), torques (2,) in N·m.
"""

from __future__ import annotations

from .law_ops import mat_vec, where_all_equal


def time_update(phi, gamma, x, du):
    """x⁺ = Φ x + Γ Δτ: the error state one sample on.

    Parameters
    ----------
    phi : array_like, shape (22, 22)
        Φ of the design point in force at the sample x belongs to.
    gamma : array_like, shape (22, 2)
        Γ there (per N·m).
    x : array_like, shape (22,)
    du : array_like, shape (2,)
        The torques held over the sample less the nominal feedforward, N·m.
    """
    return mat_vec(phi, x) + mat_vec(gamma, du)


def corrected(x, gain, c, measurements, desired):
    """The posterior x + M ((m − m_d) − C x): the measurement update with the filter gain M.

    Parameters
    ----------
    x : array_like, shape (22,)
        The prior.
    gain : array_like, shape (22, 10)
        M of the sample.
    c : array_like, shape (10, 22)
        The sensor map C.
    measurements, desired : array_like, shape (10,)
        m and the trajectory's m_d of the sample (rad, rad/s).
    """
    return x + mat_vec(gain, (measurements - desired) - mat_vec(c, x))


def measured(c, x):
    """C x: the ten measurements' deviation that the error state x gives, shape (10,)."""
    return mat_vec(c, x)


def free_torque(command, gain, x, gain_integral=None, xi=None):
    """τ = τ_cmd − K x − K_ξ ξ before the saturation, N·m, shape (2,).

    Parameters
    ----------
    command : array_like, shape (2,)
        The feedforward of the sample with its learned correction, N·m.
    gain : array_like, shape (2, 22)
        K of the set in force (with integral action, the state part of the augmented gain).
    x : array_like, shape (22,)
        The error state predicted to the sample.
    gain_integral, xi : array_like, shape (2, 2) and (2,), optional
        K_ξ and the integrated joint-angle errors ξ (rad·s); None without integral action.
    """
    tau = command - mat_vec(gain, x)
    return tau if gain_integral is None else tau - mat_vec(gain_integral, xi)


def integrated(xi, dt, c_q, x, tau, tau_free):
    """ξ + dt C_q x, only in a sample whose torque did not saturate (τ = τ_free): conditional integration,
    the anti-windup. c_q (2, 22) maps the error state to the joint angles; dt in s."""
    return where_all_equal(tau, tau_free, xi + dt * mat_vec(c_q, x), xi)
