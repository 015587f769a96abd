"""Discrete-time LQG design along the trajectory (issue 14; the paper's "future work"): files and numerics.

At each schedule point t_k (:data:`flexarm.gain_schedule.SCHEDULES`) the arm is
linearised about the desired state and the feedforward torque (the exact
linearisation of the tracking-error dynamics) and sampled with a 1 ms
zero-order hold:

    δx_{j+1} = Φ_k δx_j + Γ_k δu_j + w_j,      δy_j = C δx_j + v_j

with δx = z − z_d, δu = τ − τ_ff and the ten measurements y = (q1, q2, q̇1,
q̇2, ε1..ε6) (C: the sensor map, exact since every measurement is linear in z).

Kalman filter (steady state per point, :func:`kalman_gain`)
    V = diag(a²/3): the sensors' uniform ±a noise (encoders 0.1°, tachometers
    1 °/s, gauges 0.05°, from ``flexarm/data/sensors_default.toml``).

    W = Γ_d Σ_d Γ_dᵀ: what the filter must absorb enters the arm as forces held
    over a sample (Γ_d the ZOH input matrix of each force):

    * the unknown payload (0.275 kg at the tip, the paper's model error): a tip
      force m·a_tip, m = :data:`PAYLOAD_MASS_KG`, a_tip the rms tip acceleration
      of the slew (about 2 m/s²), per axis;
    * motor and drive model error: :data:`MOTOR_TORQUE_SIGMA` on each joint torque;
    * the model's stiffness and mass errors: a generalised force of
      :data:`ELEMENT_FORCE_SIGMA` on every element (it also keeps every mode,
      including the kHz bracket modes, observable from the noise, so the
      steady-state filter exists).

    The filter is the "current" form (measurement update at the sample the
    measurement belongs to): M = P⁻Cᵀ(CP⁻Cᵀ + V)⁻¹ with P⁻ the prior covariance
    (DARE), posterior P⁺ = (I − MC)P⁻.

LQR (per point, per weight of :mod:`flexarm.gain_sets`, R = 10·I2)
    Discrete LQR on (Φ_k, Γ_k); with integral action the state is augmented
    with ξ_{j+1} = ξ_j + dt·(q_j − q_d,j) (the two joint-angle errors) and
    weighted by :data:`INTEGRAL_WEIGHT`·I2.

All Riccati equations are solved in the balanced modal coordinates of
:func:`flexarm.lqr_design.scaling_transform` (see there for why).
The files: ``flexarm/data/lqg/lqg_<schedule>.npz`` and ``.json`` (provenance
and data-chain check as for the gain schedules), written by
``python -m flexarm.lqr --write``.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy

from .filter_law import covariance_step  # the law the native predictor's C is generated from
from .gain_schedule import (
    SCHEDULES,
    desired_states,
    load_desired,
    operating_times,
    read_design_files,
    relative_path,
    schedule_index,
    write_design_files,
)
from .gain_sets import WEIGHT_NAMES, GainError, state_weight
from .lqr_design import R_PAPER, scaling_transform, zoh
from .model import N_STATE, ArmModel, N, joint_angles, joint_velocities, strain_gauge_angles
from .parameters import DATA_DIR
from .provenance import git_commit
from .sensors import SensorSettings

#: Folder of the committed LQG design files.
DEFAULT_LQG_DIR = DATA_DIR / "lqg"
FILE_FORMAT = "flexarm-lqg-design/1"
#: Payload mass the filter is designed to absorb, kg (the paper's model error).
PAYLOAD_MASS_KG = 0.275
#: Standard deviation of the motor torque error per sample, N·m.
MOTOR_TORQUE_SIGMA = 0.02
#: Standard deviation of the generalised model-error force on every element, N·m.
ELEMENT_FORCE_SIGMA = 0.002
#: Weight of the two integrated joint-angle errors (rad·s)², integral action.
INTEGRAL_WEIGHT = 1.0e6
#: State weight of the end point's hold (issue 32 item 4), whatever the gain set: angles 1e4 (the paper's 10 ×
#: 1000), rates 1, R the paper's. After the slew the paper's weights leave a slow, lightly damped servo pair (the
#: tip creeps for seconds); with the filter's full state this weight makes the hold settle within about a second
#: with hold torques far inside the limits (poles and settling times: docs/findings.md, bounds: tests/test_lqg.py).
HOLD_STATE_WEIGHT = np.diag(np.r_[np.full(N, 1.0e4), np.full(N, 1.0)])
#: Measurement names, in the order of C's rows and the controllers' inputs.
MEASUREMENTS = ("q1", "q2", "qd1", "qd2", "eps1", "eps2", "eps3", "eps4", "eps5", "eps6")


def measurement_matrix() -> np.ndarray:
    """C, shape (10, 22): y = C z for y = (q1, q2 rad, q̇1, q̇2 rad/s, ε1..ε6 rad) (exact: linear maps)."""
    C = np.zeros((10, N_STATE))
    for i in range(N):
        e = np.zeros(N)
        e[i] = 1.0
        C[0:2, i] = joint_angles(e)
        C[2:4, N + i] = joint_velocities(e)
        C[4:10, i] = strain_gauge_angles(e)
    return C


def measurement_covariance(settings: SensorSettings | None = None) -> np.ndarray:
    """V, shape (10, 10): variances a²/3 of the uniform ±a sensor noise, rad² and (rad/s)².

    Parameters
    ----------
    settings : SensorSettings, optional
        Default: ``flexarm/data/sensors_default.toml`` (the paper's ±0.1°, ±1 °/s, ±0.05°).
    """
    s = settings if settings is not None else SensorSettings.from_toml()
    half = np.radians([s.encoder_noise_deg] * 2 + [s.tachometer_noise_deg_per_s] * 2
                      + [s.strain_gauge_noise_deg] * 6)
    return np.diag(half**2 / 3.0)


def rms_tip_acceleration(model: ArmModel, traj) -> float:
    """rms over the slew of the tip acceleration magnitude, m/s² (finite differences of the tip velocity)."""
    vel = np.array([model.tip_velocity(th, om) for th, om in zip(traj.theta, traj.omega)])
    acc = np.diff(vel, axis=0) / (traj.t[1] - traj.t[0])
    return float(np.sqrt(np.mean(np.sum(acc**2, axis=1))))


def force_input_matrix(model: ArmModel, z_bar) -> tuple[np.ndarray, np.ndarray]:
    """Continuous input matrix of the disturbance forces and their standard deviations.

    Returns
    -------
    B_d : ndarray, shape (22, 15)
        Columns: tip force x, y (N); the two joint torques (N·m); a generalised
        force on each of the 11 elements (N·m).
    kinds : tuple of str, length 15
        ``"tip"``, ``"motor"`` or ``"element"`` per column.
    """
    theta = np.asarray(z_bar, dtype=float)[:N]
    gen = np.hstack([model.tip_jacobian(theta).T, model.input_matrix(), np.eye(N)])
    B_d = np.zeros((N_STATE, gen.shape[1]))
    B_d[N:] = np.linalg.solve(model.mass_matrix(theta), gen)
    return B_d, ("tip",) * 2 + ("motor",) * 2 + ("element",) * N


def kalman_gain(Phi, C, W, V, pole_radius: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steady-state Kalman filter of x_{j+1} = Φx_j + w_j, y_j = Cx_j + v_j (current-estimator form).

    With ``pole_radius`` α < 1 the gain is the Kalman gain of Φ/α (a prescribed degree of stability, Anderson
    & Moore, *Optimal Control*, §3.5 dual): every pole of the error dynamics (I − MC)Φ lies within |λ| < α,
    however little process noise W puts on a mode. The covariances returned are then the true steady-state
    ones of that gain (a discrete Lyapunov equation), not the Riccati solution of Φ/α.

    Parameters
    ----------
    Phi : array_like, shape (n, n)
    C : array_like, shape (p, n)
    W : array_like, shape (n, n)
        Process-noise covariance (symmetric PSD).
    V : array_like, shape (p, p)
        Measurement-noise covariance (symmetric PD).
    pole_radius : float
        Largest allowed magnitude of an estimator pole, in (0, 1]; 1 is the plain Kalman filter.

    Returns
    -------
    M : ndarray, shape (n, p)
        Update gain, x̂⁺ = x̂⁻ + M (y − C x̂⁻).
    P_prior, P_post : ndarray, shape (n, n)
        Steady-state error covariances before and after the update.
    """
    Phi, C, W, V = (np.asarray(a, dtype=float) for a in (Phi, C, W, V))
    import scipy.linalg  # here, not at import: a run that only reads designs needs no SciPy linalg

    if not 0.0 < pole_radius <= 1.0:
        raise ValueError(f"pole_radius: a number in (0, 1], got {pole_radius!r}")
    P = scipy.linalg.solve_discrete_are(Phi.T / pole_radius, C.T, W, V)
    P = 0.5 * (P + P.T)
    M = np.linalg.solve(C @ P @ C.T + V, C @ P).T
    if pole_radius < 1.0:  # the prior covariance of the filter with this gain: e⁻ ← Φ(I − MC)e⁻ − ΦMv + w
        F = Phi @ (np.eye(len(P)) - M @ C)
        P = scipy.linalg.solve_discrete_lyapunov(F, W + Phi @ M @ V @ M.T @ Phi.T)
        P = 0.5 * (P + P.T)
    P_post = (np.eye(len(P)) - M @ C) @ P
    return M, P, 0.5 * (P_post + P_post.T)


def dlqr(Phi, Gamma, Q, R) -> np.ndarray:
    """Discrete LQR gain K (u = −Kx), shape (m, n), from scipy's DARE."""
    import scipy.linalg

    P = scipy.linalg.solve_discrete_are(Phi, Gamma, Q, R)
    return np.linalg.solve(R + Gamma.T @ P @ Gamma, Gamma.T @ P @ Phi)


@dataclass
class LqgPoint:
    """The LQG design at one operating point (original coordinates).

    Attributes
    ----------
    Phi : ndarray, shape (22, 22)
    Gamma : ndarray, shape (22, 2)
        1 ms ZOH model of the error dynamics.
    W : ndarray, shape (22, 22)
        Process-noise covariance per sample.
    M : ndarray, shape (22, 10)
        Kalman update gain.
    P_prior, P_post : ndarray, shape (22, 22)
        Steady-state estimation-error covariances (rad², (rad/s)²).
    K : ndarray, shape (n_weights, 2, 22)
        LQR gains per :data:`flexarm.gain_sets.WEIGHT_NAMES` entry.
    K_integral : ndarray, shape (n_weights, 2, 24)
        Gains of the integral-action design (last two columns: ξ).
    """

    Phi: np.ndarray
    Gamma: np.ndarray
    W: np.ndarray
    M: np.ndarray
    P_prior: np.ndarray
    P_post: np.ndarray
    K: np.ndarray
    K_integral: np.ndarray


def design_point(model: ArmModel, z_bar, tau_bar, V, tip_force_sigma: float, dt: float = 1e-3,
                 integral_weight: float = INTEGRAL_WEIGHT, motor_torque_sigma: float = MOTOR_TORQUE_SIGMA,
                 element_force_sigma: float = ELEMENT_FORCE_SIGMA, state_weights=None,
                 estimator_pole_radius: float = 1.0) -> LqgPoint:
    """LQG design at one operating point (module docstring).

    Parameters
    ----------
    model : ArmModel
        The controller's model (no payload).
    z_bar : array_like, shape (22,)
    tau_bar : array_like, shape (2,)
        Feedforward torque at the point, N·m.
    V : array_like, shape (10, 10)
        Measurement covariance (:func:`measurement_covariance`).
    tip_force_sigma : float
        Standard deviation of the tip force per axis, N.
    dt : float
        Sample time, s.
    integral_weight : float
        Weight of the integrated joint-angle errors.
    motor_torque_sigma : float
        Standard deviation of the motor torque error per joint, N·m.
    element_force_sigma : float
        Standard deviation of the model-error generalised force on every element, N·m.
    state_weights : sequence of ndarray, shape (22, 22), optional
        One Q per :data:`flexarm.gain_sets.WEIGHT_NAMES` entry; default their own weights (the end point's hold
        passes :data:`HOLD_STATE_WEIGHT` for every name).
    estimator_pole_radius : float
        Largest magnitude of an estimator pole (:func:`kalman_gain`); 1 for the plain Kalman filter.
    """
    A, B = model.linearize(z_bar, tau_bar)
    B_d, kinds = force_input_matrix(model, z_bar)
    T = scaling_transform(model, z_bar)
    Ti = np.linalg.inv(T)
    n_u = B.shape[1]
    Phit, Gall = zoh(Ti @ A @ T, Ti @ np.hstack([B, B_d]), dt)
    Gamt, Gdt = Gall[:, :n_u], Gall[:, n_u:]
    sigma = np.array([{"tip": tip_force_sigma, "motor": motor_torque_sigma, "element": element_force_sigma}[k]
                      for k in kinds])
    Wt = (Gdt * sigma**2) @ Gdt.T
    Wt = 0.5 * (Wt + Wt.T)
    C = measurement_matrix()
    Mt, Ppt, Pqt = kalman_gain(Phit, C @ T, Wt, V, estimator_pole_radius)
    Cq = C[0:2]
    import scipy.linalg

    Ta = scipy.linalg.block_diag(T, np.eye(2))
    Phia = np.block([[Phit, np.zeros((N_STATE, 2))], [dt * Cq @ T, np.eye(2)]])
    Gama = np.vstack([Gamt, np.zeros((2, n_u))])
    Ks, Kis = [], []
    for Q in [state_weight(name) for name in WEIGHT_NAMES] if state_weights is None else state_weights:
        Qt = T.T @ Q @ T
        Ks.append(dlqr(Phit, Gamt, 0.5 * (Qt + Qt.T), R_PAPER) @ Ti)
        Qa = scipy.linalg.block_diag(Qt, integral_weight * np.eye(2))
        Kis.append(dlqr(Phia, Gama, 0.5 * (Qa + Qa.T), R_PAPER) @ np.linalg.inv(Ta))
    return LqgPoint(Phi=T @ Phit @ Ti, Gamma=T @ Gamt, W=T @ Wt @ T.T, M=T @ Mt, P_prior=T @ Ppt @ T.T,
                    P_post=T @ Pqt @ T.T, K=np.array(Ks), K_integral=np.array(Kis))


@dataclass
class LqgDesign:
    """LQG designs at the points of one schedule (arrays stacked over the points; see :class:`LqgPoint`).

    Attributes
    ----------
    schedule : str
    times : ndarray, shape (n,)
        Operating times, s; point k is used on [t_k, t_k+1).
    operating_points : ndarray, shape (n, 22)
    tau_bar : ndarray, shape (n, 2)
    Phi, Gamma, W, M, P_prior, P_post : ndarray, shape (n, ...)
    K : ndarray, shape (n, n_weights, 2, 22)
    K_integral : ndarray, shape (n, n_weights, 2, 24)
    C : ndarray, shape (10, 22)
    V : ndarray, shape (10, 10)
    metadata : dict
    """

    schedule: str
    times: np.ndarray
    operating_points: np.ndarray
    tau_bar: np.ndarray
    Phi: np.ndarray
    Gamma: np.ndarray
    W: np.ndarray
    M: np.ndarray
    P_prior: np.ndarray
    P_post: np.ndarray
    K: np.ndarray
    K_integral: np.ndarray
    C: np.ndarray
    V: np.ndarray
    metadata: dict = field(default_factory=dict)

    ARRAYS = ("times", "operating_points", "tau_bar", "Phi", "Gamma", "W", "M", "P_prior", "P_post", "K",
              "K_integral", "C", "V")

    def __post_init__(self):
        n = len(self.times)
        for name in self.ARRAYS[1:11]:
            if len(getattr(self, name)) != n:
                raise GainError(f"LQG design {name}: expected {n} operating points, got {len(getattr(self, name))}")
        for name in self.ARRAYS:
            if not np.all(np.isfinite(getattr(self, name))):
                raise GainError(f"LQG design {name}: contains non-finite values")

    @property
    def slew_times(self) -> np.ndarray:
        """The switching times along the slew, s: every point's but the last, the hold at t_f (:func:`design_lqg`)."""
        return self.times[:-1]

    def index_at(self, t: float) -> int:
        """Index of the point in force at time t (s); the first before t_0."""
        return schedule_index(self.times, t)

    def weight_index(self, name: str) -> int:
        """Index of a weight name (:data:`flexarm.gain_sets.WEIGHT_NAMES`) in ``K``."""
        base = name.removeprefix("dlqr-")
        if base not in WEIGHT_NAMES:
            raise GainError(f"gain_set: {name!r} is not one of {WEIGHT_NAMES}")
        return WEIGHT_NAMES.index(base)

    def save(self, directory=None) -> Path:
        """Write ``lqg_<schedule>.npz`` and ``.json`` atomically; returns the npz path."""
        directory = Path(directory) if directory is not None else DEFAULT_LQG_DIR
        arrays = {name: getattr(self, name) for name in self.ARRAYS}
        return write_design_files(directory / f"lqg_{self.schedule}", arrays,
                                  dict(self.metadata, format=FILE_FORMAT, schedule=self.schedule))

    @classmethod
    def load(cls, schedule: str = "200ms", directory=None) -> LqgDesign:
        """Load a design file, checking its data chain (:func:`flexarm.gain_schedule.read_design_metadata`)."""
        if schedule not in SCHEDULES:
            raise GainError(f"schedule: {schedule!r} is not one of {tuple(SCHEDULES)}")
        directory = Path(directory) if directory is not None else DEFAULT_LQG_DIR
        meta, arrays = read_design_files(directory / f"lqg_{schedule}", "LQG design file", data_dir=directory.parent)
        return cls(schedule=schedule, metadata=meta, **{k: arrays[k] for k in cls.ARRAYS})


def design_lqg(model: ArmModel, trajectory, schedule: str = "200ms", sensors: SensorSettings | None = None,
               integral_weight: float = INTEGRAL_WEIGHT, payload_mass: float = PAYLOAD_MASS_KG,
               motor_torque_sigma: float = MOTOR_TORQUE_SIGMA,
               element_force_sigma: float = ELEMENT_FORCE_SIGMA, estimator_pole_radius: float = 1.0) -> LqgDesign:
    """LQG design at every point of a schedule along a trajectory.

    Parameters
    ----------
    model : ArmModel
        The controller's model (no payload: the payload is what the filter absorbs).
    trajectory : TrajectoryResult or path-like
    schedule : str
        ``200ms``, ``20ms`` or ``single``.
    sensors : SensorSettings, optional
        Noise half-widths for V (default the committed sensor file).
    integral_weight : float
        Weight of the integrated joint-angle errors.
    payload_mass, motor_torque_sigma, element_force_sigma : float
        The process-noise model (module docstring): payload the filter absorbs, kg; motor torque error,
        N·m; model-error force per element, N·m. The committed designs use the defaults;
        :mod:`flexarm.lqg_tradeoff` varies them.
    estimator_pole_radius : float
        Largest magnitude of an estimator pole (:func:`kalman_gain`), 1 for the plain Kalman filter.
    """
    traj, traj_path, traj_sha = load_desired(trajectory)
    z, dt = desired_states(traj), float(traj.t[1] - traj.t[0])
    times = operating_times(traj.t_f, schedule, dt)
    idx = np.round(times / dt).astype(int)
    V = measurement_covariance(sensors)
    a_tip = rms_tip_acceleration(model, traj)
    tip_sigma = payload_mass * a_tip
    # the feedforward of the last sample is the hold's zero torque
    tau_bar = np.array([traj.tau[k] if k < traj.n_samples else np.zeros(2) for k in idx])
    points = [design_point(model, z[k], tb, V, tip_sigma, dt, integral_weight, motor_torque_sigma, element_force_sigma,
                           estimator_pole_radius=estimator_pole_radius) for k, tb in zip(idx, tau_bar)]
    # The hold: one more point at t_f, the end state at rest with zero torque, regulated by HOLD_STATE_WEIGHT
    # for every gain set (the controllers use the point in force, so every sample from t_f on holds with it).
    n = traj.n_samples
    times, idx = np.r_[times, n * dt], np.r_[idx, n]
    tau_bar = np.vstack([tau_bar, np.zeros(2)])
    points.append(design_point(model, z[n], np.zeros(2), V, tip_sigma, dt, integral_weight, motor_torque_sigma,
                               element_force_sigma, [HOLD_STATE_WEIGHT] * len(WEIGHT_NAMES), estimator_pole_radius))
    stack = lambda a: np.array([getattr(p, a) for p in points])  # noqa: E731
    meta = {
        "description": "discrete-time LQG per schedule point: Kalman gains M (current form), LQR gains K "
                       "per weight, with and without integral action (flexarm.lqg_design)",
        "weights": list(WEIGHT_NAMES),
        "R": R_PAPER.tolist(),
        "integral_weight": integral_weight,
        "measurements": list(MEASUREMENTS),
        "process_noise": {"payload_mass_kg": payload_mass, "rms_tip_acceleration_m_s2": a_tip,
                          "tip_force_sigma_N": tip_sigma, "motor_torque_sigma_Nm": motor_torque_sigma,
                          "element_force_sigma_Nm": element_force_sigma},
        **({"estimator_pole_radius": estimator_pole_radius} if estimator_pole_radius < 1.0 else {}),
        "linearization": "about (z_d(t_k), tau_ff(t_k)), 1 ms zero-order hold",
        "hold": {"time_s": float(n * dt), "state_weight": "diag(1e4 I11, 1 I11) for every weight",
                 "why": "the end point's regulator (flexarm.lqg_design.HOLD_STATE_WEIGHT)"},
        "sample_time_s": dt,
        "operating_times_s": times.tolist(),
        "trajectory_file": relative_path(traj_path),
        "trajectory_sha256": traj_sha,
        "parameter_file": relative_path(model.params.source),
        "parameter_sha256": model.params.sha256,
        "commit": git_commit(),
        "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "versions": {"scipy": scipy.__version__, "numpy": np.__version__},
    }
    return LqgDesign(schedule=schedule, times=times, operating_points=z[idx], tau_bar=tau_bar,
                     Phi=stack("Phi"), Gamma=stack("Gamma"), W=stack("W"), M=stack("M"),
                     P_prior=stack("P_prior"), P_post=stack("P_post"), K=stack("K"),
                     K_integral=stack("K_integral"), C=measurement_matrix(), V=V, metadata=meta)


def transient_gains(design: LqgDesign, points, initial_covariance: float) -> np.ndarray:
    """Kalman gains of the time-varying filter, sample by sample, from a prior covariance at sample 0.

    P_0 = `initial_covariance` · P_prior(point of sample 0); then, at sample j with design point i = points[j],
    M_j = P_j Cᵀ (C P_j Cᵀ + V)⁻¹ and P_{j+1} = Φ_i (I − M_j C) P_j Φ_iᵀ + W_i (the design's W and V).

    Parameters
    ----------
    design : LqgDesign
    points : sequence of int, shape (n,)
        The design point of each sample.
    initial_covariance : float
        The factor, > 0.

    Returns
    -------
    ndarray, shape (n, 22, 10)
        All of them (:class:`TransientGains` makes them as a run asks for them).
    """
    gains = TransientGains(design, points, initial_covariance)
    return np.array([gains[j] for j in range(len(gains))]).reshape(len(gains), *design.C.T.shape)


class TransientGains:
    """:func:`transient_gains` made as they are asked for: ``gains[j]`` runs the covariance recursion through
    sample j the first time, in sample order, so a run spreads the recursion over its samples instead of
    stalling at the first one for the whole slew (the native predictor does the same, ``lqg_gains_through``).
    The numbers are :func:`transient_gains`'s, bit for bit, and so are the parameters (`design`, `points`: the
    design point of each sample, `initial_covariance`: the factor, > 0).
    """

    def __init__(self, design: LqgDesign, points, initial_covariance: float):
        if not np.isfinite(initial_covariance) or initial_covariance <= 0:
            raise ValueError(f"initial_covariance: a factor > 0, got {initial_covariance!r}")
        self._design, self._points = design, np.asarray(points, dtype=int)
        self._P = initial_covariance * design.P_prior[self._points[0]] if len(self._points) else None
        self._gains = np.empty((len(self._points), *design.C.T.shape))
        #: Samples whose gain is made so far (0 .. made − 1).
        self.made = 0

    def __len__(self) -> int:
        return len(self._points)

    def __getitem__(self, j) -> np.ndarray:
        """The gain of sample j, shape (22, 10) (made through j first if need be)."""
        j = int(j)
        if not 0 <= j < len(self._points):
            raise IndexError(f"sample {j}: the gains cover samples 0 .. {len(self._points) - 1}")
        C, V = self._design.C, self._design.V
        while self.made <= j:
            i = self._points[self.made]
            self._gains[self.made], self._P = covariance_step(self._P, C, V, self._design.Phi[i], self._design.W[i])
            self.made += 1
        return self._gains[j]
