"""Feedforward + LQR tracking control law of the paper (Fig. 3, section 6), without FMI.

Each 1 ms sample the controller receives the two encoder angles q (rad), the
two tachometer rates q̇ (rad/s) and the six strain-gauge angles ε (rad) and
returns the motor torques::

    τ = sat( τ_ff(t) − K(t) · (x̂ − x̂_d(t)) )

(its arithmetic: :mod:`flexarm.control_law`, from which the native FMUs' C is generated)

* x̂: the 11 angles reconstructed from q and ε (eqs. 21-31, rigid brackets,
  :func:`flexarm.model.reconstruct_angles`) and two velocities (below); the
  other nine velocity entries are not measured and are not fed back (their
  gain columns are zeroed, :func:`flexarm.lqr.reduce_gain`).
* x̂_d: the desired state passed through the *same* sensor map (desired
  encoder, tachometer and gauge values from z_d, then eqs. 21-31). For the
  angles this differs from the literal θ_d only by the desired bracket
  deflections (≈ τ/k_bracket, a few µrad), which the rigid-bracket
  reconstruction can never see; comparing like with like keeps those from
  acting as a constant bias through the bracket columns of K (large in the
  discrete design). On the trajectory the error is then exactly zero.
* Velocities (``omega7``):

  ``"tachometer"`` (default): θ̇1 error = q̇1 − q̇1_d and the θ̇7 column gets
  the joint-2 tachometer error q̇2 − q̇2_d. Since θ̇7 = θ̇6 + q̇2, this
  drops the θ̇6 error, i.e. treats the link-1 tip rate as one of the
  unmeasured velocities the paper ignores; it uses exactly "the two velocity
  states directly provided by the tachometers" and nothing else.

  ``"rigid"``: θ̇7 error ≈ (q̇1 − q̇1_d) + (q̇2 − q̇2_d), i.e. θ̇6 ≈ θ̇1 (link 1
  rigid in rate); closer to the absolute θ̇7 the gain was designed for when
  the shoulder lags, but it mixes the noisy shoulder tachometer into the
  elbow column.

Modes: ``"ff+fb"`` (the paper's scheme), ``"ff"`` (open loop, replays the
trajectory torques; no gains needed) and ``"fb"`` (same gains, no feedforward).
After the slew (t ≥ T) the controller holds the final desired state with zero
feedforward and the last gain set.
"""

from __future__ import annotations

import numpy as np

from . import control_law as law
from .gain_schedule import GainSchedule, as_trajectory, desired_states, sample_time
from .lqr_design import OMEGA7_CHOICES
from .model import ArmModel, N, joint_angles, joint_velocities, reconstruct_angles, strain_gauge_angles
from .parameters import load_parameters

MODES = ("ff+fb", "ff", "fb")
#: Motor peak torques |τ1|, |τ2|, N·m, read from the committed parameter file (``motors.peak_torque_Nm``).
PEAK_TORQUE = tuple(float(x) for x in load_parameters().peak_torque)


class ControllerError(ValueError):
    """A controller setting or input is invalid."""


