"""The chain's equations of motion as Numba kernels: mass matrix, forces, accelerations and their Jacobian.

Also the small dense solvers they need (Cholesky, LU with pivoting) and the kinematics of element ends.
Written in the subset of NumPy that Numba compiles. With Numba installed the
kernels are compiled to machine code on first use (the 1 ms plant step then
costs tens of microseconds instead of hundreds); without it they run as plain
NumPy with identical mathematics. Set ``FLEXARM_NO_NUMBA=1`` to force the
NumPy path. The time steppers that call these are in :mod:`flexarm._integrator_kernels`;
:mod:`flexarm._kernels` gathers both.

Arguments common to all kernels
-------------------------------
theta, omega : (n,) absolute element angles (rad) and rates (rad/s)
tau : (2,) joint torques (N·m)
mc : (n, n) constant mass coefficients M_jk (kg·m²)
kl : (n, n) Laplacian stiffness matrix (N·m/rad)
j2p, j2d : elements (0-based) that the joint-2 torque acts between
    (reaction on j2p, action on j2d); the joint-1 torque acts on element 0.
dmp : (n, n) structural damping matrix C_d (N·m·s/rad), symmetric positive
    semi-definite, zero on the rigid-body motions; the generalised force
    −C_d θ̇ is added to the right-hand side (zeros: the paper's undamped model).
"""
from __future__ import annotations

import os

import numpy as np

HAVE_NUMBA = False
if not os.environ.get("FLEXARM_NO_NUMBA"):
    try:
        from numba import njit

        from ._numba_cache import keep_cache_per_build

        keep_cache_per_build()  # inside an FMU: one cache per FMU build, not per unpacking (20 s per run)
        HAVE_NUMBA = True
    except ImportError:  # the FMUs must run with numpy/scipy only
        pass


def _jit(func):
    if HAVE_NUMBA:
        return njit(cache=True, nogil=True)(func)
    return func


# Small dense linear algebra. Compiled, hand-written loops beat a LAPACK call
# (with its checks, copies and temporaries) several times over at n = 11;
# the NumPy path keeps LAPACK.
if HAVE_NUMBA:

    @_jit
    def _cholesky_into(a, low):
        """Lower Cholesky factor of `a` (only its lower triangle is read) into `low`; `low` may be `a`."""
        n = a.shape[0]
        for j in range(n):
            d = a[j, j]
            for k in range(j):
                d -= low[j, k] * low[j, k]
            if d <= 0.0:
                raise ValueError("mass matrix not positive definite")
            low[j, j] = np.sqrt(d)
            for i in range(j + 1, n):
                s = a[i, j]
                for k in range(j):
                    s -= low[i, k] * low[j, k]
                low[i, j] = s / low[j, j]

    @_jit
    def _cholesky(a):
        low = np.zeros(a.shape)
        _cholesky_into(a, low)
        return low

    @_jit
    def _cholesky_substitute(low, x):
        n = low.shape[0]
        for i in range(n):
            for k in range(i):
                x[i] -= low[i, k] * x[k]
            x[i] /= low[i, i]
        for i in range(n - 1, -1, -1):
            for k in range(i + 1, n):
                x[i] -= low[k, i] * x[k]
            x[i] /= low[i, i]

    @_jit
    def spd_solve(a, b):
        """Solve a x = b, a symmetric positive definite (n, n), b (n,)."""
        x = b.copy()
        _cholesky_substitute(_cholesky(a), x)
        return x

    @_jit
    def spd_solve_columns(a, b):
        """Solve a X = B, a symmetric positive definite (n, n), B (n, k)."""
        low = _cholesky(a)
        out = np.empty_like(b)
        col = np.empty(b.shape[0])
        for j in range(b.shape[1]):
            for i in range(b.shape[0]):
                col[i] = b[i, j]
            _cholesky_substitute(low, col)
            for i in range(b.shape[0]):
                out[i, j] = col[i]
        return out

    @_jit
    def lu_factor(a):
        """LU factors with partial pivoting of a square matrix: (lu, pivots)."""
        n = a.shape[0]
        lu = a.copy()
        piv = np.arange(n)
        for k in range(n):
            p = k
            big = abs(lu[k, k])
            for i in range(k + 1, n):
                if abs(lu[i, k]) > big:
                    big = abs(lu[i, k])
                    p = i
            if big == 0.0:
                raise ValueError("singular stage matrix")
            if p != k:
                for j in range(n):
                    tmp = lu[k, j]
                    lu[k, j] = lu[p, j]
                    lu[p, j] = tmp
                tmp_i = piv[k]
                piv[k] = piv[p]
                piv[p] = tmp_i
            for i in range(k + 1, n):
                lu[i, k] /= lu[k, k]
                f = lu[i, k]
                for j in range(k + 1, n):
                    lu[i, j] -= f * lu[k, j]
        return lu, piv

    @_jit
    def _lu_solve_into(lu, piv, b, x):
        """Solve with the factors of :func:`lu_factor` into `x` (n,)."""
        n = lu.shape[0]
        for i in range(n):
            x[i] = b[piv[i]]
        for i in range(n):
            for k in range(i):
                x[i] -= lu[i, k] * x[k]
        for i in range(n - 1, -1, -1):
            for k in range(i + 1, n):
                x[i] -= lu[i, k] * x[k]
            x[i] /= lu[i, i]

    @_jit
    def lu_solve(lu, piv, b):
        """Solve with the factors of :func:`lu_factor`; b shape (n,)."""
        x = np.empty(lu.shape[0])
        _lu_solve_into(lu, piv, b, x)
        return x

