"""The laws' operations that NumPy cannot apply to CasADi symbols: a clamp and rounding to an integer.

The laws (:mod:`flexarm.control_law`, :mod:`flexarm.sensor_law`) are written once, in NumPy, and the native FMUs'
C is generated from them by evaluating them on CasADi symbols (:mod:`fmu_build.law_codegen`). A comparison of
symbols has no truth value, so these two take another path on symbols, to the same IEEE-754 result for every
finite value: C99's fmax/fmin for the clamp, and x − remainder(x, 1) (IEEE's remainder rounds the quotient half
to even, as :func:`numpy.round` and C's nearbyint do) with the sign of x kept, so −0.3 rounds to −0.0 as NumPy's
does. CasADi is imported only on that path (the generator's).
"""

from __future__ import annotations

import numpy as np


def _symbolic(x) -> bool:
    return np.asarray(x).dtype.kind == "O"


def clamp(x, lo, hi):
    """x clamped to [lo, hi] elementwise (NaN: NumPy keeps it; the generated C, built for finite inputs, which the
    FMI glue alone lets in, would return a bound)."""
    if _symbolic(x):
        return np.array([xi.fmax(a).fmin(b) for xi, a, b in np.broadcast(x, lo, hi)], dtype=object).reshape(
            np.broadcast(x, lo, hi).shape)
    return np.minimum(np.maximum(x, lo), hi)  # np.clip, without its overhead


def round_half_even(x):
    """The nearest integer to x elementwise, halves to even (:func:`numpy.round`)."""
    if _symbolic(x):
        import casadi as ca

        return np.array([ca.copysign(xi - ca.remainder(xi, 1.0), xi) for xi in np.ravel(x)],
                        dtype=object).reshape(np.shape(x))
    return np.round(x)
