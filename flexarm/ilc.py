"""Iterative learning control (ILC) of the slew: norm-optimal learning of a feedforward correction, no FMI.

A robot that repeats the same slew can learn the torque its model gets wrong (the paper's closing
remark). After trial j the measured tracking errors e_j correct the feedforward for trial j + 1::

    u_(j+1) = Q( u_j + L e_j ),   then clipped so that τ_ff + u stays within the motors' peak torques

* u (shape (N, 2), N·m): the correction added to the trajectory's feedforward torques, sample k held
  over [k·dt, (k+1)·dt) (:class:`flexarm.control.TrackingController`, ``feedforward_correction``).
* e_j (shape (N, 11), rad): the *measured* tracking error at samples k = 1..N, formed as the controller
  forms its own: the 11 angles reconstructed from the encoders and strain gauges (eqs. 21-31) minus the
  same map of the desired state (:func:`measured_errors`). Noisy, 1 ms samples; never the true states.
* L: the norm-optimal update of Amann, Owens and Rogers (1996) on the lifted model G of the closed loop
  (below): Δu = L e = argmin_Δu ‖e − G Δu‖²_Qe + ‖Δu‖²_Ru, i.e. L = (GᵀQeG + Ru)⁻¹GᵀQe, with
  Qe = ``error_weight``·I11 (rad⁻²) and Ru = ``input_weight``·I2 ((N·m)⁻²). On the exact model the error
  then falls monotonically: ‖e_(j+1)‖_Qe ≤ ‖e_j‖_Qe. The ratio input/error weight sets how fast it learns
  (and how much of the measurement noise it lets in); :data:`ERROR_WEIGHT` and :data:`INPUT_WEIGHT`.
* Q: a zero-phase low-pass (Butterworth of order :data:`Q_FILTER_ORDER`, cut-off
  :data:`Q_FILTER_CUTOFF_HZ`, applied forwards and backwards: ``scipy.signal.filtfilt``, odd padding).
  It keeps the learning out of the link modes above the cut-off, where the lifted model is least
  accurate (payload, nonlinearity) and where the sensors' noise would be learnt. Its price: the error
  converges to the part of the error that needs torque above the cut-off, not to zero.

The lifted model
----------------
The closed loop of feedforward + the γ = 0.1 scheduled LQR, linearised along the trajectory: at each
sample k the zero-order-hold model (Φ_k, Γ_k) of the arm linearised about (z_d, τ_ff) at the operating
point in force (every 20 ms, eqs. 11-14, :func:`flexarm.lqr_design.discretize`; the arm with the payload
the robot is known to carry, ``payload_mass``, see :func:`closed_loop_model`), closed by the
controller's gain as implemented (:func:`flexarm.lqr_design.effective_gain`: reduced gain times the
sensor map; saturation ignored)::

    δx_(k+1) = (Φ_k − Γ_k K_k C) δx_k + Γ_k Δu_k,    δy_k = E δx_k   (E: the 11 reconstructed angles)

G maps Δu_0..Δu_(N−1) to δy_1..δy_N. Dense, G would be 11N × 2N: for N = 3058 (the slew and 1 s
after it) 33 638 × 6 116 doubles = 1.6 GB, and GᵀG alone ≈ 2.5e11 flops per design. So L e is
computed without G: the update is a finite-horizon LQ tracking problem on the LTV model, solved by
a backward Riccati sweep (gains computed once per design: N steps of 22 × 22 products, well under a
second) and, per trial, one backward adjoint sweep and one forward sweep (O(N·22²)). The dense form is
kept for small horizons (:meth:`NormOptimalIlc.dense_operator`), where the tests check that both agree
and that the learning operator Q(I − LG) has spectral radius < 1.

Design files
------------
:func:`write_learned_feedforward` writes the learned correction as a design-file pair
(``<stem>.npz`` + ``.json``, :func:`flexarm.gain_schedule.write_design_files`) with its provenance:
the trajectory and parameter files with their SHA-256, the gain set and schedule, the ILC weights and
Q-filter, the trials it came from (scenario, payload, seeds, per-trial errors). A controller FMU applies
such a file when it ships in its resources as :data:`LEARNED_RESOURCE` (with the ``.json`` beside it; packed by
``fmu_build.learned.with_learned_feedforward``): the correction travels with the FMU, and no tool needs to set
a String. :func:`read_learned_feedforward` reads it and checks the data chain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.signal

from .gain_schedule import (
    GainSchedule,
    as_trajectory,
    desired_states,
    sample_time,
    schedule_index,
)
from .ilc_trial import desired_angles as desired_angles  # re-exported: a trial's measurements and loop
from .ilc_trial import feedforward_over as feedforward_over
from .ilc_trial import measured_angles as measured_angles
from .ilc_trial import measured_errors as measured_errors
from .ilc_trial import simulate_trial as simulate_trial
from .learned_feedforward import (  # noqa: F401 - the design files, re-exported: flexarm.ilc documents them
    FILE_FORMAT,
    LEARNED_RESOURCE,
    RELEARN_COMMAND,
    IlcError,
    LearnedFeedforward,
    read_learned_feedforward,
    write_learned_feedforward,
)
from .lqr_design import effective_gain, measurement_map
from .model import N_STATE, N

#: Error weight Qe = ERROR_WEIGHT · I11 on the 11 reconstructed angle errors, rad⁻².
ERROR_WEIGHT = 1.0
#: Input weight Ru = INPUT_WEIGHT · I2 on the correction's change per trial, (N·m)⁻².
INPUT_WEIGHT = 1e-6
#: Q-filter: Butterworth order (applied forwards and backwards: twice this order, zero phase).
Q_FILTER_ORDER = 2
#: Q-filter cut-off, Hz (the −3 dB point of one pass; the link modes start at about 8 Hz).
Q_FILTER_CUTOFF_HZ = 25.0
#: Spacing of the linearisation points of the lifted model (:data:`flexarm.gain_schedule.SCHEDULES`).
MODEL_SCHEDULE = "20ms"
#: Modes above this frequency are left out of the lifted model (the bracket modes), Hz.
MODE_CUTOFF_HZ = 1000.0


@dataclass
class LtvModel:
    """The closed loop linearised along the trajectory, one model per 1 ms sample.

    Attributes
    ----------
    A : ndarray, shape (N, 22, 22)
        Closed-loop transition Φ_k − Γ_k K_k C of sample k.
    B : ndarray, shape (N, 22, 2)
        Input matrix Γ_k of the correction Δu_k (N·m).
    C : ndarray, shape (11, 22)
        Output map: the 11 reconstructed angles (rad) of the state deviation.
    dt : float
        Sample time, s.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    dt: float

    @property
    def n_samples(self) -> int:
        return len(self.A)

    def simulate(self, du) -> np.ndarray:
        """Outputs δy_1..δy_N, shape (N, 11), of an input sequence Δu_0..Δu_(N−1), shape (N, 2), from δx_0 = 0."""
        du = np.asarray(du, dtype=float)
        x = np.zeros(N_STATE)
        y = np.empty((self.n_samples, len(self.C)))
        for k in range(self.n_samples):
            x = self.A[k] @ x + self.B[k] @ du[k]
            y[k] = self.C @ x
        return y