else:

    def spd_solve(a, b):
        """Solve a x = b for symmetric positive definite a (NumPy path)."""
        return np.linalg.solve(a, b)

    spd_solve_columns = spd_solve

    def lu_factor(a):
        """NumPy path: the inverse stands in for the factors (n = 11, reused six times)."""
        return np.linalg.inv(a), np.arange(a.shape[0])

    def lu_solve(lu, piv, b):
        return lu @ b


@_jit
def trig_differences(theta):
    """cos(θ_i − θ_j) and sin(θ_i − θ_j) from 2n trigonometric calls, shape (n, n) each."""
    c = np.cos(theta)
    s = np.sin(theta)
    cosd = np.outer(c, c) + np.outer(s, s)
    sind = np.outer(s, c) - np.outer(c, s)
    return cosd, sind


# Assembly of M(θ), the right-hand side and the tangent matrices. Numba gets
# fused loops (one pass, no temporaries: 4x cheaper at n = 11); NumPy gets the
# same formulas vectorised.
if HAVE_NUMBA:

    @_jit
    def assemble(theta, omega, mc, kl):
        """M(θ) (n, n), S(θ, θ̇) (n,), cos(θ_i−θ_j) and sin(θ_i−θ_j) (n, n)."""
        n = theta.shape[0]
        c = np.cos(theta)
        s = np.sin(theta)
        mass = np.empty((n, n))
        cosd = np.empty((n, n))
        sind = np.empty((n, n))
        rhs = np.zeros(n)
        for i in range(n):
            acc = 0.0
            for j in range(n):
                cd = c[i] * c[j] + s[i] * s[j]
                sd = s[i] * c[j] - c[i] * s[j]
                cosd[i, j] = cd
                sind[i, j] = sd
                mass[i, j] = mc[i, j] * cd
                acc += kl[i, j] * sd - mc[i, j] * sd * omega[j] * omega[j]
            rhs[i] = acc
        return mass, rhs, cosd, sind

    @_jit
    def tangent_matrices(mc, kl, cosd, sind, omega, acc):
        """∂(S − Mθ̈)/∂θ and ∂S/∂θ̇ at fixed θ̈, each (n, n)."""
        n = omega.shape[0]
        q = np.empty((n, n))
        v = np.empty((n, n))
        for i in range(n):
            row = 0.0
            for j in range(n):
                if i == j:
                    v[i, j] = 0.0
                    continue
                e = (mc[i, j] * omega[j] * omega[j] - kl[i, j]) * cosd[i, j] - mc[i, j] * sind[i, j] * acc[j]
                q[i, j] = e
                row += e
                v[i, j] = -2.0 * mc[i, j] * sind[i, j] * omega[j]
            q[i, i] = -row
        return q, v

else:

    def assemble(theta, omega, mc, kl):
        """M(θ) (n, n), S(θ, θ̇) (n,), cos(θ_i−θ_j) and sin(θ_i−θ_j) (n, n)."""
        cosd, sind = trig_differences(theta)
        rhs = -(mc * sind) @ (omega * omega) + (kl * sind).sum(axis=1)
        return mc * cosd, rhs, cosd, sind

    def tangent_matrices(mc, kl, cosd, sind, omega, acc):
        """∂(S − Mθ̈)/∂θ and ∂S/∂θ̇ at fixed θ̈, each (n, n)."""
        q = (mc * omega**2 - kl) * cosd - mc * sind * acc
        np.fill_diagonal(q, 0.0)
        q[np.diag_indices_from(q)] = -q.sum(axis=1)
        v = -2.0 * mc * sind * omega
        return q, v


