"""The laws' operations that NumPy cannot apply to CasADi symbols, each with its path for numbers and for symbols.

The laws (:mod:`flexarm.control_law`, :mod:`flexarm.filter_law`, :mod:`flexarm.sensor_law`,
:mod:`flexarm.filter_design`) are written once, in NumPy and Python arithmetic, and the native FMUs' C is generated
from them by evaluating them on CasADi symbols (:mod:`fmu_build.law_codegen`). A comparison of symbols has no truth
value, a symbol has no NumPy ufunc, and NumPy's reductions sum in an order of their own, so the operations here
take another path on symbols, to the same IEEE-754 result for every value, NaN and ±inf included:

* selections: :func:`select` (a scalar), :func:`where` (elementwise), :func:`where_all_equal`, the clamp
  (:func:`clamp`: selections by comparison, the sign from fmax/fmin);
* rounding to an integer (:func:`round_half_even`: x − remainder(x, 1), IEEE's remainder rounds the quotient half
  to even as :func:`numpy.round` and C's nearbyint do, with the sign of x kept, so −0.3 rounds to −0.0 as NumPy's);
* sums in NumPy's order: :func:`mat_vec`, :func:`dot`, :func:`weighted`, :func:`log_sum_exp` (a left fold of
  logaddexp), :func:`exp`;
* matrices as CasADi MX operations, so that their loops stay loops in the C: :func:`matmul`, :func:`solve`,
  :func:`identity_minus`;
* :func:`as_written`: CasADi's simplification on the fly off while a law is built, so a·(1/b) stays a·(1/b).

CasADi is imported only on the symbols' path (the generator's).
"""

from __future__ import annotations

import contextlib

import numpy as np


def _symbolic(x) -> bool:
    return np.asarray(x).dtype.kind == "O"


def is_symbol(x) -> bool:
    """True for a scalar that is not a number (a CasADi symbol: the generator's path)."""
    return not isinstance(x, (float, int, np.floating, np.integer, np.bool_))


def select(condition, if_true, otherwise):
    """`if_true` if `condition` else `otherwise`, for scalars: Python's conditional on numbers, CasADi's
    ``if_else`` on a symbolic condition."""
    if is_symbol(condition):
        import casadi as ca

        return ca.if_else(condition, if_true, otherwise)
    return if_true if condition else otherwise


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
    with as_written():
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
    return np.array(rows, dtype=object)


@contextlib.contextmanager
def as_written():
    """Build CasADi expressions exactly as written: its on-the-fly simplification rewrites (s + t) − s as t and
    a·(1/b) as a/b, which round differently from what the numbers path computes."""
    import casadi as ca

    was = ca.GlobalOptions.getSimplificationOnTheFly()
    ca.GlobalOptions.setSimplificationOnTheFly(False)
    try:
        yield
    finally:
        ca.GlobalOptions.setSimplificationOnTheFly(was)


def where(condition, if_true, otherwise):
    """`if_true` where `condition` holds, else `otherwise`, elementwise (:func:`numpy.where`)."""
    if not _symbolic(condition) and not _symbolic(if_true) and not _symbolic(otherwise):
        return np.where(condition, if_true, otherwise)
    import casadi as ca

    shape = np.broadcast(condition, if_true, otherwise).shape
    return np.array([ca.if_else(c, a, b) for c, a, b in np.broadcast(condition, if_true, otherwise)],
                    dtype=object).reshape(shape)


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


#: NumPy's NPY_LOGE2, log 2 (its logaddexp of two equal values).
LOGE2 = 0.693147180559945309417232121458176568


def log_sum_exp(v):
    """log Σ exp(v) over the last axis as :func:`numpy.logaddexp.reduce` forms it: a left fold of NumPy's
    logaddexp, max + log1p(exp(−|x − y|)), x + log 2 when equal (on symbols, one vector; the generated C calls the
    portable exp and log1p, :func:`fmu_build.law_codegen`)."""
    if not _symbolic(v):
        return np.logaddexp.reduce(v, axis=-1)
    import casadi as ca

    v = np.ravel(np.asarray(v, dtype=object))
    with as_written():
        total = v[0]
        for y in v[1:]:
            t = total - y
            ordered = ca.if_else(t > 0, total + ca.log1p(ca.exp(-t)), ca.if_else(t <= 0, y + ca.log1p(ca.exp(t)), t))
            total = ca.if_else(total == y, total + LOGE2, ordered)
    out = np.empty((), dtype=object)  # a 0-d object array: NumPy would try to convert a bare symbol
    out[()] = total
    return out


def exp(x):
    """e^x elementwise (NumPy's on numbers; the portable one in the generated C)."""
    if not _symbolic(x):
        return np.exp(x)
    import casadi as ca

    return np.array([ca.exp(xi) for xi in np.ravel(x)], dtype=object).reshape(np.shape(x))


def _matrix_symbol(x) -> bool:
    """A CasADi MX matrix: the generator's path for laws on whole matrices (compact loops in the generated C)."""
    return type(x).__name__ == "MX"


def matmul(a, b):
    """a b (NumPy's ``@`` on numbers; CasADi's mtimes, plain sums in order, on MX matrices)."""
    if _matrix_symbol(a) or _matrix_symbol(b):
        import casadi as ca

        return ca.mtimes(a, b)
    return a @ b


def solve(a, b):
    """a⁻¹ b for a symmetric positive definite a (NumPy's LU solve on numbers; CasADi's LDLᵀ on MX matrices)."""
    if _matrix_symbol(a) or _matrix_symbol(b):
        import casadi as ca

        return ca.solve(a, b, "ldl")
    return np.linalg.solve(a, b)


def identity_minus(a):
    """I − a for a square a."""
    if _matrix_symbol(a):
        import casadi as ca

        return ca.DM.eye(a.shape[0]) - a
    return np.eye(len(a)) - a