def closed_loop_model(n_samples: int, gain_set: str = "gamma0.1", schedule: str = "200ms",
                      payload_mass: float = 0.0, model_schedule: str = MODEL_SCHEDULE, trajectory=None,
                      gains=None) -> LtvModel:
    """The lifted model's per-sample matrices (module docstring).

    Parameters
    ----------
    n_samples : int
        Horizon N in 1 ms samples (may extend past the slew: the last operating point holds).
    gain_set, schedule : str
        The controller's gain schedule (:meth:`flexarm.gain_schedule.GainSchedule.load`).
    payload_mass : float
        Tip payload of the arm the model is linearised for, kg (the learning's model; the controller's gains
        stay those of the unloaded arm).
    model_schedule : str
        Spacing of the linearisation points (:data:`flexarm.gain_schedule.SCHEDULES`; ``20ms``: every 20 ms).
    trajectory : TrajectoryResult or path-like, optional
        Default the committed trajectory.
    gains : GainSchedule, optional
        The controller's schedule when it is not the committed `gain_set`/`schedule` (gains designed along a
        re-planned slew, :mod:`flexarm.payload_data`).
    """
    from .gain_schedule import operating_times
    from .model import ArmModel
    from .parameters import load_parameters
    from .trajectory.io import DEFAULT_TRAJECTORY_FILE

    n_samples = int(n_samples)
    if n_samples < 1:
        raise IlcError(f"n_samples: at least 1 sample, got {n_samples}")
    traj = as_trajectory(DEFAULT_TRAJECTORY_FILE if trajectory is None else trajectory)
    dt = sample_time(traj)
    gains = GainSchedule.load(gain_set, schedule) if gains is None else gains
    arm = ArmModel(load_parameters(payload_mass=payload_mass))
    times = operating_times(traj.t_f, model_schedule, dt)
    z = desired_states(traj)
    idx = np.round(times / dt).astype(int)
    models = [truncated_physical_model(arm, z[k], traj.tau[k], dt) for k in idx]
    k_eff = effective_gain(gains.gains)  # (n_sets, 2, 22) on the true state
    t = np.arange(n_samples) * dt
    gi = np.array([gains.index_at(tk) for tk in t])
    mi = np.array([schedule_index(times, tk) for tk in t])
    closed = np.array([[phi - gam @ k for k in k_eff] for phi, gam in models])
    gamma = np.array([gam for _, gam in models])
    return LtvModel(A=closed[mi, gi], B=gamma[mi], C=measurement_map()[:N].copy(), dt=dt)