class TrackingController:
    """Feedforward + scheduled LQR tracking controller with a 1 ms stepping API.

    Parameters
    ----------
    trajectory : TrajectoryResult or path-like
        Desired states and feedforward torques (:mod:`flexarm.trajectory.io`).
    schedule : GainSchedule or str or None
        Gain schedule, or a gain-set name loaded from the committed files with
        the ``200ms`` schedule (``gamma1``, ``gamma0.1``, ``gamma0``, ``eq32``,
        ``dlqr``, ``dlqr-*``). May be None only in mode ``"ff"``.
    mode : {"ff+fb", "ff", "fb"}
        Feedforward plus feedback, feedforward only, feedback only.
    saturation : (float, float) or None
        Torque limits |τ_1|, |τ_2| in N·m (default the motors' peak torques);
        None disables saturation.
    omega7 : {"tachometer", "rigid"}
        How the θ̇7 error is formed (module docstring).
    feedforward_correction : array_like, shape (m, 2), optional
        A learned correction (N·m, :mod:`flexarm.ilc`) added to the feedforward of samples 0..m−1
        (also after the slew, where the trajectory's feedforward is zero); refused in mode ``"fb"``.

    Notes
    -----
    Sample k covers [k·dt, (k+1)·dt); the feedforward of sample k is the
    trajectory's τ[k] for k < n_steps and zero afterwards (plus the correction's
    row k for k < m).
    """

    def __init__(self, trajectory, schedule=None, mode: str = "ff+fb", saturation=PEAK_TORQUE,
                 omega7: str = "tachometer", feedforward_correction=None):
        if mode not in MODES:
            raise ControllerError(f"mode: {mode!r} is not one of {MODES}")
        if omega7 not in OMEGA7_CHOICES:
            raise ControllerError(f"omega7: {omega7!r} is not one of {OMEGA7_CHOICES}")
        self.trajectory = as_trajectory(trajectory)
        #: Desired states at every sample, shape (n_steps + 1, 22).
        self.z = desired_states(self.trajectory)
        if isinstance(schedule, str):
            schedule = GainSchedule.load(schedule)
        if schedule is None and mode != "ff":
            raise ControllerError(f"schedule: a gain schedule is required in mode {mode!r}")
        self.schedule: GainSchedule | None = schedule
        self.mode = mode
        self.omega7 = omega7
        if saturation is None:
            self.saturation = None
        else:
            sat = np.asarray(saturation, dtype=float)
            if sat.shape != (2,) or not np.all(np.isfinite(sat)) or np.any(sat <= 0):
                raise ControllerError(f"saturation: two finite torque limits > 0 N·m, got {saturation!r}")
            self.saturation = sat
        self.dt = sample_time(self.trajectory)
        self.n_steps = self.trajectory.n_samples
        self.correction = None
        if feedforward_correction is not None:
            if mode == "fb":
                raise ControllerError("feedforward_correction: mode 'fb' has no feedforward to correct")
            corr = np.array(feedforward_correction, dtype=float)
            if corr.ndim != 2 or corr.shape[1] != 2 or not np.isfinite(corr).all():
                raise ControllerError(f"feedforward_correction: finite values of shape (m, 2) N·m, got shape "
                                      f"{corr.shape}")
            self.correction = corr
        # Desired sensor values along the trajectory, precomputed once (like with like, see module doc).
        th_d, om_d = self.trajectory.theta, self.trajectory.omega
        self._q_d = np.array([joint_angles(th) for th in th_d])
        self._qdot_d = np.array([joint_velocities(om) for om in om_d])
        eps_d = np.array([strain_gauge_angles(th) for th in th_d])
        # The estimate x̂ is linear in the 10 measurements m = (q1, q2, q̇1, q̇2, ε1..ε6):
        # x̂ = E m, so x̂ − x̂_d[k] = E m − x̂_d[k], and the law is one small mat-vec per sample.
        self._estimator = _estimator_matrix(omega7)
        m_d = np.column_stack([self._q_d, self._qdot_d, eps_d])
        self._x_hat_d = law.reconstructed_states(m_d, self._estimator)
        if schedule is not None:
            self._gain_index = np.array([schedule.index_at(k * self.dt) for k in range(self.n_steps + 1)])
            self._gains = schedule.reduced_gains()
            self._gains_per_measurement = np.array([law.gain_on_measurements(g, self._estimator)
                                                    for g in self._gains])
            # K(k) x̂_d[k] per sample: the law is τ = τ_ff − K E m + K x̂_d (no per-sample product).
            self._gain_offsets = law.gain_offsets(self._gains[self._gain_index], self._x_hat_d)

    # -- trajectory lookup --------------------------------------------------------------
    def sample_index(self, t: float) -> int:
        """Sample k of time t (s): the nearest multiple of dt (t ≥ 0)."""
        if not np.isfinite(t) or t < -0.5 * self.dt:
            raise ControllerError(f"t: must be a finite time >= 0 s, got {t!r}")
        return int(round(t / self.dt))

    def _clamped(self, k: int) -> int:
        if k < 0:
            raise ControllerError(f"k: sample index must be >= 0, got {k}")
        return min(int(k), self.n_steps)

    def desired_state(self, k: int) -> np.ndarray:
        """Desired state z_d at sample k (the final state after the slew), shape (22,)."""
        return self.z[self._clamped(k)].copy()

    def feedforward(self, k: int) -> np.ndarray:
        """Feedforward torque of sample k, N·m, shape (2,): τ[k] during the slew, 0 after (plus the correction)."""
        if k < 0:
            raise ControllerError(f"k: sample index must be >= 0, got {k}")
        tau = np.zeros(2) if self.mode == "fb" or k >= self.n_steps else self.trajectory.tau[k].copy()
        if self.correction is not None and k < len(self.correction):
            tau = law.corrected_feedforward(tau, self.correction[k])
        return tau

    def gain(self, k: int) -> np.ndarray:
        """Reduced gain in force at sample k, shape (2, 22) (zeros in mode ``"ff"``)."""
        if self.schedule is None or self.mode == "ff":
            return np.zeros((2, 2 * N))
        return self._gains[self._gain_index[self._clamped(k)]]

    def gain_per_measurement(self, k: int) -> np.ndarray:
        """The reduced gain in force at sample k on the ten measurements, K(k) E, shape (2, 10): the law's feedback
        is ``gain_per_measurement(k) @ (m − m_d(k))`` (zeros in mode ``"ff"``)."""
        if self.schedule is None or self.mode == "ff":
            return np.zeros((2, 10))
        return self._gains_per_measurement[self._gain_index[self._clamped(k)]]

    def error_estimate(self, k: int, q, qdot, strain) -> np.ndarray:
        """x̂ − x̂_d at sample k from the sensor values, shape (22,).

        Parameters
        ----------
        k : int
            Sample index (t = k·dt).
        q : array_like, shape (2,)
            Encoder angles q1 = θ1, q2 = θ7 − θ6, rad.
        qdot : array_like, shape (2,)
            Tachometer rates, rad/s.
        strain : array_like, shape (6,)
            Strain-gauge angles ε_1,1..ε_2,3, rad.

        Returns
        -------
        ndarray, shape (22,)
            Angle errors (11, eqs. 21-31 with rigid brackets) and velocity
            errors with only the θ̇1 and θ̇7 entries non-zero.
        """
        return self._estimator @ _measurements(q, qdot, strain) - self._x_hat_d[self._clamped(k)]

    def torque_at(self, k: int, q, qdot, strain) -> np.ndarray:
        """Motor torques for sample k, N·m, shape (2,) (see :meth:`error_estimate` for inputs)."""
        return self._torque(k, None if self.mode == "ff" else _measurements(q, qdot, strain))

    def torque_from_measurements(self, k: int, measurements) -> np.ndarray:
        """Motor torques for sample k, N·m, shape (2,), from one vector.

        Parameters
        ----------
        k : int
            Sample index (t = k·dt).
        measurements : array_like, shape (10,)
            q1, q2 (rad), q̇1, q̇2 (rad/s), ε1..ε6 (rad): the sensors FMU's first ten outputs.
        """
        if self.mode == "ff":
            return self._torque(k, None)
        m = np.asarray(measurements, dtype=float)
        if m.shape != (10,) or not np.isfinite(m).all():
            raise ControllerError(f"measurements: expected 10 finite values (q1, q2 rad; qd1, qd2 rad/s; "
                                  f"eps1..eps6 rad), got {measurements!r}")
        return self._torque(k, m)

    def _torque(self, k: int, m) -> np.ndarray:
        tau = self.feedforward(k)
        if m is None:
            return tau if self.saturation is None else law.saturate(tau, self.saturation)
        kc = self._clamped(k)
        # K (E m − x̂_d) with K E and K x̂_d precomputed; equal to K @ error_estimate(...) up to rounding.
        return law.tracking_torque(tau, self._gains_per_measurement[self._gain_index[kc]], m,
                                   self._gain_offsets[kc], self.saturation)

    def torque(self, t: float, q, qdot, strain) -> np.ndarray:
        """Motor torques at time t (s), N·m, shape (2,); t is rounded to the sample grid."""
        return self.torque_at(self.sample_index(t), q, qdot, strain)


