"""LQR gain schedules along the minimum-time trajectory (paper sections 4-6, eq. 32).

At each operating time t_k the model is linearised about the desired state
z̄ = z_d(t_k) (eqs. 11-14; by default with τ̄ = 0 as in the paper), and the
algebraic Riccati equation (eq. 17) is solved for

* ``gamma1``, ``gamma0.1``, ``gamma0``: Q = diag(10·I11, γ·I11) (eq. 20),
* ``eq32``: the experimental Q = diag(10·I11, 80, 0.8·I5, 4, 0.8·I4) (eq. 32),

all with R = 10·I2 (eq. 19). The same weights also give a discrete-time
design on the 1 ms zero-order-hold model (gain sets ``dlqr-<name>``;
``dlqr`` alone means ``dlqr-gamma0.1``), the paper's "future work".

Schedules: ``200ms`` (t = 0, 0.2, ..., 11 sets for the 2.058 s slew, the
paper's tables), ``20ms`` (every 20 ms) and ``single`` (one set at mid-slew:
the operating point nearest, on average, to every point of the slew; the
paper's experiment used one set without saying where).

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

import argparse
import datetime as _dt
import hashlib
import importlib.metadata
import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy
import scipy.linalg

from .model import N_STATE, ArmModel, N
from .parameters import DATA_DIR, load_parameters

#: Directory of the committed gain-schedule files.
DEFAULT_GAIN_DIR = DATA_DIR / "gains"
#: Sample time of the controller and plant step, s.
DEFAULT_DT = 1e-3
#: Input weight of eq. 19.
R_PAPER = 10.0 * np.eye(2)
#: State indices of the two velocities the tachometers provide (θ̇1, θ̇7).
MEASURED_VELOCITY_STATES = (N + 0, N + 6)
#: Base names of the state weights; discrete designs are named ``dlqr-<base>``.
WEIGHT_NAMES = ("gamma1", "gamma0.1", "gamma0", "eq32")
#: Every gain-set name written by the CLI.
GAIN_SET_NAMES = WEIGHT_NAMES + tuple(f"dlqr-{w}" for w in WEIGHT_NAMES)
#: Schedule labels and their spacing in s (None: one set at mid-slew).
SCHEDULES = {"200ms": 0.2, "20ms": 0.02, "single": None}
#: Linearisation forms: the paper's τ̄ = 0 (eq. 11) or about the feedforward torque.
LINEARIZATIONS = ("paper", "feedforward")
#: How the θ̇7 error is formed from the tachometers (see :mod:`flexarm.control`).
OMEGA7_CHOICES = ("tachometer", "rigid")
#: Lower bound on the frequency used to scale modal positions, rad/s (rigid modes get 1).
OMEGA_FLOOR = 1.0
FILE_FORMAT = "flexarm-gain-schedule/1"


class GainError(ValueError):
    """A gain-set name, schedule or gain file is invalid."""


# -- weights -------------------------------------------------------------------
def state_weight(name: str) -> np.ndarray:
    """State weight Q (22×22) of a named design.

    Parameters
    ----------
    name : str
        ``gamma1``, ``gamma0.1``, ``gamma0`` (eq. 20, Q = diag(10·I11, γ·I11)),
        ``eq32`` (eq. 32), or any ``gamma<float>`` with 0 ≤ γ ≤ 100;
        a ``dlqr-`` prefix is ignored.

    Returns
    -------
    ndarray, shape (22, 22)
    """
    base = name.removeprefix("dlqr-")
    if base == "eq32":
        vel = np.full(N, 0.8)
        vel[0] = 80.0  # θ̇1: most of the observed overshoot was in link 1
        vel[6] = 4.0  # θ̇7
        return np.diag(np.r_[np.full(N, 10.0), vel])
    if base.startswith("gamma"):
        try:
            gamma = float(base[5:])
        except ValueError:
            gamma = float("nan")
        if np.isfinite(gamma) and 0.0 <= gamma <= 100.0:
            return np.diag(np.r_[np.full(N, 10.0), np.full(N, gamma)])
    raise GainError(f"gain set name: {name!r} is not one of {GAIN_SET_NAMES + ('dlqr',)} "
                    "(or gamma<γ> with 0 <= γ <= 100)")


def canonical_name(name: str) -> str:
    """Resolve the alias ``dlqr`` (= ``dlqr-gamma0.1``) and check the name."""
    name = "dlqr-gamma0.1" if name == "dlqr" else name
    state_weight(name)
    return name


def is_discrete(name: str) -> bool:
    """True for discrete-time (``dlqr-``) designs."""
    return canonical_name(name).startswith("dlqr-")


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


def zoh(A, B, dt: float = DEFAULT_DT) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation Φ = e^{A dt}, Γ = ∫₀^dt e^{As} ds B (augmented expm).

    Call it on well-scaled matrices (e.g. Ã, B̃ of :func:`scaling_transform`).
    """
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    n, m = B.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = A * dt
    aug[:n, n:] = B * dt
    e = scipy.linalg.expm(aug)
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