# The RODAS4 stage right-hand sides: ż into `out` with the workspace reused
# across the six stages (Numba: no allocation per stage, lower triangle only).
if HAVE_NUMBA:

    @_jit
    def stage_derivative(z, tau, mc, kl, j2p, j2d, dmp, c, s, mass, out):
        """ż = f(z) + g(z)τ (eq. 7) into `out` (2n,); c, s (n,), mass (n, n) are workspace."""
        n = z.shape[0] // 2
        for i in range(n):
            c[i] = np.cos(z[i])
            s[i] = np.sin(z[i])
            out[i] = z[n + i]
        rhs = out[n:]
        for i in range(n):
            acc = 0.0
            for j in range(n):
                sd = s[i] * c[j] - c[i] * s[j]
                acc += kl[i, j] * sd - mc[i, j] * sd * z[n + j] * z[n + j] - dmp[i, j] * z[n + j]
                if j <= i:
                    mass[i, j] = mc[i, j] * (c[i] * c[j] + s[i] * s[j])
            rhs[i] = acc
        rhs[0] += tau[0]
        rhs[j2d] += tau[1]
        rhs[j2p] -= tau[1]
        _cholesky_into(mass, mass)  # in place: the lower triangle becomes the factor
        _cholesky_substitute(mass, rhs)

else:

    def stage_derivative(z, tau, mc, kl, j2p, j2d, dmp, c, s, mass, out):
        """ż = f(z) + g(z)τ (eq. 7) into `out` (NumPy path; the workspace is unused)."""
        out[:] = state_derivative(z, tau, mc, kl, j2p, j2d, dmp)


@_jit
def input_forces(tau, n, j2p, j2d):
    """Generalised forces B̄τ on the absolute angles, shape (n,)."""
    u = np.zeros(n)
    u[0] += tau[0]
    u[j2d] += tau[1]
    u[j2p] -= tau[1]
    return u


@_jit
def acceleration(theta, omega, tau, mc, kl, j2p, j2d, dmp):
    """θ̈ = M(θ)⁻¹ (S(θ, θ̇) − C_d θ̇ + B̄τ) (eq. 5 with damping), rad/s², shape (n,).

    S_i = Σ_j M_ij sin(θ_j − θ_i) θ̇_j² + Σ_j K_ij sin(θ_i − θ_j)   (eq. 8).
    """
    mass, rhs, _, _ = assemble(theta, omega, mc, kl)
    return spd_solve(mass, rhs - dmp @ omega + input_forces(tau, theta.shape[0], j2p, j2d))


@_jit
def state_derivative(z, tau, mc, kl, j2p, j2d, dmp):
    """ż = f(z) + g(z)τ (eq. 7), shape (2n,)."""
    n = z.shape[0] // 2
    out = np.empty_like(z)
    out[:n] = z[n:]
    out[n:] = acceleration(z[:n], z[n:], tau, mc, kl, j2p, j2d, dmp)
    return out


@_jit
def acceleration_jacobian(theta, omega, tau, mc, kl, j2p, j2d, dmp):
    """∂θ̈/∂θ and ∂θ̈/∂θ̇ at (θ, θ̇, τ), each shape (n, n); also returns θ̈.

    Differentiates M(θ)θ̈ = S(θ, θ̇) + B̄τ implicitly (eq. 14 with the
    appendix gradients, including the torque term):
    ∂θ̈/∂z = M⁻¹ (∂S/∂z − ∂M/∂z θ̈).
    """
    mass, rhs, cosd, sind = assemble(theta, omega, mc, kl)
    n = theta.shape[0]
    acc = spd_solve(mass, rhs - dmp @ omega + input_forces(tau, n, j2p, j2d))
    q, v = tangent_matrices(mc, kl, cosd, sind, omega, acc)
    both = np.empty((n, 2 * n))
    both[:, :n] = q
    both[:, n:] = v - dmp
    sol = spd_solve_columns(mass, both)
    return np.ascontiguousarray(sol[:, :n]), np.ascontiguousarray(sol[:, n:]), acc


@_jit
def chain_kinematics(theta, omega, alpha, length, ends):
    """Positions and accelerations of the distal ends of elements `ends`.

    Parameters
    ----------
    theta, omega, alpha : (n,) angles (rad), rates (rad/s), accelerations (rad/s²)
    length : (n,) element lengths (m)
    ends : (m,) int, 0-based elements, ascending

    Returns
    -------
    (m, 5) rows (x, y, ẍ, ÿ, a_n) in m and m/s², one pass over the chain; a_n is
    the acceleration normal to the end element, (−sin θ_e, cos θ_e)·(ẍ, ÿ).
    """
    out = np.zeros((ends.shape[0], 5))
    x = y = ax = ay = 0.0
    j = 0
    for i in range(theta.shape[0]):
        c, s = np.cos(theta[i]), np.sin(theta[i])
        om2 = omega[i] * omega[i]
        x += length[i] * c
        y += length[i] * s
        ax += length[i] * (-s * alpha[i] - c * om2)
        ay += length[i] * (c * alpha[i] - s * om2)
        while j < ends.shape[0] and ends[j] == i:
            out[j, 0], out[j, 1], out[j, 2], out[j, 3] = x, y, ax, ay
            out[j, 4] = -s * ax + c * ay
            j += 1
    return out
