"""The controllers' per-sample arithmetic, written once (issue 33 item 4).

The library's controllers (:mod:`flexarm.control`, :mod:`flexarm.lqg`) call these functions on NumPy arrays; the
native controller FMUs' C is generated from the very same functions, evaluated on CasADi symbols at build time
(:mod:`fmu_build.law_codegen`). A change here is a change of both FMU kinds: there is no hand-kept C copy of it.

They are plain NumPy on purpose: matrix products with ``@`` and :func:`numpy.einsum` (on object arrays of symbols
NumPy sums the products in order, the order the C then runs), the rest element by element. The one operation NumPy
cannot apply to symbols, the clamp of a saturation, is :func:`flexarm.law_ops.clamp`.

Shapes: the paper's law on the ten measurements m = (q1, q2, q̇1, q̇2, ε1..ε6) (rad, rad/s), the reduced gain K
(2, 22) of the set in force, the estimator E (22, 10) with x̂ = E m (eqs. 21-31), torques in N·m.
"""

from __future__ import annotations

import numpy as np

from .law_ops import clamp

#: A set of a gain schedule (or an LQG design point) is in force from its time minus this (s): the sample grid's
#: times k·dt are products, a few ulp off the schedule's times, and must not miss the switch at their own sample.
SWITCH_TOLERANCE_S = 1e-9


def has_switched(switch_time, t):
    """Whether a set switching in at `switch_time` (s) is in force at time `t` (s); elementwise.

    The schedules' rule (:func:`flexarm.gain_schedule.schedule_index`): the set in force at t is the last whose
    switching time is at most t + :data:`SWITCH_TOLERANCE_S`.
    """
    return switch_time <= t + SWITCH_TOLERANCE_S  # on symbols: 1 or 0 in the generated C


def corrected_feedforward(feedforward, correction):
    """The feedforward the law sends, N·m (2,): the trajectory's plus a learned correction (:mod:`flexarm.ilc`).
    Which row of each (zero after the slew, zero past the correction's end) the callers say."""
    return feedforward + correction


def gain_on_measurements(gain, estimator):
    """K E: a gain on the ten measurements.

    Parameters
    ----------
    gain : array_like, shape (2, 22)
        Reduced gain K (N·m per rad, N·m per rad/s).
    estimator : array_like, shape (22, 10)
        E, x̂ = E m.

    Returns
    -------
    ndarray, shape (2, 10)
    """
    return gain @ estimator


def reconstructed_states(measurements, estimator):
    """x̂ = E m of each row of `measurements`, shape (n, 10) -> (n, 22) (rad, rad/s)."""
    return measurements @ estimator.T


def gain_offsets(gains, states):
    """K(k) x̂_d(k) of each sample k: gains (n, 2, 22) and states (n, 22) -> (n, 2), N·m."""
    return np.einsum("kij,kj->ki", gains, states)


def tracking_torque(feedforward, gain_on_measurement, measurements, offset, limit):
    """The paper's law at one sample: τ = sat(τ_ff − (K E m − K x̂_d)).

    Parameters
    ----------
    feedforward : array_like, shape (2,)
        τ_ff of the sample (with a learned correction), N·m.
    gain_on_measurement : array_like, shape (2, 10)
        K E of the set in force (:func:`gain_on_measurements`).
    measurements : array_like, shape (10,)
        m (or, predicting over a loop delay, the predicted deviation C x̂ with a zero offset).
    offset : array_like, shape (2,)
        K x̂_d of the sample (:func:`gain_offsets`).
    limit : array_like, shape (2,) or None
        |τ_1|, |τ_2| limits, N·m (None: no saturation).

    Returns
    -------
    ndarray, shape (2,)
    """
    tau = feedforward - (gain_on_measurement @ measurements - offset)
    return tau if limit is None else saturate(tau, limit)


def saturate(tau, limit):
    """τ clamped to [−limit, limit] elementwise (N·m)."""
    return clamp(tau, -limit, limit)
