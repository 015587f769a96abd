"""The LQG tracking controller (issue 14): Kalman filter, delay predictor, discrete LQR, integral action.

No FMI here: ``fmus/controller/flexarm_controller_lqg_fmu.py`` wraps
:class:`LqgController`. The design data come from :mod:`flexarm.lqg_design`.

Each 1 ms sample k the controller receives the ten measurements m (encoders,
tachometers, gauges) and returns the torques. With ``loop_delay_samples = d``
the master delivers at sample k the measurement of the plant state at k − d
(Jacobi stepping with separate sensors and controller FMUs: d = 2), and the
torque it returns acts from sample k on. Per sample, with δ meaning "minus the
desired value" and j = k − d:

1. time update of the filter to sample j with the torque sent at j − 1:
   x̂⁻_j = Φ x̂⁺_{j−1} + Γ δu_{j−1};
2. measurement update: x̂⁺_j = x̂⁻_j + M (δm − C x̂⁻_j);
3. prediction across the delay with the torques already sent (exact for the
   linear model): x̂_k = Φ^d x̂⁺_j + Σ_i Φ^{k−1−i} Γ δu_i, i = j .. k−1;
4. δu_k = −K x̂_k − K_ξ ξ_k, τ_k = sat(τ_ff(k) + u_k + δu_k) with u_k a learned
   feedforward correction (:mod:`flexarm.ilc`, zero without one); the
   saturated τ_k − τ_ff(k) is what the filter and predictor use next;
5. integral action (optional): ξ_{k+1} = ξ_k + dt·C_q x̂_k, frozen in a sample
   whose torque saturates (conditional integration: no wind-up).

Φ, Γ, M, K are those of the schedule point in force at each sample. Before
the first measurement's time (k < d) the filter stays at sample 0.
After the slew the controller holds the final desired state (τ_ff = 0) with the
design's last point, the hold at t_f: its filter is linearised at the end state
at rest and its gains regulate it with :data:`flexarm.lqg_design.HOLD_STATE_WEIGHT`
whatever the gain set (the tip settles within about 1 s instead of 10-40 s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import control_law, filter_law
from .gain_schedule import as_trajectory, desired_states, sample_time
from .lqg_design import LqgDesign, TransientGains
from .model import N_STATE
from .trajectory.io import SAMPLE_TIME

#: Largest loop delay the predictor accepts, samples (the FMU's ``loop_delay_samples`` range).
MAX_DELAY_SAMPLES = 10


class LqgError(ValueError):
    """An LQG controller setting or input is invalid."""


@dataclass
class LqgState:
    """What the controller carries from one sample to the next.

    Attributes
    ----------
    k : int
        Next sample to compute.
    x_post : ndarray, shape (22,)
        Posterior error estimate at the filter's sample max(k − 1 − d, 0).
    du : ndarray, shape (d + 1, 2)
        Torque deviations τ − τ_ff sent at samples k − 1 − d .. k − 1 (oldest first), N·m.
    xi : ndarray, shape (2,)
        Integrated joint-angle errors, rad·s.
    started : bool
        Whether the filter has taken a measurement.
    """

    k: int
    x_post: np.ndarray
    du: np.ndarray
    xi: np.ndarray
    started: bool = False

    def as_dict(self) -> dict:
        """JSON-serialisable form (FMU state)."""
        return {"k": self.k, "x_post": self.x_post.tolist(), "du": self.du.tolist(), "xi": self.xi.tolist(),
                "started": self.started}

    @classmethod
    def from_dict(cls, d: dict) -> LqgState:
        """Inverse of :meth:`as_dict`."""
        return cls(int(d["k"]), np.array(d["x_post"], dtype=float), np.array(d["du"], dtype=float).reshape(-1, 2),
                   np.array(d["xi"], dtype=float), bool(d["started"]))


def check_loop_delay(value) -> int:
    """``loop_delay_samples`` as an int, or :class:`LqgError` naming the allowed range."""
    if isinstance(value, bool) or int(value) != value or not 0 <= value <= MAX_DELAY_SAMPLES:
        raise LqgError(f"loop_delay_samples: must be an integer in 0..{MAX_DELAY_SAMPLES}, got {value!r}")
    return int(value)


def check_saturation(value) -> np.ndarray:
    """Torque limits |τ1|, |τ2| (N·m) as an array of shape (2,), or :class:`LqgError`."""
    sat = np.asarray(value, dtype=float)
    if sat.shape != (2,) or not np.all(np.isfinite(sat)) or np.any(sat <= 0):
        raise LqgError(f"saturation: two finite torque limits > 0 N·m, got {value!r}")
    return sat


def check_correction(value) -> np.ndarray | None:
    """A learned feedforward correction (:mod:`flexarm.ilc`) as an array of shape (m, 2) N·m, None for none, or
    :class:`LqgError`."""
    if value is None:
        return None
    corr = np.array(value, dtype=float)
    if corr.ndim != 2 or corr.shape[1] != 2 or not np.isfinite(corr).all():
        raise LqgError(f"feedforward_correction: finite values of shape (m, 2) N·m, got shape {corr.shape}")
    return corr


def correction_at(correction: np.ndarray | None, k: int) -> np.ndarray:
    """Row k of a learned correction (N·m, shape (2,)); zero past its end or without one."""
    return correction[k].copy() if correction is not None and k < len(correction) else np.zeros(2)


def check_sample_input(state_k: int, k: int, measurements) -> np.ndarray:
    """The ten measurements of sample k as an array, or :class:`LqgError` (wrong sample, shape or value)."""
    if k != state_k:
        raise LqgError(f"k: the controller is at sample {state_k}, got sample {k} (one call per sample)")
    m = np.asarray(measurements, dtype=float)
    if m.shape != (10,) or not np.isfinite(m).all():
        raise LqgError(f"measurements: expected 10 finite values (q1, q2 rad; qd1, qd2 rad/s; "
                       f"eps1..eps6 rad), got {measurements!r}")
    return m


class LqgController:
    """Feedforward + LQG tracking controller with a 1 ms stepping API.

    Parameters
    ----------
    trajectory : TrajectoryResult or path-like
    design : LqgDesign
    gain_set : str
        Weight name (:data:`flexarm.gain_sets.WEIGHT_NAMES`; a ``dlqr-`` prefix is ignored).
    loop_delay_samples : int
        Samples between the plant state and the measurement the controller receives, 0..10.
    integral_action : bool
        Feed back the integrated joint-angle errors (anti-windup by conditional integration).
    saturation : (float, float)
        Torque limits |τ1|, |τ2|, N·m.
    feedforward_correction : array_like, shape (m, 2), optional
        A learned correction (N·m, :mod:`flexarm.ilc`) added to the feedforward of samples 0..m−1. The
        filter's input stays the deviation from the nominal feedforward it was linearised about
        (τ − τ_ff, correction included), so it predicts the correction's effect.
    initial_covariance : float, optional
        Run the filter as the time-varying Kalman filter over the slew, its prior covariance at sample 0 this
        factor times the design's steady prior there (:func:`flexarm.lqg_design.transient_gains`); None: the
        design's steady gain of each schedule point throughout.
    """

    def __init__(self, trajectory, design: LqgDesign, gain_set: str = "gamma0.1", loop_delay_samples: int = 0,
                 integral_action: bool = False, saturation=(7.0, 2.25), feedforward_correction=None,
                 initial_covariance: float | None = None):
        delay, sat = check_loop_delay(loop_delay_samples), check_saturation(saturation)
        self.correction = check_correction(feedforward_correction)
        self.trajectory = as_trajectory(trajectory)
        #: Desired states at every sample, shape (n_steps + 1, 22).
        self.z = desired_states(self.trajectory)
        self.design = design
        self.gain_set = gain_set
        self.delay = delay
        self.integral_action = bool(integral_action)
        self.saturation = sat
        self.dt = sample_time(self.trajectory)
        self.n_steps = self.trajectory.n_samples
        w = design.weight_index(gain_set)
        self._K = design.K_integral[:, w, :, :N_STATE] if integral_action else design.K[:, w]
        self._K_xi = design.K_integral[:, w, :, N_STATE:] if integral_action else None
        self._index = np.array([design.index_at(k * self.dt) for k in range(self.n_steps + 1)])
        self._y_d = self.z @ design.C.T  # desired measurements (the sensor map is linear)
        #: The filter's gain of samples 0 .. n_steps − 1, made as the run reaches them (None: the design's steady
        #: gain of each point).
        self.gains = None if initial_covariance is None else TransientGains(design, self._index[:-1],
                                                                          initial_covariance)
        self._Cq = design.C[0:2]

    # -- trajectory lookup --------------------------------------------------------------
    def sample_index(self, t: float) -> int:
        """Sample k of time t (s): the nearest multiple of dt (t ≥ 0)."""
        if not np.isfinite(t) or t < -0.5 * self.dt:
            raise LqgError(f"t: must be a finite time >= 0 s, got {t!r}")
        return int(round(t / self.dt))

    def desired_measurement(self, j: int) -> np.ndarray:
        """The ten measurements the trajectory predicts for the plant's sample j (zero innovation): the law's
        y_d, the row the native twin reads (fmus/native/lqg_resources.py writes the same expression)."""
        return self._y_d[self._c(max(int(j), 0))].copy()

    def _c(self, k: int) -> int:
        return min(k, self.n_steps)

    def feedforward(self, k: int) -> np.ndarray:
        """Feedforward torque of sample k, N·m: τ[k] during the slew, 0 after."""
        return self.trajectory.tau[k].copy() if k < self.n_steps else np.zeros(2)

    def initial_state(self) -> LqgState:
        """The state at t = 0: on the trajectory, nothing sent, integrators empty."""
        return LqgState(0, np.zeros(N_STATE), np.zeros((self.delay + 1, 2)), np.zeros(2))

    # -- the law --------------------------------------------------------------------------
    def estimate(self, state: LqgState, k: int, measurements) -> tuple[np.ndarray, np.ndarray]:
        """Filter and predictor of steps 1-3 (module docstring).

        Returns
        -------
        x_post : ndarray, shape (22,)
            Posterior error estimate at sample j = max(k − d, 0).
        x_now : ndarray, shape (22,)
            Predicted error at sample k.
        """
        d = self.delay
        j = max(k - d, 0)
        i_j = self._index[self._c(j)]
        x = state.x_post
        if state.started and j > 0 and k - d >= 0:  # time update from j − 1 with the torque sent then
            i_p = self._index[self._c(j - 1)]
            x = filter_law.time_update(self.design.Phi[i_p], self.design.Gamma[i_p], x, state.du[0])
        gain = self.design.M[i_j] if self.gains is None or j >= len(self.gains) else self.gains[j]
        x_post = filter_law.corrected(x, gain, self.design.C, np.asarray(measurements, dtype=float),
                                      self._y_d[self._c(j)])
        x_now = x_post
        sent = state.du[1:] if k - d >= 0 else state.du[d + 1 - k:]  # torques of samples j .. k − 1
        for n, du in enumerate(sent):
            i_s = self._index[self._c(j + n)]
            x_now = filter_law.time_update(self.design.Phi[i_s], self.design.Gamma[i_s], x_now, du)
        return x_post, x_now

    def step(self, state: LqgState, k: int, measurements) -> tuple[np.ndarray, LqgState]:
        """Torques of sample k and the state after it (``state`` is not changed).

        Parameters
        ----------
        state : LqgState
            The state after sample k − 1 (:meth:`initial_state` for k = 0).
        k : int
            Sample index, t = k·dt; must be ``state.k``.
        measurements : array_like, shape (10,)
            q1, q2 (rad), q̇1, q̇2 (rad/s), ε1..ε6 (rad), of the plant state at k − d.

        Returns
        -------
        tau : ndarray, shape (2,)
            Motor torques, N·m.
        new_state : LqgState
        """
        m = check_sample_input(state.k, k, measurements)
        x_post, x_now = self.estimate(state, k, m)
        i_k = self._index[self._c(k)]
        ff = self.feedforward(k)
        command = control_law.corrected_feedforward(ff, correction_at(self.correction, k))
        integral = (self._K_xi[i_k], state.xi) if self.integral_action else ()
        tau_free = filter_law.free_torque(command, self._K[i_k], x_now, *integral)
        tau = control_law.saturate(tau_free, self.saturation)
        xi = state.xi
        if self.integral_action:
            xi = filter_law.integrated(xi, self.dt, self._Cq, x_now, tau, tau_free)
        du = np.vstack([state.du[1:], tau - ff])
        return tau, LqgState(k + 1, x_post, du, xi, True)


#: The predicting law's prior covariance at sample 0, a factor of the design's steady prior there
#: (:class:`PredictedTracking`): large enough that the first samples' estimate follows the measurements. The
#: velocity error it gives is flat from about 1e4 to 1e9 (``benchmarks/study_paper_law_delay.py``).
PREDICTOR_PRIOR = 1e6
#: The predicting law's offset: its feedback acts on the predicted deviation C x̂, already about the trajectory.
_NO_OFFSET = np.zeros(2)


class PredictedTracking:
    """The paper's tracking law over a loop delay of d ≥ 1 samples (issue 31): predict, then the paper's gains.

    The paper's law (:class:`flexarm.control.TrackingController`) feeds back the state reconstructed from the
    measurement of the sample it computes; in a Jacobi master that measurement is d samples old, and the stiff
    γ = 0.1 loop goes unstable on it. Here the LQG design's Kalman filter of the same schedule takes the
    measurement of sample k − d and predicts the error state to sample k with the torques actually sent
    (:meth:`LqgController.estimate`, the linearised model along the slew), as the time-varying Kalman filter from
    a large prior covariance (:data:`PREDICTOR_PRIOR`, :func:`flexarm.lqg_design.transient_gains`): over the first
    half second, where the feedforward rings the arm hardest, its estimate follows the measurements instead of
    leaning on the model, which is what the delay-free law does. The paper's law then runs on the
    measurement that prediction gives for sample k, m_d(k) + C x̂_k: its own reconstruction (eqs. 21-31, E) and its
    reduced gain in force at k, τ_k = sat(τ_ff(k) − K(t_k) E C x̂_k), the loop a Gauss-Seidel master runs with
    the true measurement. (The reduced gain on the filter's whole state, K(t_k) x̂_k, is a different loop: the filter's
    eleven angles and nine velocities are not the reconstruction's, and it doubled the rms velocity error.)
    Feedforward, gains, saturation and the learned correction are the paper law's; with d = 0 use that law itself.
    What it gives against the delay-free law: ``benchmarks/study_paper_law_delay.py``.

    Parameters
    ----------
    law : TrackingController
        The paper's law (any mode; ``"ff"`` has no gains and sends the feedforward).
    design : LqgDesign
        The LQG design of the law's schedule (the same switching times).
    delay : int
        Loop delay, samples, 1..:data:`MAX_DELAY_SAMPLES`.
    """

    def __init__(self, law, design: LqgDesign, delay: int):
        delay = check_loop_delay(delay)
        if delay < 1:
            raise LqgError("delay: PredictedTracking is for a delay of 1 or more samples (0: the law itself)")
        if law.schedule is not None and not np.array_equal(np.asarray(law.schedule.times), design.slew_times):
            raise LqgError(f"design: schedule {design.schedule!r} switches at other times than the law's gains")
        self.law, self.delay, self.dt, self.n_steps = law, delay, law.dt, law.n_steps
        # its filter and predictor only: its gains, feedforward correction and saturation are not used; the
        # time-varying filter from a large prior: the first half second follows the measurements
        self.filter = LqgController(law.trajectory, design, "gamma0.1", delay, initial_covariance=PREDICTOR_PRIOR)

    def initial_state(self) -> LqgState:
        """On the trajectory, nothing sent."""
        return self.filter.initial_state()

    def desired_measurement(self, j: int) -> np.ndarray:
        """The ten measurements the trajectory predicts for the plant's sample j (zero innovation)."""
        return self.filter.desired_measurement(j)

    def step(self, state: LqgState, k: int, measurements) -> tuple[np.ndarray, LqgState]:
        """Torques of sample k from the measurement of sample k − d, and the state after it (`state` unchanged).

        Parameters
        ----------
        state : LqgState
            After sample k − 1 (:meth:`initial_state` for k = 0).
        k : int
            Sample index; must be ``state.k``.
        measurements : array_like, shape (10,)
            q1, q2 (rad), q̇1, q̇2 (rad/s), ε1..ε6 (rad) of the plant at max(k − d, 0) (before k = d: the
            desired measurement of t = 0).
        """
        m = check_sample_input(state.k, k, measurements)
        x_post, x_now = self.filter.estimate(state, k, m)
        # the paper's law on the measurement predicted for k, m_d(k) + C x̂_k: its reconstruction, its gains
        tau = control_law.tracking_torque(self.law.feedforward(k), self.law.gain_per_measurement(k),
                                          filter_law.measured(self.filter.design.C, x_now), _NO_OFFSET,
                                          self.law.saturation)
        du = np.vstack([state.du[1:], tau - self.filter.feedforward(k)])  # about the nominal feedforward
        return tau, LqgState(k + 1, x_post, du, state.xi, True)


def lqg_controller(gain_set: str = "gamma0.1", schedule: str = "200ms", loop_delay_samples: int = 0,
                   integral_action: bool = False, saturation=None, feedforward_correction=None) -> LqgController:
    """The controller on the committed trajectory and LQG design files (torque limits from the parameter file;
    `feedforward_correction`: a learned correction, :class:`LqgController`)."""
    from .gain_schedule import default_trajectory_path
    from .parameters import load_parameters

    sat = load_parameters().peak_torque if saturation is None else saturation
    return LqgController(default_trajectory_path(), LqgDesign.load(schedule), gain_set, loop_delay_samples,
                         integral_action, sat, feedforward_correction)


def simulate_lqg(model, controller: LqgController, n_steps: int | None = None, plant_delay: int | None = None,
                 sensors=None, z0=None, substeps: int | None = None):
    """Run the library plant under an LQG controller, the measurement delayed by ``plant_delay`` samples.

    Parameters
    ----------
    model : ArmModel
        The plant (e.g. with the payload the controller does not know).
    controller : LqgController
    n_steps : int, optional
        Samples; default the slew length.
    plant_delay : int, optional
        The loop's real delay (default the controller's ``loop_delay_samples``): the measurement
        the controller gets at sample k is that of the state at max(k − plant_delay, 0).
    sensors : flexarm.sensors.SensorBank, optional
        Noise source (None: exact measurements).
    z0 : array_like, shape (22,), optional
        Initial state (default the trajectory's first state).
    substeps : int, optional
        RODAS4 substeps per step.

    Returns
    -------
    states : ndarray, shape (n + 1, 22)
    torques : ndarray, shape (n, 2)

    Raises
    ------
    flexarm.integrator.IntegrationError
        When the plant diverges.
    """
    from .integrator import DEFAULT_SUBSTEPS, PlantSimulator
    from .sensors import true_signals_from_state

    n_steps = controller.n_steps if n_steps is None else int(n_steps)
    delay = controller.delay if plant_delay is None else int(plant_delay)
    z0 = controller.z[0] if z0 is None else np.asarray(z0, dtype=float)
    plant = PlantSimulator(model, z0, substeps=substeps or DEFAULT_SUBSTEPS)
    C = controller.design.C
    state = controller.initial_state()
    states, torques, measured = [plant.z.copy()], [], []
    for k in range(n_steps):
        if sensors is None:
            measured.append(C @ plant.z)
        else:
            tau_prev = torques[-1] if torques else np.zeros(2)
            measured.append(sensors.measure(true_signals_from_state(model, plant.z, tau_prev))[:10])
        tau, state = controller.step(state, k, measured[max(k - delay, 0)])
        plant.step(tau, controller.dt)
        torques.append(tau)
        states.append(plant.z.copy())
    return np.array(states), np.array(torques).reshape(-1, 2)


#: Master stepping algorithms (the names of :mod:`scenarios.master.cosim`).
STEPPINGS = ("gauss-seidel", "jacobi")


def required_loop_delay(stepping: str, feedthrough_fmus: int = 2, samples_per_step: int = 1) -> int:
    """The ``loop_delay_samples`` a master's stepping puts into the loop.

    Parameters
    ----------
    stepping : {"gauss-seidel", "jacobi"}
        Gauss-Seidel (our master's default: each FMU reads its inputs after
        the FMUs before it updated) adds no delay. Jacobi (libcosim's fixed-step
        algorithm, fmpy's ``simulate_ssp``: all outputs read, then all inputs
        set) adds one communication step per direct-feedthrough FMU the signal
        crosses.
    feedthrough_fmus : int
        Direct-feedthrough FMUs from the plant's outputs to its torque inputs,
        the controller included: 2 with a separate sensors FMU, 1 when the
        controller reads the plant directly.
    samples_per_step : int
        The master's communication step in controller samples (1 ms each):
        a Jacobi master stepping h = n ms delays by ``feedthrough_fmus`` · n
        samples at its communication points.

    Returns
    -------
    int
        Samples (0..:data:`MAX_DELAY_SAMPLES`).

    Raises
    ------
    LqgError
        For an unknown stepping, bad counts, or a delay beyond :data:`MAX_DELAY_SAMPLES`.
    """
    if stepping not in STEPPINGS:
        raise LqgError(f"stepping: {stepping!r} is not one of {STEPPINGS}")
    if isinstance(feedthrough_fmus, bool) or not isinstance(feedthrough_fmus, int) \
            or not 1 <= feedthrough_fmus <= MAX_DELAY_SAMPLES:
        raise LqgError(f"feedthrough_fmus: an integer in 1..{MAX_DELAY_SAMPLES}, got {feedthrough_fmus!r}")
    if isinstance(samples_per_step, bool) or not isinstance(samples_per_step, int) or samples_per_step < 1:
        raise LqgError(f"samples_per_step: an integer >= 1 (the communication step in 1 ms samples), "
                       f"got {samples_per_step!r}")
    delay = 0 if stepping == "gauss-seidel" else feedthrough_fmus * samples_per_step
    if delay > MAX_DELAY_SAMPLES:
        raise LqgError(f"samples_per_step: Jacobi stepping of {samples_per_step} samples through {feedthrough_fmus} "
                       f"feedthrough FMUs delays the loop by {delay} samples, more than the predictor covers "
                       f"(loop_delay_samples 0..{MAX_DELAY_SAMPLES}); step at most "
                       f"{MAX_DELAY_SAMPLES // feedthrough_fmus} ms")
    return delay


def with_loop_delay(parameters: dict, stepping: str, feedthrough_fmus: int = 2, step_size: float | None = None) -> dict:
    """A controller's parameters for a target master: ``loop_delay_samples`` set to :func:`required_loop_delay`.

    For exports (SSP) to masters that step differently from the scenario's own:
    the returned copy has ``loop_delay_samples`` replaced; other keys are kept.
    `step_size` is the master's communication step in s (None: one sample,
    :data:`flexarm.trajectory.io.SAMPLE_TIME`); it must be a whole multiple of
    the sample.
    """
    samples = 1
    if step_size is not None:
        samples = int(round(step_size / SAMPLE_TIME))
        if not np.isfinite(step_size) or samples < 1 or abs(step_size / SAMPLE_TIME - samples) > 1e-6:
            raise LqgError(f"step_size: {step_size!r} s is not a whole multiple of the controller's sample "
                           f"({SAMPLE_TIME:g} s)")
    out = dict(parameters)
    out["loop_delay_samples"] = required_loop_delay(stepping, feedthrough_fmus, samples)
    return out
