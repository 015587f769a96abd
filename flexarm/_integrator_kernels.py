"""The time steppers of the chain as Numba kernels: RODAS4, exponential Rosenbrock-Euler, 2-stage Gauss, RK4.

Each advances the state z = (θ, θ̇) over one communication step with the equations of motion of
:mod:`flexarm._dynamics_kernels` (same arguments; Numba when installed, else plain NumPy with identical
mathematics). :mod:`flexarm._kernels` gathers both modules.
"""

from __future__ import annotations

import numpy as np

from ._dynamics_kernels import (
    HAVE_NUMBA,
    _jit,
    assemble,
    input_forces,
    lu_factor,
    lu_solve,
    spd_solve,
    spd_solve_columns,
    stage_derivative,
    tangent_matrices,
)

if HAVE_NUMBA:
    from ._dynamics_kernels import _lu_solve_into


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


#: RODAS4 error control (issue 26 W1): a substep whose embedded error estimate exceeds this on any element angle
#: (rad) is redone at half the length, and the rest of the communication step keeps the shorter length. A coarse
#: zero-order hold (table2 at 4 ms) drives the 190 Hz mode hard enough for the 0.5 ms substep's phase error on it to
#: show (8.7 % rms rates against 64 substeps per ms before; docs/model.md); the 1 ms loops mostly stay below it
#: (about 6 % more substeps on table2/none). The angles only: the L-stable scheme damps the kHz bracket modes at
#: any unresolved substep length, which keeps the rate components of the estimate high until they are resolved.
RODAS4_ANGLE_TOL = 3e-8
#: At most this many halvings of the nominal substep (2 per ms: down to 64 per ms).
RODAS4_MAX_HALVINGS = 5


@_jit
def advance(z, tau, dt, substeps, mc, kl, j2p, j2d, dmp, coef_a, coef_c, gamma, angle_tol, max_halvings):
    """Advance by dt (s) with constant torque in RODAS4 substeps of nominal length dt/substeps, error-controlled.

    A substep whose embedded estimate exceeds `angle_tol` (rad) on an angle is rejected and retried at half the
    length, at most `max_halvings` times (angle_tol <= 0: no control); the rest of the step keeps the shorter
    length, and the next call starts at the nominal one again: the result depends on (z, tau, dt) only. (Restarting
    every nominal substep at full length instead, so that a 4 ms step would equal four 1 ms steps even where it
    refines, measured 1.15 % rms rates against 64 substeps per ms on table2/none at 4 ms, over the 1 % asked.)

    Returns (z_new, max_abs_error_estimate of the accepted substeps, substeps taken including rejected ones)."""
    n = z.shape[0] // 2
    total = substeps << max_halvings  # the step in units of the shortest allowed substep
    pos = 0
    level = 0
    err = 0.0
    taken = 0
    while pos < total:
        h = dt / (substeps << level)
        z_try, e = rodas4_step(z, tau, h, mc, kl, j2p, j2d, dmp, coef_a, coef_c, gamma)
        taken += 1
        if angle_tol > 0.0 and level < max_halvings and np.max(np.abs(e[:n])) > angle_tol:
            level += 1
            continue
        z = z_try
        err = max(err, np.max(np.abs(e)))
        pos += 1 << (max_halvings - level)
    return z, err, taken


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
