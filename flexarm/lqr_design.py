"""LQR design at one operating point (paper eqs. 11-20, 32): Riccati solves and sampled-data diagnostics.

At an operating time t_k the model is linearised about the desired state
z̄ = z_d(t_k) (eqs. 11-14; by default with τ̄ = 0 as in the paper), and the
algebraic Riccati equation (eq. 17) is solved for a named state weight
(:mod:`flexarm.gain_sets`) with R = 10·I2 (eq. 19), in continuous time or on
the 1 ms zero-order-hold model (``dlqr-`` designs, the paper's "future work").
Schedules along the trajectory and their files: :mod:`flexarm.gain_schedule`;
the command line: :mod:`flexarm.lqr`.

Numerics
--------
The bracket springs put eigenvalues near ±1.3e5 i into A while the rigid
modes sit at 0 and the link modes at 8-20 Hz; with angles in rad and rates in
rad/s, ‖A‖ ≈ ω_max² ≈ 2e10. A Schur solver applied to A directly
(``control.lqr``) leaves relative residuals of 1e-10 to 1e-5. We therefore
solve in *modal, frequency-scaled* coordinates x = T x̃ (:func:`scaling_transform`):
the columns of T are the mass-normalised mode shapes V of the undamped
pencil (K_t, M) at the operating angles, with the position part divided by
max(ω_i, 1 rad/s), so each flexible mode becomes a block
[[0, ω], [−ω, 0]] and ‖Ã‖ ≈ ω_max. Then

    Ã = T⁻¹AT,  B̃ = T⁻¹B,  Q̃ = TᵀQT,  (R unchanged)
    P = T⁻ᵀ P̃ T⁻¹,  K = R⁻¹BᵀP = K̃ T⁻¹.

T is exact algebra (any non-singular T gives the same P and K); it only
changes how well the solver's rounding errors are conditioned.

Residual measure (reported, and asserted < 1e-8 by the tests), in the
*original* coordinates, Frobenius norms::

    rel_res(P) = ‖AᵀP + PA − PGP + Q‖ / (‖Q‖ + 2‖AᵀP‖ + ‖PGP‖),  G = BR⁻¹Bᵀ

i.e. the residual relative to the size of the terms that cancel (the usual
backward-error style measure of SLICOT/Benner). For the discrete design the
same idea with ΦᵀPΦ − P − ΦᵀPΓ(R + ΓᵀPΓ)⁻¹ΓᵀPΦ + Q.

Reduced gain: the controller feeds back all 11 angle errors and only the two
tachometer velocities (θ̇1 and θ̇7 columns, state indices 11 and 17); the
other nine velocity columns of K are zeroed (:func:`reduce_gain`).

Sampled-data diagnostics (printed by the CLI): spectral radius of Φ − ΓK
with Φ, Γ the 1 ms zero-order-hold model, for the full gain, the reduced
gain and the gain as implemented (reduced gain times the sensor map C of
:func:`measurement_map`: rigid-bracket reconstruction, tachometers). At the
rest point (q1, q2) = (−0.9, 1.0) rad the largest moduli all belong to the
5.6 kHz bracket mode (aliased to ≈ 387 Hz at 1 kHz): full gain 1.0009 /
1.00024 / 1.00000006 for γ = 1 / 0.1 / 0, reduced 1.0000076 / 0.9999997 /
0.9999997, implemented 1.0020 / 1.0006 / 1.00015 (growth ≤ 2 s⁻¹), while
every link and rigid mode is inside the unit circle and the continuous
implemented loop is stable (max Re ≈ −0.23 / −0.10 / −0.05 s⁻¹, a 0.15 Hz
rigid-body pair). So sampling alone only produces a slow growth of a
micro-radian bracket vibration, which the L-stable plant integrator (and any
real structural damping) removes; it does not explain γ = 1's divergence
under noise, which comes from its large gains acting on the sensor noise.
The discrete designs (``dlqr-*``) put ρ(full) < 1 by construction; their
large entries (10³-10⁴ N·m/rad) sit on the bracket columns, which the
rigid-bracket reconstruction never excites (their implemented gain K·C is
of the same order as the continuous one).

Run ``python -m flexarm.lqr --help`` for the CLI (design, write, diagnostics).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gain_sets import GainError
from .model import N_STATE, ArmModel, N

#: Sample time of the controller and plant step, s.
DEFAULT_DT = 1e-3
#: Input weight of eq. 19.
R_PAPER = 10.0 * np.eye(2)
#: State indices of the two velocities the tachometers provide (θ̇1, θ̇7).
MEASURED_VELOCITY_STATES = (N + 0, N + 6)
#: How the θ̇7 error is formed from the tachometers (see :mod:`flexarm.control`).
OMEGA7_CHOICES = ("tachometer", "rigid")
#: Lower bound on the frequency used to scale modal positions, rad/s (rigid modes get 1).
OMEGA_FLOOR = 1.0


def reduce_gain(K) -> np.ndarray:
    """Zero the nine velocity columns no sensor provides.

    Parameters
    ----------
    K : array_like, shape (..., 2, 22)

    Returns
    -------
    ndarray, same shape, columns 11..21 zero except 11 (θ̇1) and 17 (θ̇7).
    """
    K = np.array(K, dtype=float)
    mask = np.ones(N_STATE, dtype=bool)
    mask[N:] = False
    mask[list(MEASURED_VELOCITY_STATES)] = True
    K[..., ~mask] = 0.0
    return K


def measurement_map(omega7: str = "tachometer") -> np.ndarray:
    """Linear map C from the true state to the controller's state estimate, shape (22, 22).

    x̂ = C x with noiseless sensors (see :mod:`flexarm.control`): angles
    through the encoder/gauge reconstruction of eqs. 21-31 (rigid brackets),
    the θ̇1 entry from tachometer 1, the θ̇7 entry from tachometer 2
    (``"tachometer"``: q̇2 = θ̇7 − θ̇6) or from both (``"rigid"``: q̇1 + q̇2),
    the other nine velocity entries zero. K·C is the gain the implemented
    controller really applies to the true state error.
    """
    from .model import joint_angles, reconstruct_angles, strain_gauge_angles

    if omega7 not in OMEGA7_CHOICES:
        raise GainError(f"omega7: {omega7!r} is not one of {OMEGA7_CHOICES}")
    C = np.zeros((N_STATE, N_STATE))
    for j in range(N):
        e = np.zeros(N)
        e[j] = 1.0
        C[:N, j] = reconstruct_angles(joint_angles(e), strain_gauge_angles(e))
    C[N + 0, N + 0] = 1.0
    C[N + 6, N + 6] = 1.0
    C[N + 6, N + 5] = -1.0
    if omega7 == "rigid":
        C[N + 6, N + 0] += 1.0
    return C


def effective_gain(K, omega7: str = "tachometer") -> np.ndarray:
    """Gain on the true state error as implemented: reduce_gain(K) @ C, shape (..., 2, 22)."""
    return reduce_gain(K) @ measurement_map(omega7)


# -- numerics --------------------------------------------------------------------
def scaling_transform(model: ArmModel, z_bar, omega_floor: float = OMEGA_FLOOR) -> np.ndarray:
    """Modal, frequency-scaled coordinates x = T x̃ for an operating point.

    Parameters
    ----------
    model : ArmModel
    z_bar : array_like, shape (22,)
        Operating point; only its angles are used.
    omega_floor : float
        Smallest frequency (rad/s) used to scale a modal position, so the two
        rigid-body modes (ω ≈ 0) keep unit scale.

    Returns
    -------
    ndarray, shape (22, 22)
        T = blockdiag(V·diag(1/max(ω_i, floor)), V), V the mass-normalised
        eigenvectors of the symmetrised tangent stiffness pencil at the
        operating angles (any non-singular T is exact; this one balances).
    """
    theta = np.asarray(z_bar, dtype=float)[:N]
    mass = model.mass_matrix(theta)
    a_th = model.jacobian(np.r_[theta, np.zeros(N)])[N:, :N]
    k_t = -mass @ a_th
    k_t = 0.5 * (k_t + k_t.T)
    import scipy.linalg  # here, not at import: SciPy's linalg costs a run that only reads gains

    w2, vec = scipy.linalg.eigh(k_t, mass)
    scale = np.maximum(np.sqrt(np.maximum(w2, 0.0)), omega_floor)
    T = np.zeros((N_STATE, N_STATE))
    T[:N, :N] = vec / scale
    T[N:, N:] = vec
    return T


def riccati_residual(A, B, Q, R, P) -> float:
    """Relative residual of the continuous ARE (eq. 17), see module docstring.

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, m)
    Q : array_like, shape (n, n)
    R : array_like, shape (m, m)
    P : array_like, shape (n, n)

    Returns
    -------
    float
        ‖AᵀP + PA − PGP + Q‖_F / (‖Q‖_F + 2‖AᵀP‖_F + ‖PGP‖_F), G = BR⁻¹Bᵀ.
    """
    A, B, Q, R, P = (np.asarray(x, dtype=float) for x in (A, B, Q, R, P))
    atp = A.T @ P
    pgp = P @ B @ np.linalg.solve(R, B.T @ P)
    res = atp + atp.T - pgp + Q
    return float(np.linalg.norm(res) / (np.linalg.norm(Q) + 2 * np.linalg.norm(atp) + np.linalg.norm(pgp)))


def discrete_riccati_residual(Phi, Gamma, Q, R, P) -> float:
    """Relative residual of the discrete ARE.

    Returns
    -------
    float
        ‖ΦᵀPΦ − P − W + Q‖_F / (‖ΦᵀPΦ‖_F + ‖P‖_F + ‖W‖_F + ‖Q‖_F),
        W = ΦᵀPΓ(R + ΓᵀPΓ)⁻¹ΓᵀPΦ.
    """
    Phi, Gamma, Q, R, P = (np.asarray(x, dtype=float) for x in (Phi, Gamma, Q, R, P))
    ppp = Phi.T @ P @ Phi
    pg = Phi.T @ P @ Gamma
    w = pg @ np.linalg.solve(R + Gamma.T @ P @ Gamma, pg.T)
    res = ppp - P - w + Q
    den = np.linalg.norm(ppp) + np.linalg.norm(P) + np.linalg.norm(w) + np.linalg.norm(Q)
    return float(np.linalg.norm(res) / den)


def zoh(A, B, dt: float = DEFAULT_DT, expm=None) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation Φ = e^{A dt}, Γ = ∫₀^dt e^{As} ds B (augmented expm).

    Call it on well-scaled matrices (e.g. Ã, B̃ of :func:`scaling_transform`). ``expm`` is the matrix
    exponential to use (default :func:`scipy.linalg.expm`; the kernels' Padé one spares a SciPy import).
    """
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    n, m = B.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = A * dt
    aug[:n, n:] = B * dt
    if expm is None:
        import scipy.linalg

        expm = scipy.linalg.expm
    e = expm(aug)
    return e[:n, :n], e[:n, n:]


