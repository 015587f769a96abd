"""The LQG's per-sample arithmetic, written once (issue 33 item 4): its Kalman filters, predictor and feedback.

The library's laws (:class:`flexarm.lqg.LqgController`, :class:`flexarm.lqg.PredictedTracking`,
:class:`flexarm.lqg_bank.BankController`, the last on all its filters at once) call these functions on NumPy
arrays; the native controller FMUs' C is generated from them, evaluated on CasADi symbols at build time
(:mod:`fmu_build.law_codegen`), as :mod:`flexarm.control_law`'s. The C keeps which sample and which design point is
which, and the order of the steps.

Matrix-vector products go through :func:`flexarm.law_ops.mat_vec`: NumPy's (BLAS) on numbers, compensated sums
in the generated C. Shapes: the error state x (22,) (11 angles, rad, and 11 rates, rad/s, about the trajectory),
the ten measurements (q1, q2, q̇1, q̇2, ε1..ε6), torques (2,) in N·m.
"""

from __future__ import annotations

import numpy as np

from .law_ops import (
    clamp,
    dot,
    exp,
    identity_minus,
    log_sum_exp,
    mat_vec,
    matmul,
    solve,
    weighted,
    where,
    where_all_equal,
)


def time_update(phi, gamma, x, du, drift=None):
    """x⁺ = Φ x + Γ Δτ (+ d): the error state one sample on.

    Parameters
    ----------
    phi : array_like, shape (22, 22)
        Φ of the design point in force at the sample x belongs to.
    gamma : array_like, shape (22, 2)
        Γ there (per N·m).
    x : array_like, shape (22,)
    du : array_like, shape (2,)
        The torques held over the sample less the nominal feedforward, N·m.
    drift : array_like, shape (22,), optional
        A payload model's drift over the sample (:func:`flexarm.lqg_bank.drift_along_path`).

    The payload bank passes all its filters at once: phi (n, 22, 22), gamma (n, 22, 2), x (n, 22), drift (n, 22).
    """
    x_next = mat_vec(phi, x) + mat_vec(gamma, du)
    return x_next if drift is None else x_next + drift


def innovation(x, c, measurements, desired):
    """e = (m − m_d) − C x: what the measurements say that the prior x does not, shape (10,) (or (n, 10) for n
    priors x (n, 22)).

    Parameters
    ----------
    x : array_like, shape (22,)
        The prior.
    c : array_like, shape (10, 22)
        The sensor map C.
    measurements, desired : array_like, shape (10,)
        m and the trajectory's m_d of the sample (rad, rad/s).
    """
    return (measurements - desired) - mat_vec(c, x)


def updated(x, gain, innovation):
    """The posterior x + M e: the measurement update with the filter gain M (22, 10) (or one per prior)."""
    return x + mat_vec(gain, innovation)


def corrected(x, gain, c, measurements, desired):
    """The posterior x + M ((m − m_d) − C x) of the single filter (:func:`innovation`, :func:`updated`)."""
    return updated(x, gain, innovation(x, c, measurements, desired))


def log_likelihood_update(log_p, e, s_inv, log_det_s):
    """log p − ½ (eᵀ S⁻¹ e + log det S): a model's log posterior after its innovation e (10,), S⁻¹ (10, 10) and
    log det S of its filter (the payload bank; batched over models on numbers)."""
    return log_p - 0.5 * (dot(e, mat_vec(s_inv, e)) + log_det_s)


def normalised_posterior(log_p, log_floor, active=None):
    """The payload bank's log posterior normalised, floored at `log_floor` and normalised again, and its
    probabilities: (log p, p), each (n_models,). A NaN stays NaN (np.maximum's floor). `active` (symbols only: the
    generated C's fixed length) marks the models present; the rest come out −inf and 0, and change no sum."""
    if active is not None:
        log_p = where(active, log_p, -np.inf)
    log_p = log_p - log_sum_exp(log_p)
    log_p = clamp(log_p, log_floor, np.inf)
    if active is not None:
        log_p = where(active, log_p, -np.inf)
    log_p = log_p - log_sum_exp(log_p)
    if active is not None:  # a NaN posterior leaves the absent ones −inf too
        log_p = where(active, log_p, -np.inf)
    return log_p, exp(log_p)


def state_drift(psi, delta_acceleration):
    """d = Ψ Δα: a payload model's state drift over one sample (rad, rad/s), shape (22,), from Ψ E (22, 11) of its
    design point and what the payload adds to the element accelerations (11,), rad/s²."""
    return mat_vec(psi, delta_acceleration)


def reseeded(p_unloaded, reseed_below, x_quiet, x_unloaded):
    """The quiet filter's estimate: the unloaded model's once its posterior p_unloaded falls below `reseed_below`
    (the unloaded arm is ruled out; a NaN posterior rules out nothing), else its own."""
    return where(p_unloaded < reseed_below, x_unloaded, x_quiet)


def covariance_step(p, c, v, phi, w):
    """One sample of the time-varying Kalman filter: the gain M = P Cᵀ (C P Cᵀ + V)⁻¹ (22, 10) and the next prior
    P⁺ = Φ (I − M C) P Φᵀ + W (22, 22), symmetrised (P, V, W symmetric; :func:`flexarm.lqg_design.transient_gains`).
    On numbers NumPy's products and LU solve, as before; the generated C (MX) CasADi's products and LDLᵀ solve."""
    cp = matmul(c, p)
    gain = solve(matmul(cp, c.T) + v, cp).T
    p_next = matmul(matmul(phi, matmul(identity_minus(matmul(gain, c)), p)), phi.T) + w
    return gain, 0.5 * (p_next + p_next.T)


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


def feedback(gain, x, gain_integral=None, xi=None):
    """u = K x (+ K_ξ ξ): one payload model's feedback on its own estimate, N·m, shape (2,) (batched over models
    on numbers: gain (n, 2, 22), x (n, 22))."""
    u = mat_vec(gain, x)
    return u if gain_integral is None else u + mat_vec(gain_integral, xi)


def bank_free_torque(command, weights, feedbacks):
    """τ = τ_cmd − Σ_f w_f u_f before the saturation: the payload bank's models' feedbacks (n, 2) weighed by
    their posterior (n,), N·m."""
    return command - weighted(weights, feedbacks)


def weighted_estimate(weights, estimates):
    """Σ_f w_f x_f: the bank's estimates (n, 22) weighed as its torque (the integrators' input)."""
    return weighted(weights, estimates)


def integrated(xi, dt, c_q, x, tau, tau_free):
    """ξ + dt C_q x, only in a sample whose torque did not saturate (τ = τ_free): conditional integration,
    the anti-windup. c_q (2, 22) maps the error state to the joint angles; dt in s."""
    return where_all_equal(tau, tau_free, xi + dt * mat_vec(c_q, x), xi)