def _estimator_matrix(omega7: str) -> np.ndarray:
    """E, shape (22, 10): x̂ = E m for m = (q1, q2, q̇1, q̇2, ε1..ε6) (eqs. 21-31, module docstring)."""
    est = np.zeros((2 * N, 10))
    for j in range(10):
        m = np.zeros(10)
        m[j] = 1.0
        est[:N, j] = reconstruct_angles(m[0:2], m[4:10])
    est[N + 0, 2] = 1.0
    est[N + 6, 3] = 1.0
    if omega7 == "rigid":
        est[N + 6, 2] = 1.0
    return est


def _measurements(q, qdot, strain) -> np.ndarray:
    """The 10 measurements as one vector, validated (shapes and finiteness)."""
    try:
        m = np.concatenate((q, qdot, strain)).astype(float, copy=False)
        ok = m.shape == (10,) and np.shape(q) == (2,) and np.shape(qdot) == (2,) and np.isfinite(m).all()
    except (ValueError, TypeError):
        ok = False
    if not ok:  # name the offending argument
        _vector(q, 2, "q", "encoder angles in rad")
        _vector(qdot, 2, "qdot", "tachometer rates in rad/s")
        _vector(strain, 6, "strain", "strain-gauge angles in rad")
    return m


def _vector(x, n: int, name: str, what: str) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.shape != (n,) or not np.all(np.isfinite(x)):
        raise ControllerError(f"{name}: expected {n} finite {what}, got {x!r}")
    return x