# -- trajectory access -----------------------------------------------------------------
@dataclass
class TrajectoryData:
    """The desired trajectory as plain arrays (1 ms samples).

    Attributes
    ----------
    t : ndarray, shape (n,)
        Sample times, s, t[0] = 0, uniform spacing ``dt``.
    tau : ndarray, shape (n, 2)
        Feedforward torque held over [t_k, t_k+1), N·m.
    z : ndarray, shape (n, 22)
        Desired state (θ rad, θ̇ rad/s).
    path : str
        File it came from ('' when built in memory).
    sha256 : str
        SHA-256 of that file ('' when built in memory).
    """

    t: np.ndarray
    tau: np.ndarray
    z: np.ndarray
    path: str = ""
    sha256: str = ""

    def __post_init__(self):
        self.t = np.asarray(self.t, dtype=float)
        self.tau = np.asarray(self.tau, dtype=float)
        self.z = np.asarray(self.z, dtype=float)
        n = len(self.t)
        if self.t.ndim != 1 or n < 2:
            raise GainError(f"trajectory t: expected a 1-D array of >= 2 times, got shape {self.t.shape}")
        if self.tau.shape != (n, 2):
            raise GainError(f"trajectory tau: expected shape ({n}, 2), got {self.tau.shape}")
        if self.z.shape != (n, N_STATE):
            raise GainError(f"trajectory z: expected shape ({n}, {N_STATE}), got {self.z.shape}")
        steps = np.diff(self.t)
        if abs(self.t[0]) > 1e-12 or np.ptp(steps) > 1e-9 or steps[0] <= 0:
            raise GainError("trajectory t: must start at 0 with a uniform positive spacing")
        for name in ("t", "tau", "z"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise GainError(f"trajectory {name}: contains non-finite values")

    @property
    def dt(self) -> float:
        """Sample spacing, s."""
        return float(self.t[1] - self.t[0])

    @property
    def duration(self) -> float:
        """Slew time t[-1], s."""
        return float(self.t[-1])

    @property
    def n_steps(self) -> int:
        """Number of control steps of the slew (samples − 1)."""
        return len(self.t) - 1


def as_trajectory_data(traj) -> TrajectoryData:
    """Convert a trajectory object, mapping or path to :class:`TrajectoryData`.

    Accepts a :class:`TrajectoryData`; a path to an ``.npz`` file (loaded with
    :func:`flexarm.trajectory.load_trajectory` when that module exists); or
    any object or mapping with fields ``t``, ``tau1``, ``tau2``,
    ``theta1..theta11``, ``omega1..omega11`` (or ``tau`` (n, 2), ``theta``
    (n, 11), ``omega`` (n, 11), or ``z`` (n, 22)).
    """
    if isinstance(traj, TrajectoryData):
        return traj
    path, sha = "", ""
    if isinstance(traj, (str, os.PathLike)):
        path = str(traj)
        sha = file_sha256(path)
        traj = _load_trajectory_file(path)
    get = (lambda k: traj[k] if k in traj else None) if hasattr(traj, "keys") else \
        (lambda k: getattr(traj, k, None))
    path = path or str(get("path") or get("source") or "")
    sha = sha or str(get("sha256") or "")
    t = get("t")
    if t is None:
        raise GainError("trajectory: no field 't' (sample times, s)")
    if get("tau") is not None:
        tau = np.asarray(get("tau"), dtype=float)
    elif get("tau1") is not None and get("tau2") is not None:
        tau = np.column_stack([get("tau1"), get("tau2")])
    else:
        raise GainError("trajectory: needs 'tau' (n, 2) or 'tau1' and 'tau2' (N·m)")
    if get("z") is not None:
        z = np.asarray(get("z"), dtype=float)
    else:
        theta = _stack(get, "theta")
        omega = _stack(get, "omega")
        z = np.hstack([theta, omega])
    return TrajectoryData(np.asarray(t, dtype=float), tau, z, path, sha)


def _stack(get, prefix: str) -> np.ndarray:
    whole = get(prefix)
    if whole is not None and np.ndim(whole) == 2:
        return np.asarray(whole, dtype=float)
    cols = [get(f"{prefix}{i}") for i in range(1, N + 1)]
    if any(c is None for c in cols):
        raise GainError(f"trajectory: needs '{prefix}' (n, 11) or '{prefix}1'..'{prefix}11'")
    return np.column_stack(cols)


def _load_trajectory_file(path: str):
    """Arrays of a trajectory file: via :func:`flexarm.trajectory.load_trajectory` (which
    validates) for files in its format, else the raw npz arrays (e.g. ``t``, ``tau``, ``z``)."""
    with np.load(path, allow_pickle=False) as data:
        raw = {k: data[k] for k in data.files if k != "metadata"}
    if "tau1" in raw:
        try:
            from .trajectory import load_trajectory
        except ImportError:  # the optimiser module (CasADi) is not needed to read the arrays
            return raw
        return load_trajectory(path)
    return raw


def default_trajectory_path() -> Path:
    """The committed minimum-time trajectory, ``flexarm/data/trajectory.npz``."""
    return DATA_DIR / "trajectory.npz"


def file_sha256(path) -> str:
    """SHA-256 hex digest of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


# -- schedules -----------------------------------------------------------------------------
def operating_times(duration: float, schedule: str, dt: float = DEFAULT_DT) -> np.ndarray:
    """Operating times of a schedule, s, on the ``dt`` sample grid.

    ``200ms``/``20ms``: 0, spacing, ... up to the slew time; ``single``: the
    sample nearest mid-slew.
    """
    if schedule not in SCHEDULES:
        raise GainError(f"schedule: {schedule!r} is not one of {tuple(SCHEDULES)}")
    spacing = SCHEDULES[schedule]
    if spacing is None:
        return np.array([round(duration / 2 / dt) * dt])
    n = int(np.floor(duration / spacing + 1e-9)) + 1
    return np.round(np.arange(n) * spacing / dt) * dt


@dataclass
class GainSchedule:
    """Piecewise-constant gains along the trajectory.

    Attributes
    ----------
    name : str
        Gain-set name (e.g. ``gamma0.1``, ``dlqr-gamma0.1``).
    schedule : str
        ``200ms``, ``20ms`` or ``single``.
    times : ndarray, shape (n_sets,)
        Operating times t_k, s; gain k is used on [t_k, t_k+1), the last one
        from t_n-1 on (including the hold after the slew).
    gains : ndarray, shape (n_sets, 2, 22)
        Full-state gains K_k.
    operating_points : ndarray, shape (n_sets, 22)
        Linearisation states z̄_k.
    Q, R : ndarray
        Weights, shapes (22, 22) and (2, 2).
    residuals, rho_full, rho_reduced, rho_implemented, max_real_full, max_real_reduced : ndarray, shape (n_sets,)
        Per-set diagnostics (see :class:`GainDesign`).
    metadata : dict
        Provenance (written to the JSON side file).
    """

    name: str
    schedule: str
    times: np.ndarray
    gains: np.ndarray
    operating_points: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    residuals: np.ndarray
    rho_full: np.ndarray
    rho_reduced: np.ndarray
    rho_implemented: np.ndarray
    max_real_full: np.ndarray
    max_real_reduced: np.ndarray
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        self.times = np.atleast_1d(np.asarray(self.times, dtype=float))
        self.gains = np.asarray(self.gains, dtype=float).reshape(-1, 2, N_STATE)
        if len(self.gains) != len(self.times) or len(self.times) == 0:
            raise GainError(f"gains: expected {len(self.times)} sets of shape (2, 22), got {self.gains.shape}")
        if np.any(np.diff(self.times) <= 0):
            raise GainError("times: operating times must be strictly increasing")
        if not np.all(np.isfinite(self.gains)):
            raise GainError("gains: contain non-finite values")

    @property
    def discrete(self) -> bool:
        """True for a discrete-time (dlqr) design."""
        return self.name.startswith("dlqr-")

    def index_at(self, t: float) -> int:
        """Index of the set in force at time t (s); the first set before t_0."""
        return max(int(np.searchsorted(self.times, t + 1e-9, side="right")) - 1, 0)

    def gain_at(self, t: float, reduced: bool = True) -> np.ndarray:
        """Gain in force at time t (s), shape (2, 22); ``reduced`` zeros the unmeasured velocity columns."""
        K = self.gains[self.index_at(t)]
        return reduce_gain(K) if reduced else K.copy()

    def reduced_gains(self) -> np.ndarray:
        """All sets with the nine unmeasured velocity columns zeroed, shape (n_sets, 2, 22)."""
        return reduce_gain(self.gains)

    # -- files ---------------------------------------------------------------------
    def save(self, directory=None) -> Path:
        """Write ``<name>_<schedule>.npz`` and ``.json`` atomically; returns the npz path."""
        directory = Path(directory) if directory is not None else DEFAULT_GAIN_DIR
        directory.mkdir(parents=True, exist_ok=True)
        stem = directory / f"{self.name}_{self.schedule}"  # names contain dots: no with_suffix
        arrays = dict(times=self.times, gains=self.gains, operating_points=self.operating_points, Q=self.Q,
                      R=self.R, residuals=self.residuals, rho_full=self.rho_full, rho_reduced=self.rho_reduced,
                      rho_implemented=self.rho_implemented, max_real_full=self.max_real_full,
                      max_real_reduced=self.max_real_reduced)
        npz_path = Path(f"{stem}.npz")
        _atomic_write(npz_path, lambda f: np.savez(f, **arrays))
        meta = dict(self.metadata)
        meta.update(format=FILE_FORMAT, name=self.name, schedule=self.schedule,
                    npz_file=npz_path.name, npz_sha256=file_sha256(npz_path))
        text = json.dumps(meta, indent=2, sort_keys=False) + "\n"
        _atomic_write(Path(f"{stem}.json"), lambda f: f.write(text.encode()))
        return npz_path

    @classmethod
    def load(cls, name: str, schedule: str = "200ms", directory=None) -> GainSchedule:
        """Load a committed (or written) gain schedule.

        Parameters
        ----------
        name : str
            Gain-set name (``gamma1``, ``gamma0.1``, ``gamma0``, ``eq32``,
            ``dlqr-*``, alias ``dlqr``).
        schedule : str
            ``200ms``, ``20ms`` or ``single``.
        directory : path-like, optional
            Default ``flexarm/data/gains``.
        """
        name = canonical_name(name)
        if schedule not in SCHEDULES:
            raise GainError(f"schedule: {schedule!r} is not one of {tuple(SCHEDULES)}")
        directory = Path(directory) if directory is not None else DEFAULT_GAIN_DIR
        stem = directory / f"{name}_{schedule}"
        npz_path, json_path = Path(f"{stem}.npz"), Path(f"{stem}.json")
        if not npz_path.exists():
            raise GainError(f"gain file {npz_path} does not exist; run `python -m flexarm.lqr --write`")
        meta = json.loads(json_path.read_text()) if json_path.exists() else {}
        with np.load(npz_path) as d:
            arrays = {k: d[k] for k in d.files}
        return cls(name=name, schedule=schedule, metadata=meta, **arrays)


def _atomic_write(path: Path, writer) -> None:
    """Write through a temporary file in the same directory, then rename over ``path``."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            writer(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _git_commit() -> str:
    """HEAD commit of the source tree (read-only; '+dirty' when files differ)."""
    root = Path(__file__).resolve().parent.parent
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                              check=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, check=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def design_schedule(model: ArmModel, trajectory, name: str, schedule: str = "200ms", R=R_PAPER,
                    linearization: str = "paper") -> GainSchedule:
    """Design a gain schedule along a trajectory.

    Parameters
    ----------
    model : ArmModel
        The controller's model (no payload: the payload is the model error).
    trajectory : TrajectoryData, path or trajectory object
        See :func:`as_trajectory_data`.
    name : str
        Gain-set name (see :func:`state_weight`).
    schedule : str
        ``200ms``, ``20ms`` or ``single``.
    R : array_like, shape (2, 2)
    linearization : str
        ``paper`` (τ̄ = 0, eq. 11) or ``feedforward`` (τ̄ = τ_ff(t_k)).

    Returns
    -------
    GainSchedule
    """
    name = canonical_name(name)
    if linearization not in LINEARIZATIONS:
        raise GainError(f"linearization: {linearization!r} is not one of {LINEARIZATIONS}")
    traj = as_trajectory_data(trajectory)
    Q = state_weight(name)
    R = np.asarray(R, dtype=float)
    times = operating_times(traj.duration, schedule, traj.dt)
    idx = np.round(times / traj.dt).astype(int)
    designs = []
    for k in idx:
        tau_bar = traj.tau[k] if linearization == "feedforward" else (0.0, 0.0)
        designs.append(design_gain(model, traj.z[k], Q, R, tau_bar, discrete=name.startswith("dlqr-"),
                                   dt=traj.dt))
    col = lambda a: np.array([getattr(d, a) for d in designs])  # noqa: E731
    meta = {
        "description": "LQR gains K (tau = tau_ff - K (x - x_d)), eqs. 17-20/32 of the paper",
        "design": "discrete-time dlqr on the ZOH model" if name.startswith("dlqr-") else "continuous-time lqr",
        "solver": "control.dlqr/lqr(method='scipy') in modal frequency-scaled coordinates (flexarm.lqr)",
        "residual_definition": ("||A'P+PA-PGP+Q||_F / (||Q||_F + 2||A'P||_F + ||PGP||_F), G = B R^-1 B', "
                                "original coordinates" if not name.startswith("dlqr-") else
                                "||F'PF-P-W+Q||_F/(||F'PF||_F+||P||_F+||W||_F+||Q||_F), "
                                "W = F'PG(R+G'PG)^-1 G'PF, original coordinates"),
        "linearization": ("paper: A = df/dz at z_d(t_k), tau_bar = 0 (eqs. 11-14)" if linearization == "paper"
                          else "feedforward: A = d(f+g tau_ff)/dz at (z_d(t_k), tau_ff(t_k))"),
        "sample_time_s": traj.dt,
        "operating_times_s": times.tolist(),
        "Q_diagonal": np.diag(Q).tolist(),
        "R": R.tolist(),
        "measured_velocity_states": list(MEASURED_VELOCITY_STATES),
        "trajectory_file": _relative(traj.path),
        "trajectory_sha256": traj.sha256,
        "parameter_file": _relative(model.params.source),
        "parameter_sha256": model.params.sha256,
        "payload_mass_kg": float(model.params.payload_mass),
        "commit": _git_commit(),
        "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "versions": {"python-control": importlib.metadata.version("control"), "scipy": scipy.__version__,
                     "numpy": np.__version__},
        "max_residual": float(col("residual").max()),
        "max_abs_gain": float(np.abs(col("K")).max()),
    }
    return GainSchedule(name=name, schedule=schedule, times=times, gains=col("K"),
                        operating_points=traj.z[idx], Q=Q, R=R, residuals=col("residual"),
                        rho_full=col("rho_full"), rho_reduced=col("rho_reduced"),
                        rho_implemented=col("rho_implemented"),
                        max_real_full=col("max_real_full"), max_real_reduced=col("max_real_reduced"),
                        metadata=meta)