def spliced_model(before: LtvModel, after: LtvModel, k0: int) -> LtvModel:
    """The LTV model whose samples k < k0 are `before`'s and k ≥ k0 `after`'s (same state coordinates, sample time
    and horizon): e.g. the unloaded arm's closed loop during the slew and the payload's after it."""
    if before.A.shape != after.A.shape or before.dt != after.dt or not np.array_equal(before.C, after.C):
        raise IlcError("spliced_model: the two models need the same horizon, sample time and output map")
    k0 = int(min(max(k0, 0), before.n_samples))
    return LtvModel(A=np.concatenate([before.A[:k0], after.A[k0:]]), B=np.concatenate([before.B[:k0], after.B[k0:]]),
                    C=before.C.copy(), dt=before.dt)


def truncated_physical_model(arm, z_bar, tau_bar, dt: float, cutoff_hz: float = MODE_CUTOFF_HZ):
    """ZOH model (Φ, Γ), shapes (22, 22), (22, 2), of the linearisation with the modes above ``cutoff_hz``
    removed (the bracket modes, 5.6-21 kHz: above the sampling rate, and damped by the plant's L-stable
    integrator, so an exact ZOH model of them mispredicts the plant), in physical coordinates.

    In the modal coordinates of :func:`flexarm.lqr_design.scaling_transform` (x = T x̃) the kept modes are
    sampled exactly (:func:`flexarm.lqr_design.zoh`) and mapped back: Φ = T_r Φ̃_r T⁻¹_r, Γ = T_r Γ̃_r (the
    removed modes' coordinates are projected out). Physical coordinates keep consecutive operating points,
    whose modal bases differ, consistent.
    """
    import scipy.linalg

    from .lqr_design import scaling_transform, zoh

    A, B = arm.linearize(z_bar, tau_bar)
    T = scaling_transform(arm, z_bar)
    Ti = np.linalg.inv(T)
    theta = np.asarray(z_bar, dtype=float)[:N]
    mass = arm.mass_matrix(theta)
    k_t = -mass @ arm.jacobian(np.r_[theta, np.zeros(N)])[N:, :N]
    w2 = scipy.linalg.eigh(0.5 * (k_t + k_t.T), mass, eigvals_only=True)
    modes = np.flatnonzero(np.sqrt(np.maximum(w2, 0.0)) < 2 * np.pi * cutoff_hz)
    keep = np.r_[modes, N + modes]
    phi_r, gam_r = zoh((Ti @ A @ T)[np.ix_(keep, keep)], (Ti @ B)[keep], dt)
    return T[:, keep] @ phi_r @ Ti[keep], T[:, keep] @ gam_r