@dataclass
class GainDesign:
    """One LQR design at one operating point, with its diagnostics.

    Attributes
    ----------
    K : ndarray, shape (2, 22)
        Full-state gain, τ = −K x (N·m per rad, N·m per rad/s).
    P : ndarray, shape (22, 22)
        Riccati solution in the original coordinates.
    residual : float
        Relative Riccati residual in the original coordinates (module docstring).
    residual_scaled : float
        Same measure in the scaled coordinates the solver worked in.
    max_real_full, max_real_reduced : float
        max Re eig(A − BK) with the full and the reduced gain, 1/s
        (for a discrete design: of the ZOH-equivalent continuous loop, not defined; NaN).
    rho_full, rho_reduced : float
        Spectral radius of Φ − ΓK (1 ms ZOH) with the full / reduced gain.
    rho_implemented : float
        Same with the gain as implemented, reduce_gain(K)·C (:func:`effective_gain`,
        ``omega7="tachometer"``): rigid-bracket angle reconstruction and
        tachometer velocities.
    """

    K: np.ndarray
    P: np.ndarray
    residual: float
    residual_scaled: float
    max_real_full: float
    max_real_reduced: float
    rho_full: float
    rho_reduced: float
    rho_implemented: float


def design_gain(model: ArmModel, z_bar, Q, R=R_PAPER, tau_bar=(0.0, 0.0), discrete: bool = False,
                dt: float = DEFAULT_DT) -> GainDesign:
    """LQR gain at one operating point.

    Parameters
    ----------
    model : ArmModel
    z_bar : array_like, shape (22,)
        Operating point (rad, rad/s).
    Q : array_like, shape (22, 22)
        State weight (symmetric, positive semidefinite).
    R : array_like, shape (2, 2)
        Input weight (symmetric, positive definite).
    tau_bar : array_like, shape (2,)
        Torque of the linearisation, N·m; (0, 0) is the paper's form.
    discrete : bool
        Design on the ``dt`` zero-order-hold model (``control.dlqr``) instead
        of the continuous model (``control.lqr``).
    dt : float
        Sample time, s (discrete design and the ZOH diagnostics).

    Returns
    -------
    GainDesign
    """
    Q = np.asarray(Q, dtype=float)
    R = np.asarray(R, dtype=float)
    if Q.shape != (N_STATE, N_STATE) or not np.allclose(Q, Q.T) or np.linalg.eigvalsh(Q).min() < -1e-12:
        raise GainError(f"Q: must be a symmetric positive semidefinite {N_STATE}x{N_STATE} matrix")
    if R.shape != (2, 2) or not np.allclose(R, R.T) or np.linalg.eigvalsh(R).min() <= 0:
        raise GainError("R: must be a symmetric positive definite 2x2 matrix")
    if not (np.isfinite(dt) and 0 < dt <= 0.1):
        raise GainError(f"dt: must be in (0, 0.1] s, got {dt!r}")
    A, B = model.linearize(z_bar, tau_bar)
    T = scaling_transform(model, z_bar)
    Ti = np.linalg.inv(T)
    At, Bt = Ti @ A @ T, Ti @ B
    Qt = T.T @ Q @ T
    Qt = 0.5 * (Qt + Qt.T)
    Phit, Gamt = zoh(At, Bt, dt)
    # python-control only for the design: the controller FMUs load gain files
    # through this module and must run with NumPy/SciPy alone.
    import control

    if discrete:
        Kt, Pt, _ = control.dlqr(Phit, Gamt, Qt, R, method="scipy")
        res_scaled = discrete_riccati_residual(Phit, Gamt, Qt, R, Pt)
    else:
        Kt, Pt, _ = control.lqr(At, Bt, Qt, R, method="scipy")
        res_scaled = riccati_residual(At, Bt, Qt, R, Pt)
    Kt, Pt = np.asarray(Kt), np.asarray(Pt)
    P = Ti.T @ Pt @ Ti
    P = 0.5 * (P + P.T)
    K = Kt @ Ti
    if not discrete:
        P, K, Pt = _newton_refine(A, B, Q, R, At, Bt, Qt, Ti, P, K, Pt)
        res_scaled = riccati_residual(At, Bt, Qt, R, Pt)
    if discrete:
        Phi, Gam = T @ Phit @ Ti, T @ Gamt
        residual = discrete_riccati_residual(Phi, Gam, Q, R, P)
        max_full = max_red = float("nan")
    else:
        residual = riccati_residual(A, B, Q, R, P)
        max_full = float(np.linalg.eigvals(A - B @ K).real.max())
        max_red = float(np.linalg.eigvals(A - B @ reduce_gain(K)).real.max())
    # Eigenvalues are similarity invariant: evaluate Φ − ΓK in the scaled coordinates.
    rho_full = float(np.abs(np.linalg.eigvals(Phit - Gamt @ (K @ T))).max())
    rho_red = float(np.abs(np.linalg.eigvals(Phit - Gamt @ (reduce_gain(K) @ T))).max())
    rho_impl = float(np.abs(np.linalg.eigvals(Phit - Gamt @ (effective_gain(K) @ T))).max())
    return GainDesign(K, P, residual, res_scaled, max_full, max_red, rho_full, rho_red, rho_impl)