def simulate_closed_loop(model: ArmModel, controller: TrackingController, n_steps: int | None = None, z0=None,
                         substeps: int | None = None, stop_on_divergence: bool = True):
    """Run the library plant under the controller with noiseless sensors (1 ms).

    Parameters
    ----------
    model : ArmModel
        The plant (e.g. with the 0.275 kg payload the controller does not know).
    controller : TrackingController
    n_steps : int, optional
        Samples to run; default the slew length.
    z0 : array_like, shape (22,), optional
        Initial state; default the trajectory's first state.
    substeps : int, optional
        RODAS4 substeps per 1 ms step; default :data:`flexarm.integrator.DEFAULT_SUBSTEPS`.
    stop_on_divergence : bool
        Stop (returning the partial run) when the plant integration fails.

    Returns
    -------
    states : ndarray, shape (n + 1, 22)
        States at t = 0, dt, ..., n·dt.
    torques : ndarray, shape (n, 2)
        Torque applied over each step, N·m.
    """
    # Imported here: the integrator's Numba kernels cost a third of a second to import, and the reference
    # signals (flexarm.reference, read by every run) need only the sampling of this module.
    from .integrator import DEFAULT_SUBSTEPS, IntegrationError, PlantSimulator

    substeps = DEFAULT_SUBSTEPS if substeps is None else substeps
    n_steps = controller.n_steps if n_steps is None else int(n_steps)
    z0 = controller.z[0] if z0 is None else np.asarray(z0, dtype=float)
    plant = PlantSimulator(model, z0, substeps=substeps)
    states, torques = [plant.z.copy()], []
    for k in range(n_steps):
        th, om = plant.theta, plant.omega
        tau = controller.torque_at(k, joint_angles(th), joint_velocities(om), strain_gauge_angles(th))
        try:
            plant.step(tau, controller.dt)
        except IntegrationError:
            if not stop_on_divergence:
                raise
            break
        torques.append(tau)
        states.append(plant.z.copy())
    return np.array(states), np.array(torques).reshape(-1, 2)


def tracking_errors(states, trajectory) -> dict[str, float]:
    """The tables' error metrics of a run against the trajectory (deg, deg/s).

    Parameters
    ----------
    states : array_like, shape (n + 1, 22)
        Simulated states from t = 0 (runs past the slew are compared with the final state).
    trajectory : TrajectoryResult or path-like

    Returns
    -------
    dict
        ``pos_peak``, ``vel_peak`` (max over all 11 elements and samples),
        ``pos_rms``, ``vel_rms`` (rms over all 11 elements and samples).
    """
    traj = as_trajectory(trajectory)
    states = np.asarray(states, dtype=float)
    idx = np.minimum(np.arange(len(states)), traj.n_samples)
    err = np.degrees(states - desired_states(traj)[idx])
    pos, vel = err[:, :N], err[:, N:]
    return {"pos_peak": float(np.abs(pos).max()), "vel_peak": float(np.abs(vel).max()),
            "pos_rms": float(np.sqrt(np.mean(pos**2))), "vel_rms": float(np.sqrt(np.mean(vel**2)))}