def q_filter(u, dt: float, cutoff_hz: float = Q_FILTER_CUTOFF_HZ, order: int = Q_FILTER_ORDER) -> np.ndarray:
    """Zero-phase low-pass of each column of `u` (shape (n, m)): Butterworth, forwards and backwards.

    ``cutoff_hz`` ≤ 0 or None: no filter (the identity).
    """
    u = np.asarray(u, dtype=float)
    if cutoff_hz is None or cutoff_hz <= 0:
        return u.copy()
    nyquist = 0.5 / dt
    if not cutoff_hz < nyquist:
        raise IlcError(f"q_filter_cutoff_hz: must be below the Nyquist frequency {nyquist:g} Hz, got {cutoff_hz!r}")
    b, a = scipy.signal.butter(int(order), cutoff_hz / nyquist)
    if len(u) <= 3 * max(len(a), len(b)):
        raise IlcError(f"q_filter: {len(u)} samples are too few for the order-{order} filter")
    return scipy.signal.filtfilt(b, a, u, axis=0, padtype="odd")


def q_filter_matrix(n: int, dt: float, cutoff_hz: float = Q_FILTER_CUTOFF_HZ,
                    order: int = Q_FILTER_ORDER) -> np.ndarray:
    """The Q-filter as a dense (n, n) matrix on one channel (column j: the filter applied to unit vector j)."""
    return q_filter(np.eye(n), dt, cutoff_hz, order)