def _relative(path: str) -> str:
    if not path:
        return ""
    p = Path(path).resolve()
    root = Path(__file__).resolve().parent.parent
    try:
        return str(p.relative_to(root))
    except ValueError:
        return str(p)


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


# -- CLI -----------------------------------------------------------------------------------
def _table(schedules: list[GainSchedule]) -> str:
    head = (f"{'gain set':<15}{'sched':>7}{'sets':>5}{'max|K|':>10}{'|K|vel2':>9}{'max|KC|':>9}"
            f"{'max res':>10}{'rho full':>13}{'rho reduced':>13}{'rho impl':>13}{'maxRe full':>11}{'maxRe red':>11}")
    lines = [head, "-" * len(head)]
    for s in schedules:
        mag = gain_magnitudes(s.gains)
        eff = float(np.abs(effective_gain(s.gains)).max())
        lines.append(f"{s.name:<15}{s.schedule:>7}{len(s.times):>5}{mag['overall']:>10.4g}"
                     f"{mag['velocity_measured']:>9.3g}{eff:>9.4g}{s.residuals.max():>10.2e}"
                     f"{s.rho_full.max():>13.8f}{s.rho_reduced.max():>13.8f}{s.rho_implemented.max():>13.8f}"
                     f"{np.max(s.max_real_full):>11.4g}{np.max(s.max_real_reduced):>11.4g}")
    return "\n".join(lines)


