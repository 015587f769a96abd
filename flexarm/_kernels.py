"""Numerical kernels of the 11-element chain: dynamics, Jacobian, RODAS4, Gauss, exponential and RK4 steps.

Written in the subset of NumPy that Numba compiles. With Numba installed the
kernels are compiled to machine code on first use (the 1 ms plant step then
costs tens of microseconds instead of hundreds); without it they run as plain
NumPy with identical mathematics. Set ``FLEXARM_NO_NUMBA=1`` to force the
NumPy path.

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


# RODAS4 (Hairer & Wanner, Solving ODEs II, section IV.7; coefficients of
# rodas.f): 6 stages, order 4 with an embedded order-3 estimate, L-stable and
# stiffly accurate, so the bracket modes (tens of kHz) are damped rather than
# resolved, and the solution is the last stage value.
RODAS4_GAMMA = 0.25
RODAS4_A = np.array([
    [0.0, 0.0, 0.0, 0.0],
    [1.544, 0.0, 0.0, 0.0],
    [0.9466785280815826, 0.2557011698983284, 0.0, 0.0],
    [3.314825187068521, 2.896124015972201, 0.9986419139977817, 0.0],
    [1.221224509226641, 6.019134481288629, 12.53708332932087, -0.6878860361058950],
])
RODAS4_C = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0],
    [-5.6688, 0.0, 0.0, 0.0, 0.0],
    [-2.430093356833875, -0.2063599157091915, 0.0, 0.0, 0.0],
    [-0.1073529058151375, -9.594562251023355, -20.47028614809616, 0.0, 0.0],
    [7.496443313967647, -10.24680431464352, -33.99990352819905, 11.70890893206160, 0.0],
    [8.083246795921522, -7.981132988064893, -31.52159432874371, 16.31930543123136, -6.058818238834054],
])


@_jit
def _stage_system(z, tau, h, mc, kl, j2p, j2d, dmp, gamma):
    """What every RODAS4 stage of one step shares (see :func:`_rodas4_step_vectorised`).

    Returns g = 1/(γh), M, V, the LU factors of g² M − g V − Q, and ż at z (2n,).
    """
    n = z.shape[0] // 2
    theta = z[:n]
    omega = z[n:]
    mass, rhs, cosd, sind = assemble(theta, omega, mc, kl)
    acc = spd_solve(mass, rhs - dmp @ omega + input_forces(tau, n, j2p, j2d))
    q, v = tangent_matrices(mc, kl, cosd, sind, omega, acc)
    v = v - dmp
    g = 1.0 / (gamma * h)
    w_lu, w_piv = lu_factor(g * g * mass - g * v - q)
    f = np.empty(2 * n)
    f[:n] = omega
    f[n:] = acc
    return g, mass, v, w_lu, w_piv, f


@_jit
def _rodas4_step_vectorised(z, tau, h, mc, kl, j2p, j2d, dmp, coef_a, coef_c, gamma):
    """One RODAS4 step of size h (s) with constant torque; returns (z_new, error_estimate).

    The stage systems (I/(γh) − J) k = r are reduced with the second-order
    structure J = [[0, I], [A_θ, A_ω]] (A_θ = M⁻¹Q, A_ω = M⁻¹V, eq. 14) to
    one n×n system W k_θ = r_ω + g r_θ − A_ω r_θ, W = g² I − g A_ω − A_θ
    (g = 1/(γh)). Multiplied by M it needs no inverse of M at all:
    (g² M − g V − Q) k_θ = M (r_ω + g r_θ) − V r_θ, factored once per step
    (this saves the 2n solves that forming A_θ and A_ω would cost).
    """
    n = z.shape[0] // 2
    g, mass, v, w_lu, w_piv, f = _stage_system(z, tau, h, mc, kl, j2p, j2d, dmp, gamma)
    ks = np.zeros((6, 2 * n))
    u = z.copy()
    work_c, work_s, work_m = np.empty(n), np.empty(n), np.empty((n, n))
    for stage in range(6):
        if stage > 0:
            if stage < 5:
                u[:] = z
                for j in range(stage):
                    u += coef_a[stage, j] * ks[j]
            else:
                u += ks[4]
            stage_derivative(u, tau, mc, kl, j2p, j2d, dmp, work_c, work_s, work_m, f)
            for j in range(stage):
                f += (coef_c[stage, j] / h) * ks[j]
        r_th = f[:n]
        r_om = f[n:]
        k_th = lu_solve(w_lu, w_piv, mass @ (r_om + g * r_th) - v @ r_th)
        ks[stage, :n] = k_th
        ks[stage, n:] = g * k_th - r_th
    z_new = u + ks[5]
    return z_new, ks[5].copy()


if HAVE_NUMBA:

    @_jit
    def _rodas4_step_loops(z, tau, h, mc, kl, j2p, j2d, dmp, coef_a, coef_c, gamma):
        """:func:`_rodas4_step_vectorised` with explicit loops: no temporaries (Numba only)."""
        n = z.shape[0] // 2
        g, mass, v, w_lu, w_piv, f = _stage_system(z, tau, h, mc, kl, j2p, j2d, dmp, gamma)
        ks = np.zeros((6, 2 * n))
        u = z.copy()
        b = np.empty(n)
        k_th = np.empty(n)
        work_c, work_s, work_m = np.empty(n), np.empty(n), np.empty((n, n))
        for stage in range(6):
            if stage > 0:
                if stage < 5:
                    for i in range(2 * n):
                        t = z[i]
                        for j in range(stage):
                            t += coef_a[stage, j] * ks[j, i]
                        u[i] = t
                else:
                    for i in range(2 * n):
                        u[i] += ks[4, i]
                stage_derivative(u, tau, mc, kl, j2p, j2d, dmp, work_c, work_s, work_m, f)
                for j in range(stage):
                    cj = coef_c[stage, j] / h
                    for i in range(2 * n):
                        f[i] += cj * ks[j, i]
            # M (r_ω + g r_θ) − V r_θ, then the LU solve (see _rodas4_step_vectorised)
            for i in range(n):
                t = 0.0
                for j in range(n):
                    t += mass[i, j] * (f[n + j] + g * f[j]) - v[i, j] * f[j]
                b[i] = t
            _lu_solve_into(w_lu, w_piv, b, k_th)
            for i in range(n):
                ks[stage, i] = k_th[i]
                ks[stage, n + i] = g * k_th[i] - f[i]
        for i in range(2 * n):
            u[i] += ks[5, i]
        return u, ks[5].copy()

    rodas4_step = _rodas4_step_loops
else:
    rodas4_step = _rodas4_step_vectorised


@_jit
def advance(z, tau, dt, substeps, mc, kl, j2p, j2d, dmp, coef_a, coef_c, gamma):
    """Advance by dt (s) with constant torque in `substeps` equal RODAS4 steps.

    Returns (z_new, max_abs_error_estimate)."""
    h = dt / substeps
    err = 0.0
    for _ in range(substeps):
        z, e = rodas4_step(z, tau, h, mc, kl, j2p, j2d, dmp, coef_a, coef_c, gamma)
        err = max(err, np.max(np.abs(e)))
    return z, err


# Exponential Rosenbrock-Euler (Hochbruck, Ostermann & Schweitzer, SIAM J. Numer. Anal. 47, 2009):
# z⁺ = z + h φ1(hJ) f(z), J the exact Jacobian at z. Order 2, and exact for a linear system with
# constant torque, so every mode of the linearised arm (8 Hz to 21 kHz) keeps its amplitude and
# frequency: no numerical damping, no frequency warping. φ1(hJ)·hf is the last column of the
# exponential of the (2n+1)-square matrix [[hJ, hf], [0, 0]].
_PADE13 = np.array([64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
                    129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0,
                    40840800.0, 960960.0, 16380.0, 182.0, 1.0])
_THETA13 = 5.371920351148152  # 1-norm bound of the degree-13 Padé approximant (Higham, SIMAX 26, 2005)


# Numba and NumPy alike (NumPy: no SciPy import for a few matrix exponentials).
@_jit
def expm(a):
    """Matrix exponential: scaling and squaring with the [13/13] Padé approximant (Higham 2005)."""
    n = a.shape[0]
    norm = 0.0
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(a[i, j])
        norm = max(norm, col)
    s = 0
    if norm > _THETA13:
        s = int(np.ceil(np.log2(norm / _THETA13)))
    x = a * (0.5**s)
    b = _PADE13
    ident = np.eye(n)
    x2 = x @ x
    x4 = x2 @ x2
    x6 = x4 @ x2
    u = x @ (x6 @ (b[13] * x6 + b[11] * x4 + b[9] * x2) + b[7] * x6 + b[5] * x4 + b[3] * x2 + b[1] * ident)
    v = x6 @ (b[12] * x6 + b[10] * x4 + b[8] * x2) + b[6] * x6 + b[4] * x4 + b[2] * x2 + b[0] * ident
    r = np.ascontiguousarray(np.linalg.solve(v - u, v + u))
    for _ in range(s):
        r = r @ r
    return r



@_jit
def exponential_euler_step(z, tau, h, mc, kl, j2p, j2d, dmp):
    """One exponential Rosenbrock-Euler step of size h (s) with constant torque; returns z_new (2n,).

    The velocities are scaled by c = sqrt(max |diag ∂θ̈/∂θ|) (≈ the highest natural frequency) inside
    the exponential, which balances the blocks of hJ and cuts the squarings from about 25 to 6.
    """
    n = z.shape[0] // 2
    theta = z[:n]
    omega = z[n:]
    mass, rhs, cosd, sind = assemble(theta, omega, mc, kl)
    acc = spd_solve(mass, rhs - dmp @ omega + input_forces(tau, n, j2p, j2d))
    q, v = tangent_matrices(mc, kl, cosd, sind, omega, acc)
    both = np.empty((n, 2 * n))
    both[:, :n] = q
    both[:, n:] = v - dmp
    sol = spd_solve_columns(mass, both)  # [∂θ̈/∂θ, ∂θ̈/∂θ̇]
    c = 1.0
    for i in range(n):
        c = max(c, np.sqrt(abs(sol[i, i])))
    m = 2 * n
    aug = np.zeros((m + 1, m + 1))
    for i in range(n):
        aug[i, n + i] = h * c
        aug[i, m] = h * omega[i]
        aug[n + i, m] = h * acc[i] / c
        for j in range(n):
            aug[n + i, j] = h * sol[i, j] / c
            aug[n + i, n + j] = h * sol[i, n + j]
    e = expm(aug)
    z_new = z.copy()
    for i in range(n):
        z_new[i] += e[i, m]
        z_new[n + i] += c * e[n + i, m]
    return z_new


@_jit
def advance_exponential(z, tau, dt, substeps, mc, kl, j2p, j2d, dmp):
    """Advance by dt (s) with constant torque in `substeps` exponential Rosenbrock-Euler steps."""
    h = dt / substeps
    for _ in range(substeps):
        z = exponential_euler_step(z, tau, h, mc, kl, j2p, j2d, dmp)
    return z


# Gauss-Legendre collocation, 2 stages (order 4; Hairer, Lubich & Wanner, Geometric Numerical Integration,
# II.1.3): symmetric and A-stable with |R(iy)| = 1, so it adds no numerical damping to any mode and, applied to
# this reversible system (θ, θ̇) -> (θ, −θ̇), keeps the energy error bounded with no secular drift. Unknowns: the
# two stage accelerations K_i (n each); stage rates W_i = θ̇ + h Σ_j a_ij K_j and angles
# Θ_i = θ + h c_i θ̇ + h² Σ_j (a²)_ij K_j. Residual G_i(K) = M(Θ_i) K_i − (S(Θ_i, W_i) − C_d W_i + B̄τ), solved by
# simplified Newton with the iteration matrix δ_ij M − h² (a²)_ij Q − h a_ij (V − C_d) frozen at the step's start
# (eq. 14's tangents) and factored once per step, iterated to round-off.
_SQRT3 = np.sqrt(3.0)
GAUSS_A = np.array([[0.25, 0.25 - _SQRT3 / 6.0], [0.25 + _SQRT3 / 6.0, 0.25]])
GAUSS_A2 = GAUSS_A @ GAUSS_A
GAUSS_C = np.array([0.5 - _SQRT3 / 6.0, 0.5 + _SQRT3 / 6.0])
#: Newton: converged when max |ΔK| <= GAUSS_TOL · s, s = |θ̈|max + |θ̇|max / h + 1 rad/s² at the step's start, or
#: when the corrections stop contracting below GAUSS_FLOOR · s (round-off); at most GAUSS_MAX_ITER iterations.
GAUSS_TOL = 1e-13
GAUSS_FLOOR = 1e-6
GAUSS_MAX_ITER = 40


@_jit
def gauss_step(z, tau, h, mc, kl, j2p, j2d, dmp, coef_a, coef_a2, coef_c):
    """One 2-stage Gauss-Legendre step of size h (s) with constant torque; returns (z_new, newton_iterations).

    ValueError if the stage equations do not converge (the step is too long for the simplified Newton
    iteration, or the state is absurd): the caller reports an integration error, never a partial solution.
    """
    n = z.shape[0] // 2
    theta = z[:n]
    omega = z[n:]
    mass, rhs, cosd, sind = assemble(theta, omega, mc, kl)
    u = input_forces(tau, n, j2p, j2d)
    base = u - dmp @ omega
    acc = spd_solve(mass, rhs + base)
    q, v = tangent_matrices(mc, kl, cosd, sind, omega, acc)
    v = v - dmp
    w = np.empty((2 * n, 2 * n))
    for bi in range(2):
        for bj in range(2):
            blk = -(h * h * coef_a2[bi, bj]) * q - (h * coef_a[bi, bj]) * v
            if bi == bj:
                blk = blk + mass
            w[bi * n:(bi + 1) * n, bj * n:(bj + 1) * n] = blk
    lu, piv = lu_factor(w)
    k = np.empty(2 * n)
    k[:n] = acc
    k[n:] = acc
    g = np.empty(2 * n)
    # acceleration scale of the step (rad/s²): the stage accelerations and the rates over the substep
    scale = np.max(np.abs(acc)) + np.max(np.abs(omega)) / h + 1.0
    last = np.inf
    iterations = 0
    converged = False
    for it in range(GAUSS_MAX_ITER):
        iterations = it + 1
        k1 = k[:n]
        k2 = k[n:]
        for i in range(2):
            th_i = theta + (h * coef_c[i]) * omega + (h * h) * (coef_a2[i, 0] * k1 + coef_a2[i, 1] * k2)
            om_i = omega + h * (coef_a[i, 0] * k1 + coef_a[i, 1] * k2)
            m_i, s_i, _, _ = assemble(th_i, om_i, mc, kl)
            g[i * n:(i + 1) * n] = m_i @ k[i * n:(i + 1) * n] - (s_i - dmp @ om_i + u)
        dk = lu_solve(lu, piv, g)
        k = k - dk
        step = np.max(np.abs(dk))
        if not np.isfinite(step):
            break
        if step <= GAUSS_TOL * scale:
            converged = True
            break
        if it >= 2 and step >= 0.5 * last:
            # No longer contracting: the round-off floor of the residual (its spring terms carry an absolute
            # error of about eps · k_bracket), or a step too long for the frozen iteration matrix.
            converged = step <= GAUSS_FLOOR * scale
            break
        last = step
    if not converged:
        raise ValueError("Gauss stage equations did not converge")
    z_new = np.empty(2 * n)
    b1 = 0.5 * (1.0 - coef_c[0])
    b2 = 0.5 * (1.0 - coef_c[1])
    z_new[:n] = theta + h * omega + (h * h) * (b1 * k[:n] + b2 * k[n:])
    z_new[n:] = omega + (0.5 * h) * (k[:n] + k[n:])
    return z_new, iterations


@_jit
def advance_gauss(z, tau, dt, substeps, mc, kl, j2p, j2d, dmp, coef_a, coef_a2, coef_c):
    """Advance by dt (s) with constant torque in `substeps` Gauss-Legendre steps; returns (z_new, max iterations)."""
    h = dt / substeps
    most = 0
    for _ in range(substeps):
        z, it = gauss_step(z, tau, h, mc, kl, j2p, j2d, dmp, coef_a, coef_a2, coef_c)
        most = max(most, it)
    return z, most


# The reference: classical explicit RK4 at microsecond steps (ωh <= 0.34 for the 21 kHz bracket mode at
# 2.5 µs, far inside its stability interval |ωh| < 2.83; phase error per period ~ (ωh)^4/120), no Jacobian,
# no iteration: slow (hundreds of derivative evaluations per ms) but independent of the implicit schemes.
@_jit
def advance_rk4(z, tau, dt, steps, mc, kl, j2p, j2d, dmp):
    """Advance by dt (s) with constant torque in `steps` classical RK4 steps; returns z_new (2n,)."""
    n = z.shape[0] // 2
    m = 2 * n
    h = dt / steps
    k1 = np.empty(m)
    k2 = np.empty(m)
    k3 = np.empty(m)
    k4 = np.empty(m)
    u = np.empty(m)
    y = z.copy()
    work_c, work_s, work_m = np.empty(n), np.empty(n), np.empty((n, n))
    for _ in range(steps):
        stage_derivative(y, tau, mc, kl, j2p, j2d, dmp, work_c, work_s, work_m, k1)
        for i in range(m):
            u[i] = y[i] + 0.5 * h * k1[i]
        stage_derivative(u, tau, mc, kl, j2p, j2d, dmp, work_c, work_s, work_m, k2)
        for i in range(m):
            u[i] = y[i] + 0.5 * h * k2[i]
        stage_derivative(u, tau, mc, kl, j2p, j2d, dmp, work_c, work_s, work_m, k3)
        for i in range(m):
            u[i] = y[i] + h * k3[i]
        stage_derivative(u, tau, mc, kl, j2p, j2d, dmp, work_c, work_s, work_m, k4)
        for i in range(m):
            y[i] = y[i] + (h / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    return y


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