def _newton_refine(A, B, Q, R, At, Bt, Qt, Ti, P, K, Pt, iterations: int = 2):
    """Kleinman-Newton steps on the Schur solution, in the scaled coordinates.

    The nearly undamped modes of γ = 0 leave the Schur solution a few 1e-9
    from the exact one; a Newton step (a Lyapunov solve with the closed loop)
    restores full accuracy. A step is kept only if it lowers the residual in
    the original coordinates.
    """
    import scipy.linalg

    best = riccati_residual(A, B, Q, R, P)
    for _ in range(iterations):
        Kt = np.linalg.solve(R, Bt.T @ Pt)
        acl = At - Bt @ Kt
        Xt = scipy.linalg.solve_continuous_lyapunov(acl.T, -(Qt + Kt.T @ R @ Kt))
        Xt = 0.5 * (Xt + Xt.T)
        X = Ti.T @ Xt @ Ti
        X = 0.5 * (X + X.T)
        res = riccati_residual(A, B, Q, R, X)
        if not res < best:
            break
        best, Pt, P = res, Xt, X
        K = np.linalg.solve(R, B.T @ P)
    return P, K, Pt



def discretize(model: ArmModel, z_bar, tau_bar=(0.0, 0.0), dt: float = DEFAULT_DT):
    """Zero-order-hold model of the linearisation at one operating point, computed in balanced coordinates.

    Parameters
    ----------
    model : ArmModel
    z_bar : array_like, shape (22,)
        Operating point (rad, rad/s).
    tau_bar : array_like, shape (2,)
        Torque of the linearisation, N·m.
    dt : float
        Sample time, s.

    Returns
    -------
    Phi : ndarray, shape (22, 22)
    Gamma : ndarray, shape (22, 2)
        x_{k+1} = Φ x_k + Γ u_k for deviations from the operating point.
    T : ndarray, shape (22, 22)
        The balancing transform of :func:`scaling_transform` (x = T x̃).
    """
    A, B = model.linearize(z_bar, tau_bar)
    T = scaling_transform(model, z_bar)
    Ti = np.linalg.inv(T)
    Phit, Gamt = zoh(Ti @ A @ T, Ti @ B, dt)
    return T @ Phit @ Ti, T @ Gamt, T


def gain_magnitudes(K) -> dict[str, float]:
    """Largest |gain| on angle errors and on the two measured velocity errors.

    Parameters
    ----------
    K : array_like, shape (..., 2, 22)

    Returns
    -------
    dict
        ``position`` (N·m/rad), ``velocity_measured`` (N·m·s/rad, θ̇1 and θ̇7
        columns), ``velocity_all`` (all 11 velocity columns), ``overall``.
    """
    K = np.abs(np.asarray(K, dtype=float))
    return {"position": float(K[..., :N].max()),
            "velocity_measured": float(K[..., list(MEASURED_VELOCITY_STATES)].max()),
            "velocity_all": float(K[..., N:].max()),
            "overall": float(K.max())}