def main(argv=None) -> int:
    """Command line: design the gain schedules, print diagnostics, optionally write the files."""
    ap = argparse.ArgumentParser(prog="python -m flexarm.lqr", description=__doc__.split("\n")[0])
    ap.add_argument("--trajectory", default=str(default_trajectory_path()),
                    help="trajectory .npz (default: flexarm/data/trajectory.npz)")
    ap.add_argument("--params", default=None, help="parameter file (default: the committed Sandia arm)")
    ap.add_argument("--sets", nargs="+", default=list(GAIN_SET_NAMES), help="gain-set names")
    ap.add_argument("--schedules", nargs="+", default=list(SCHEDULES), choices=list(SCHEDULES))
    ap.add_argument("--linearization", default="paper", choices=LINEARIZATIONS)
    ap.add_argument("--write", action="store_true", help="write <set>_<schedule>.npz/.json")
    ap.add_argument("--out", default=str(DEFAULT_GAIN_DIR), help="output directory for --write")
    ap.add_argument("--per-set", action="store_true", help="also print each operating point's numbers")
    args = ap.parse_args(argv)
    if not Path(args.trajectory).exists():
        print(f"error: trajectory file {args.trajectory} does not exist", file=sys.stderr)
        return 2
    model = ArmModel(load_parameters(args.params))
    traj = as_trajectory_data(args.trajectory)
    print(f"trajectory {args.trajectory} ({traj.duration:.3f} s, sha256 {traj.sha256[:12]}...), "
          f"linearization={args.linearization}, R = 10 I2")
    done = []
    for name in args.sets:
        for sched in args.schedules:
            s = design_schedule(model, traj, name, sched, linearization=args.linearization)
            done.append(s)
            if args.write:
                s.save(args.out)
            if args.per_set:
                for k, tk in enumerate(s.times):
                    mag = gain_magnitudes(s.gains[k])
                    print(f"  {s.name} {sched} t={tk:6.3f} max|K|={mag['overall']:9.4g} res={s.residuals[k]:.2e} "
                          f"rho_full={s.rho_full[k]:.9f} rho_red={s.rho_reduced[k]:.9f}")
    print(_table(done))
    print("\nmax|K|: full gain; |K|vel2: theta1/theta7 velocity columns; max|KC|: gain on the true state as "
          "implemented (reduced, rigid-bracket reconstruction, tachometers); res: relative Riccati residual "
          "(original coordinates, see module doc); rho: spectral radius of Phi - Gamma K (1 ms ZOH) with the full, "
          "reduced and implemented gain; maxRe: max Re eig(A - BK), continuous, full / reduced gain.")
    if args.write:
        print(f"wrote {len(done)} schedules to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