class NormOptimalIlc:
    """Norm-optimal ILC on an :class:`LtvModel`, without dense matrices (module docstring).

    Parameters
    ----------
    model : LtvModel
    error_weight : float
        Qe = error_weight · I (rad⁻²).
    input_weight : float
        Ru = input_weight · I2 ((N·m)⁻²), > 0.
    q_cutoff_hz : float or None
        Q-filter cut-off (None or 0: no Q-filter).
    q_order : int
        Q-filter order per pass.
    """

    def __init__(self, model: LtvModel, error_weight: float = ERROR_WEIGHT, input_weight: float = INPUT_WEIGHT,
                 q_cutoff_hz: float | None = Q_FILTER_CUTOFF_HZ, q_order: int = Q_FILTER_ORDER,
                 leak_weight: float = 0.0, time_weight=None, learning_gain: float = 1.0, output_weight=None,
                 settling_q_cutoff_hz: float | None = None, settling_start: int | None = None):
        if not (np.isfinite(error_weight) and error_weight > 0):
            raise IlcError(f"error_weight: a finite weight > 0 rad^-2, got {error_weight!r}")
        if not (np.isfinite(input_weight) and input_weight > 0):
            raise IlcError(f"input_weight: a finite weight > 0 (N m)^-2, got {input_weight!r}")
        if not (np.isfinite(leak_weight) and leak_weight >= 0):
            raise IlcError(f"leak_weight: a finite weight >= 0 (N m)^-2, got {leak_weight!r}")
        self.model = model
        self.error_weight, self.input_weight = float(error_weight), float(input_weight)
        self.leak_weight = float(leak_weight)
        if not (np.isfinite(learning_gain) and 0 < learning_gain < 2):
            raise IlcError(f"learning_gain: a step factor in (0, 2), got {learning_gain!r}")
        #: β: the update takes β Δu (β = 1: the norm-optimal step; the fixed point does not depend on β).
        self.learning_gain = float(learning_gain)
        w = np.ones(model.n_samples) if time_weight is None else np.asarray(time_weight, dtype=float)
        if w.shape != (model.n_samples,) or not np.isfinite(w).all() or w.min() < 0:
            raise IlcError(f"time_weight: {model.n_samples} finite weights >= 0 (samples 1..N), got shape {w.shape}")
        #: Per-sample factor of the error weight (sample k + 1 of the errors).
        self.time_weight = w
        ny = len(model.C)
        if output_weight is not None:
            x = np.asarray(output_weight, dtype=float)
            if x.shape != (model.n_samples, ny, ny) or not np.isfinite(x).all():
                raise IlcError(f"output_weight: {model.n_samples} finite ({ny}, {ny}) matrices (samples 1..N), "
                               f"got shape {x.shape}")
            if np.abs(x - x.transpose(0, 2, 1)).max() > 1e-12 * max(1.0, np.abs(x).max()):
                raise IlcError("output_weight: each sample's matrix must be symmetric")
            if np.linalg.eigvalsh(x).min() < -1e-12 * max(1.0, np.abs(x).max()):
                raise IlcError("output_weight: each sample's matrix must be positive semidefinite")
            output_weight = x
        #: Per-sample weight added to error_weight · time_weight · I on the errors (None: none), shape (N, 11, 11):
        #: the error of sample k + 1 costs eᵀ(error_weight · time_weight[k] · I + output_weight[k])e.
        self.output_weight = output_weight
        self.q_cutoff_hz, self.q_order = q_cutoff_hz, int(q_order)
        if settling_start is not None and not 0 <= int(settling_start) <= model.n_samples:
            raise IlcError(f"settling_start: a sample in [0, {model.n_samples}], got {settling_start!r}")
        if settling_q_cutoff_hz is not None and not (np.isfinite(settling_q_cutoff_hz) and settling_q_cutoff_hz >= 0):
            raise IlcError(f"settling_q_cutoff_hz: a cut-off >= 0 Hz (0: no filter), got {settling_q_cutoff_hz!r}")
        #: From sample `settling_start` on the Q-filter's cut-off is `settling_q_cutoff_hz`, each phase filtered on
        #: its own (None: the same filter throughout).
        self.settling_q_cutoff_hz = settling_q_cutoff_hz if settling_start is not None else None
        self.settling_start = None if settling_q_cutoff_hz is None else settling_start
        self._riccati()

    def _riccati(self) -> None:
        """Backward Riccati sweep of the LQ tracking problem: the feedback K_k, M_k⁻¹Γ_kᵀ and (A−BK)ᵀ per sample."""
        m = self.model
        n = m.n_samples
        CtQC = self.error_weight * m.C.T @ m.C  # times time_weight[k − 1] for the error of sample k
        w = self.time_weight
        R = (self.input_weight + self.leak_weight) * np.eye(2)
        self._K = np.empty((n, 2, N_STATE))
        self._G = np.empty((n, 2, N_STATE))
        self._Minv = np.empty((n, 2, 2))
        self._Acl_T = np.empty((n, N_STATE, N_STATE))
        X = self.output_weight
        if X is not None:  # the added output weight, carried to the state: CᵀX_kC
            CtXC = np.einsum("ia,kij,jb->kab", m.C, X, m.C)
        P = w[n - 1] * CtQC + (CtXC[n - 1] if X is not None else 0.0)  # cost-to-go of δx_N
        for k in range(n - 1, -1, -1):
            A, B = m.A[k], m.B[k]
            PB = P @ B
            M = R + B.T @ PB
            K = np.linalg.solve(M, PB.T @ A)
            self._K[k] = K
            self._G[k] = np.linalg.solve(M, B.T)
            self._Minv[k] = np.linalg.inv(M)
            acl = A - B @ K
            self._Acl_T[k] = acl.T
            # the output cost of δx_k (k ≥ 1) plus the cost-to-go through sample k
            P = (w[k - 1] * CtQC + (CtXC[k - 1] if X is not None else 0.0) if k > 0 else 0.0) + A.T @ P @ acl
            P = 0.5 * (P + P.T)

    def step(self, error, correction=None) -> np.ndarray:
        """The norm-optimal change Δu of the correction, shape (N, 2), for the errors e_1..e_N, shape (N, 11).

        Minimises ‖e − GΔu‖²_Qe + r‖Δu‖² + s‖u + Δu‖² (r = ``input_weight``, s = ``leak_weight``, u =
        `correction`, default zero): Δu = (GᵀQeG + (r + s)I)⁻¹(GᵀQe e − s u); with s = 0 this is L e.
        """
        m = self.model
        e = np.asarray(error, dtype=float)
        h = None
        if self.leak_weight and correction is not None:
            h = self.leak_weight * np.asarray(correction, dtype=float)
        if e.shape != (m.n_samples, len(m.C)):
            raise IlcError(f"error: expected shape ({m.n_samples}, {len(m.C)}) (samples 1..N, rad), got {e.shape}")
        if not np.isfinite(e).all():
            raise IlcError("error: contains non-finite values")
        n = m.n_samples
        s = np.zeros((n + 1, N_STATE))  # adjoint s_k: V_k(x) = xᵀP_k x − 2 s_kᵀ x + c
        # with the leak term 2hᵀΔu_k per sample: s_k = CᵀQe_k + (A−BK)ᵀs_(k+1) + K_kᵀh_k,
        # Δu_k = −K_k x_k + M_k⁻¹(Γ_kᵀ s_(k+1) − h_k)
        we = self.error_weight * e * self.time_weight[:, None]
        if self.output_weight is not None:
            we = we + np.einsum("kij,kj->ki", self.output_weight, e)
        ct = m.C.T
        s[n] = ct @ we[n - 1]
        for k in range(n - 1, 0, -1):
            s[k] = ct @ we[k - 1] + self._Acl_T[k] @ s[k + 1]
            if h is not None:
                s[k] += self._K[k].T @ h[k]
        du = np.empty((n, 2))
        x = np.zeros(N_STATE)
        for k in range(n):
            du[k] = -self._K[k] @ x + self._G[k] @ s[k + 1]
            if h is not None:
                du[k] -= self._Minv[k] @ h[k]
            x = m.A[k] @ x + m.B[k] @ du[k]
        return du

    def update(self, correction, error, feedforward=None, limits=None) -> np.ndarray:
        """The next trial's correction: Q(u + L e), clipped so that feedforward + correction stays in the limits.

        Parameters
        ----------
        correction : array_like, shape (N, 2)
            This trial's correction u_j, N·m.
        error : array_like, shape (N, 11)
            Its measured errors e_1..e_N, rad (:func:`measured_errors`).
        feedforward : array_like, shape (N, 2), optional
            The trajectory's feedforward over the horizon (zero after the slew), N·m; with `limits`.
        limits : (float, float), optional
            |τ1|, |τ2| limits, N·m: the correction is clipped to [−limit − τ_ff, limit − τ_ff].

        Returns
        -------
        ndarray, shape (N, 2)
        """
        u = np.asarray(correction, dtype=float)
        if u.shape != (self.model.n_samples, 2):
            raise IlcError(f"correction: expected shape ({self.model.n_samples}, 2) N·m, got {u.shape}")
        nxt = self.q(u + self.learning_gain * self.step(error, u))
        if limits is not None:
            lim = np.asarray(limits, dtype=float)
            ff = np.zeros_like(nxt) if feedforward is None else np.asarray(feedforward, dtype=float)
            nxt = np.clip(nxt, -lim - ff, lim - ff)
        return nxt

    def q(self, u) -> np.ndarray:
        """The Q-filter on each column of `u` (shape (N, m)): the zero-phase low-pass; with ``settling_start`` the
        samples before it and from it on are filtered each on their own, the latter with the settling's cut-off (so
        neither phase's correction leaks into the other's through the filter; the torque may step at t_f)."""
        u = np.asarray(u, dtype=float)
        dt = self.model.dt
        k0 = self.settling_start
        if k0 is None:
            return q_filter(u, dt, self.q_cutoff_hz, self.q_order)
        out = np.empty_like(u)
        out[:k0] = q_filter(u[:k0], dt, self.q_cutoff_hz, self.q_order) if k0 else u[:0]
        out[k0:] = q_filter(u[k0:], dt, self.settling_q_cutoff_hz, self.q_order) if k0 < len(u) else u[k0:]
        return out

    # -- dense forms, for small horizons (tests, analysis) -------------------------
    def lifted_matrix(self) -> np.ndarray:
        """G, shape (11N, 2N): δy_1..δy_N (sample-major) from Δu_0..Δu_(N−1) (sample-major). Small N only."""
        m = self.model
        n, ny = m.n_samples, len(m.C)
        G = np.zeros((n * ny, n * 2))
        for j in range(n):  # response to unit inputs at sample j
            X = m.B[j].copy()  # (22, 2): state at j + 1
            for k in range(j, n):
                G[k * ny:(k + 1) * ny, j * 2:(j + 1) * 2] = m.C @ X
                if k + 1 < n:
                    X = m.A[k + 1] @ X
        return G

    def dense_operator(self) -> tuple[np.ndarray, np.ndarray]:
        """(L, T): the dense learning gain L = (GᵀQeG + (r + s)I)⁻¹GᵀQe, shape (2N, 11N), and the learning operator
        on the correction, T = Q(I − L G − s H⁻¹), shape (2N, 2N), H = GᵀQeG + (r + s)I: on a plant equal to the
        model, e_j = e_0 − G u_j and u_(j+1) = T u_j + Q L e_0."""
        G = self.lifted_matrix()
        n = self.model.n_samples
        W = np.diag(self.error_weight * np.repeat(self.time_weight, len(self.model.C)))
        if self.output_weight is not None:
            W += scipy.linalg.block_diag(*self.output_weight)
        H = G.T @ W @ G + (self.input_weight + self.leak_weight) * np.eye(2 * n)
        L = np.linalg.solve(H, G.T @ W)
        Qm = self.q(np.eye(n))
        Q2 = np.kron(Qm, np.eye(2))  # sample-major: the same filter on each channel
        return L, Q2 @ (np.eye(2 * n) - L @ G - self.leak_weight * np.linalg.inv(H))


