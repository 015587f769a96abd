"""The laws' operations that NumPy cannot apply to CasADi symbols: a clamp and rounding to an integer.

The laws (:mod:`flexarm.control_law`, :mod:`flexarm.sensor_law`) are written once, in NumPy, and the native FMUs'
C is generated from them by evaluating them on CasADi symbols (:mod:`fmu_build.law_codegen`). A comparison of
symbols has no truth value, so these two take another path on symbols, to the same IEEE-754 result for every
value, NaN and ±inf included: selections by comparison for the clamp, and x − remainder(x, 1) for the rounding
(IEEE's remainder rounds the quotient half to even, as :func:`numpy.round` and C's nearbyint do) with the sign of
x kept, so −0.3 rounds to −0.0 as NumPy's does. CasADi is imported only on that path (the generator's).
"""

from __future__ import annotations

import numpy as np


def _symbolic(x) -> bool:
    return np.asarray(x).dtype.kind == "O"


def clamp(x, lo, hi):
    """x clamped to [lo, hi] elementwise; NaN stays NaN (a diverged signal must not come out as a bound)."""
    if _symbolic(x):
        return np.array([_clamp_symbol(*args) for args in np.broadcast(x, lo, hi)], dtype=object).reshape(
            np.broadcast(x, lo, hi).shape)
    return np.minimum(np.maximum(x, lo), hi)  # np.clip, without its overhead


def _clamp_symbol(x, lo, hi):
    """NumPy's clamp on a symbol. C's fmax/fmin drop a NaN, so the value comes from comparisons (false for NaN:
    x passes), which CasADi writes as sums of selections; such a sum turns −0.0 into +0.0, so the sign comes
    from fmax/fmin's result (exact and signed; copysign keeps a NaN)."""
    import casadi as ca

    chosen = ca.if_else(x < lo, lo, ca.if_else(hi < x, hi, x))
    return ca.copysign(chosen, x.fmax(lo).fmin(hi))


def round_half_even(x):
    """The nearest integer to x elementwise, halves to even (:func:`numpy.round`)."""
    if _symbolic(x):
        import casadi as ca

        def rounded(xi):  # ±inf and NaN are their own (remainder would make them NaN)
            finite = xi.fmax(-xi) < np.inf
            return ca.copysign(ca.if_else(finite, xi - ca.remainder(xi, 1.0), xi), xi)

        return np.array([rounded(xi) for xi in np.ravel(x)], dtype=object).reshape(np.shape(x))
    return np.round(x)


def mat_vec(a, x):
    """A x: a (r, c) and x (c,) -> (r,); on numbers also batched, the product NumPy takes for the shapes.

    On numbers, NumPy's product (BLAS): a (r, c) on x (c,) as ``a @ x``; one matrix on a batch of vectors x (n, c)
    as ``x @ a.T`` (one GEMM), a matrix per vector, a (n, r, c) and x (n, c), as one ``matmul``; a batch of matrices
    on one vector as ``a @ x``. On symbols (a (r, c), x (c,) only), each row summed in order with a compensated
    (Neumaier) sum, nearly exact: the Kalman filters' lightly damped modes carry rounding over thousands of
    samples, and a nearly exact product keeps the generated law as close to the exact one as BLAS's is (plain sums
    in order drift further). Knuth's TwoSum gives each addition's exact rounding error without a branch; CasADi
    would simplify (s + t) − s to t, so the sums are built with its simplification off.
    """
    if not _symbolic(a) and not _symbolic(x):
        if np.ndim(x) == 1:
            return a @ x
        return x @ a.T if np.ndim(a) == 2 else np.matmul(a, x[..., None])[..., 0]
    import casadi as ca

    a, x = np.asarray(a, dtype=object), np.asarray(x, dtype=object)
    was = ca.GlobalOptions.getSimplificationOnTheFly()
    ca.GlobalOptions.setSimplificationOnTheFly(False)
    try:
        rows = []
        for row in a:
            total, carry = ca.SX(0.0), ca.SX(0.0)
            for aij, xj in zip(row, x):
                term = aij * xj
                t = total + term
                b = t - total
                carry = carry + ((total - (t - b)) + (term - b))
                total = t
            rows.append(total + carry)
    finally:
        ca.GlobalOptions.setSimplificationOnTheFly(was)
    return np.array(rows, dtype=object)


def where_all_equal(a, b, if_equal, otherwise):
    """`if_equal` when a equals b elementwise (NaN equals nothing), else `otherwise`."""
    if not _symbolic(a) and not _symbolic(b):
        return if_equal if np.array_equal(a, b) else otherwise
    import casadi as ca

    equal = ca.SX(1.0)
    for ai, bi in zip(np.ravel(a), np.ravel(b)):
        equal = equal * (ai == bi)
    return np.array([ca.if_else(equal, y, n) for y, n in zip(np.ravel(if_equal), np.ravel(otherwise))],
                    dtype=object).reshape(np.shape(if_equal))


def dot(a, b):
    """a · b over the last axis (a batch of vector pairs on numbers; one pair on symbols, a compensated sum)."""
    if not _symbolic(a) and not _symbolic(b):
        return np.einsum("...a,...a->...", a, b)
    return mat_vec(np.asarray(b, dtype=object)[None, :], a)[0]


def weighted(weights, rows):
    """Σ_f w_f rows_f: weights (n,) and rows (n, m) -> (m,) (``weights @ rows`` on numbers; on symbols each
    column a compensated sum over f in order)."""
    if not _symbolic(weights) and not _symbolic(rows):
        return weights @ rows
    return mat_vec(np.asarray(rows, dtype=object).T, weights)