def settling_weights(trajectory, n_samples: int, settling_weight: float = 1.0,
                     tip_weight: float = 0.0) -> tuple[np.ndarray, np.ndarray | None]:
    """The error weights of :class:`NormOptimalIlc` that stress the settling: ``(time_weight, output_weight)``.

    The errors of the samples at and after t_f (the arm should be at rest on the end point) get the factor
    `settling_weight` on ``error_weight`` and, added, `tip_weight` (m⁻²) times JᵀJ, J the tip Jacobian at the
    end configuration (:meth:`flexarm.model.ArmModel.tip_jacobian`): eᵀJᵀJe is the squared tip deviation, to
    first order, that the measured angle errors e imply (from the sensors, as the rest of the learning).
    ``output_weight`` is None when `tip_weight` is 0.
    """
    traj = as_trajectory(trajectory)
    if not (np.isfinite(settling_weight) and settling_weight >= 0):
        raise IlcError(f"settling_weight: a finite factor >= 0, got {settling_weight!r}")
    if not (np.isfinite(tip_weight) and tip_weight >= 0):
        raise IlcError(f"settling_tip_weight: a finite weight >= 0 m^-2, got {tip_weight!r}")
    n = int(n_samples)
    after = np.arange(1, n + 1) >= traj.n_samples  # error i is of sample i + 1; sample n_samples is at t_f
    w = np.where(after, float(settling_weight), 1.0)
    if not tip_weight:
        return w, None
    from .model import ArmModel
    from .parameters import load_parameters

    J = ArmModel(load_parameters()).tip_jacobian(desired_states(traj)[-1])
    x = np.zeros((n, N, N))
    x[after] = float(tip_weight) * J.T @ J
    return w, x
