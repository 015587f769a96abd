"""A multiple-model LQG: a bank of Kalman filters, one per payload mass (issue 14's two goals at once).

The committed LQG (:mod:`flexarm.lqg`) absorbs the unknown payload as white process noise in its
filter, which makes the filter fast and lets the sensors' noise through; a filter that trusts the
model keeps the noise out and the payload in (:mod:`flexarm.lqg_tradeoff`). Here the payload is a
*known family of models* instead.

Identification filters
    One per payload mass m on a grid (:data:`DEFAULT_MASSES`), each designed by
    :func:`flexarm.lqg_design.design_lqg` on the arm with that payload (``params.with_payload(m)``)
    linearised about the desired trajectory and the nominal feedforward τ_ff, with the committed
    motor and element process noise but no tip force. Each carries the affine drift of its model
    along the path: τ_ff is designed for m = 0, so a loaded arm does not stay on z_d,

        δx_{j+1} = Φ_m δx_j + Γ_m δu_j + d_m,j,   d_m,j = Ψ_m [0; α_m(z_d,j, τ_ff,j) − α_0(z_d,j, τ_ff,j)]

    (Ψ = ∫₀^dt e^{As} ds at the schedule point, α the element accelerations of eq. 5, rad/s²):
    that drift is what the payload does. Each innovation e (at the filter's sample j = k − d) adds
    its Gaussian log-likelihood −½(eᵀS⁻¹e + log det S), S = C P⁻ Cᵀ + V, to the model's log
    posterior; the posterior is floored at :data:`POSTERIOR_FLOOR` so that the bank can switch.
Quiet filter
    The arm without payload with model-trusting process noise (motor and element terms ×
    :data:`QUIET_SCALE`): it stands in for the m = 0 model in the control law, so that with no
    payload the sensors' noise stays out. So little process noise leaves the arm's 190-290 Hz modes,
    undamped in the model, almost uncorrected: the plain Kalman gain put its slowest estimator pole at
    |λ| = 0.999999 (a 1000 s time constant) and made the gain a property of the CPU (M regenerated to
    6e-6 of its peak across OpenBLAS kernels). Its gain is therefore designed with a prescribed degree of
    stability (:data:`QUIET_POLE_RADIUS`, :func:`flexarm.lqg_design.kalman_gain`): every estimator pole
    within |λ| ≤ 0.9996 (2.6 s), faster than the identification filters' 0.9999, M reproducible to 4e-8.
    Its likelihood is not used (a model-trusting filter's
    small S would win or lose on its confidence, not on the mass). While the posterior has ruled
    out the unloaded arm (p_0 < :data:`QUIET_RESEED_BELOW`) it is re-seeded from the unloaded
    identification filter's estimate each sample, so that a later switch to m = 0 starts from an
    estimate of the real arm rather than one it drifted to under the payload. (Re-seeding at a
    higher p_0 lets noise in: at p_0 < 0.01 the γ = 1 noise ratio is ×6.9 instead of ×1.4.)

The torque is τ_ff + Σ_m p_m (−K_m x̂_m − K_ξ,m ξ) with the posterior p (``select="mixture"``)
or the most probable model alone (``"map"``); K_m the LQR gains of model m's design. Every filter
predicts across the loop delay as :class:`flexarm.lqg.LqgController` does (drift included), and
the integrators ξ integrate the weighted joint-angle estimate (conditional integration, no wind-up).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import control_law, filter_law
from .gain_schedule import (
    GainError,
    as_trajectory,
    default_trajectory_path,
    desired_states,
    read_design_files,
    sample_time,
    write_design_files,
)
from .lqg import (
    LqgController,
    LqgError,
    check_correction,
    check_loop_delay,
    check_sample_input,
    check_saturation,
    correction_at,
)
from .lqg_design import DEFAULT_LQG_DIR, ELEMENT_FORCE_SIGMA, MOTOR_TORQUE_SIGMA, LqgDesign, design_lqg
from .lqr_design import scaling_transform, zoh
from .model import N_STATE, ArmModel, N
from .parameters import ArmParameters

#: Payload masses of the identification filters, kg.
DEFAULT_MASSES = (0.0, 0.025, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4)
#: Scale of the committed motor and element process-noise terms in the quiet filter.
QUIET_SCALE = 0.01
#: Largest estimator pole magnitude of the quiet filter's design (the Kalman gain of Φ/α; its poles come out
#: at about α², 0.9996, a 2.6 s time constant at 1 ms). 0.9995 lets noise in (γ = 1 with integral action:
#: noisy ÷ quiet 1.95 against issue 14's 2), 0.9999 keeps more noise out but M reproduces only to 9e-8.
QUIET_POLE_RADIUS = 0.9998
#: Smallest posterior probability of a model (lets the bank switch).
POSTERIOR_FLOOR = 1e-4
#: Posterior of the unloaded model below which the quiet filter is re-seeded (10 × the floor).
QUIET_RESEED_BELOW = 1e-3
SELECTIONS = ("mixture", "map")
#: Schedules that have a committed bank (the 20 ms one would be ten times the size for no measured gain).
BANK_SCHEDULES = ("200ms",)
BANK_FILE_FORMAT = "flexarm-lqg-bank/1"
#: What each filter's design keeps in the bank file (what the control law and the likelihoods use).
BANK_DESIGN_ARRAYS = ("times", "operating_points", "tau_bar", "Phi", "Gamma", "W", "M", "P_prior", "P_post",
                      "K", "K_integral", "C", "V")


def drift_along_path(design: LqgDesign, psi: np.ndarray, delta_acceleration: np.ndarray, dt: float) -> np.ndarray:
    """The state drift d_j = Ψ_i(j) Δα_j over each sample (rad, rad/s), shape (n_steps + 1, 22).

    Parameters
    ----------
    design : LqgDesign
        Gives the schedule point i(j) in force at t_j = j dt.
    psi : ndarray, shape (n_points, 22, 11)
        ∫₀^dt e^{As} ds E per point (E puts an acceleration on the velocity rows), s, s².
    delta_acceleration : ndarray, shape (n_steps + 1, 11)
        α_m − α_0 along the path, rad/s².
    dt : float
        s.
    """
    return np.array([filter_law.state_drift(psi[design.index_at(j * dt)], a) for j, a in enumerate(delta_acceleration)])


@dataclass
class BankModel:
    """One filter of the bank.

    Attributes
    ----------
    mass : float
        Payload mass of its model, kg.
    design : LqgDesign
        The LQG designed on the arm with that payload.
    psi : ndarray, shape (n_points, 22, 11)
        Ψ E per schedule point: the state change over a sample from an element acceleration held over it.
    delta_acceleration : ndarray, shape (n_steps + 1, 11)
        α_m − α_0 at (z_d,j, τ_ff,j): what the payload adds to the element accelerations, rad/s².
    S_inv : ndarray, shape (n_points, 10, 10)
        Inverse innovation covariances per schedule point (1/rad², s²/rad²).
    log_det_S : ndarray, shape (n_points,)
    drift : ndarray, shape (n_steps + 1, 22)
        d_j = Ψ Δα_j: the state drift over the sample from j under τ_ff (rad, rad/s); derived.
    """

    mass: float
    design: LqgDesign
    psi: np.ndarray
    delta_acceleration: np.ndarray
    S_inv: np.ndarray
    log_det_S: np.ndarray
    drift: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        dt = float(self.design.metadata["sample_time_s"])  # every design records its sample
        self.drift = drift_along_path(self.design, self.psi, self.delta_acceleration, dt)


@dataclass
class PayloadBank:
    """The identification filters (increasing mass, the first without payload) and the quiet filter."""

    models: list[BankModel]
    quiet: BankModel
    metadata: dict = field(default_factory=dict)

    @property
    def masses(self) -> np.ndarray:
        """Payload masses of the identification filters, kg, shape (n_models,)."""
        return np.array([b.mass for b in self.models])

    @property
    def filters(self) -> list[BankModel]:
        """The identification filters, then the quiet filter (the order of the file's arrays)."""
        return self.models + [self.quiet]

    @property
    def schedule(self) -> str:
        return self.quiet.design.schedule

    def save(self, directory=None) -> Path:
        """Write ``bank_<schedule>.npz`` and ``.json`` atomically; returns the npz path.

        Each array is stacked over the filters (identification filters by mass, the quiet filter last).
        """
        directory = Path(directory) if directory is not None else DEFAULT_LQG_DIR
        arrays = {name: np.array([getattr(b.design, name) for b in self.filters]) for name in BANK_DESIGN_ARRAYS}
        arrays.update(masses=self.masses, **{name: np.array([getattr(b, name) for b in self.filters])
                                             for name in ("psi", "delta_acceleration", "S_inv", "log_det_S")})
        return write_design_files(directory / f"bank_{self.schedule}", arrays,
                                  dict(self.metadata, format=BANK_FILE_FORMAT, schedule=self.schedule))

    @classmethod
    def load(cls, schedule: str = "200ms", directory=None) -> PayloadBank:
        """Load a committed bank, checking its data chain (:func:`flexarm.gain_schedule.read_design_metadata`).

        Raises
        ------
        GainError
            If ``schedule`` has no bank or the file is missing; StaleDataError if its inputs changed.
        """
        if schedule not in BANK_SCHEDULES:
            raise GainError(f"schedule: the payload bank exists for {BANK_SCHEDULES}, not {schedule!r}")
        directory = Path(directory) if directory is not None else DEFAULT_LQG_DIR
        meta, a = read_design_files(directory / f"bank_{schedule}", "LQG bank file", data_dir=directory.parent)
        if meta.get("format") != BANK_FILE_FORMAT:
            raise GainError(f"{directory / f'bank_{schedule}.npz'}: format {meta.get('format')!r}, expected "
                            f"{BANK_FILE_FORMAT!r}")
        filters = []
        for f, mass in enumerate(list(a["masses"]) + [0.0]):
            design = LqgDesign(schedule=schedule, metadata=meta["designs"][f],
                               **{name: a[name][f] for name in BANK_DESIGN_ARRAYS})
            filters.append(BankModel(float(mass), design, a["psi"][f], a["delta_acceleration"][f],
                                     a["S_inv"][f], a["log_det_S"][f]))
        return cls(filters[:-1], filters[-1], meta)


def design_bank_model(params: ArmParameters, mass: float, trajectory=None, schedule: str = "200ms",
                      model_scale: float = 1.0, estimator_pole_radius: float = 1.0) -> BankModel:
    """One filter: the LQG of the arm with payload ``mass`` (kg), its drift along the path and its S.

    Parameters
    ----------
    params : ArmParameters
        The arm (its own payload is replaced by ``mass``).
    mass : float
        kg.
    trajectory : TrajectoryResult or path-like, optional
        Default the committed trajectory.
    schedule : str
    model_scale : float
        Scale of the committed motor and element process-noise terms (no tip force in W).
    estimator_pole_radius : float
        Largest magnitude of an estimator pole (:func:`flexarm.lqg_design.kalman_gain`), 1 for the plain filter.
    """
    trajectory = default_trajectory_path() if trajectory is None else trajectory
    traj = as_trajectory(trajectory)
    nominal, loaded = ArmModel(params.with_payload(0.0)), ArmModel(params.with_payload(mass))
    design = design_lqg(loaded, trajectory, schedule, payload_mass=0.0,
                        motor_torque_sigma=model_scale * MOTOR_TORQUE_SIGMA,
                        element_force_sigma=model_scale * ELEMENT_FORCE_SIGMA,
                        estimator_pole_radius=estimator_pole_radius)
    z, dt, n = desired_states(traj), sample_time(traj), traj.n_samples
    E = np.zeros((N_STATE, N))
    E[N:] = np.eye(N)
    psi = []  # Ψ[:, N:] per point: the state change over a sample from an acceleration held over it
    for zb, tb in zip(design.operating_points, design.tau_bar):
        A, _ = loaded.linearize(zb, tb)
        T = scaling_transform(loaded, zb)
        Ti = np.linalg.inv(T)
        psi.append(T @ zoh(Ti @ A @ T, Ti @ E, dt)[1])
    d_alpha = np.zeros((n + 1, N))
    if mass != 0.0:  # the unloaded arm is the nominal one: no drift
        for j in range(n + 1):
            tau = traj.tau[j] if j < n else np.zeros(2)
            th, om = z[j, :N], z[j, N:]
            d_alpha[j] = loaded.acceleration(th, om, tau) - nominal.acceleration(th, om, tau)
    S = design.C @ design.P_prior @ design.C.T + design.V
    return BankModel(float(mass), design, np.array(psi), d_alpha, np.linalg.inv(S), np.linalg.slogdet(S)[1])


def design_bank(params: ArmParameters, masses=DEFAULT_MASSES, trajectory=None, schedule: str = "200ms",
                quiet_scale: float = QUIET_SCALE, quiet_pole_radius: float = QUIET_POLE_RADIUS) -> PayloadBank:
    """The identification filters for ``masses`` (kg, increasing, the first 0) and the quiet filter.

    Raises
    ------
    LqgError
        If the masses are not increasing from 0.
    """
    masses = [float(m) for m in masses]
    if len(masses) < 2 or masses[0] != 0.0 or np.any(np.diff(masses) <= 0):
        raise LqgError(f"masses: at least two increasing payload masses starting at 0 kg, got {masses!r}")
    models = [design_bank_model(params, m, trajectory, schedule) for m in masses]
    quiet = design_bank_model(params, 0.0, trajectory, schedule, quiet_scale, quiet_pole_radius)
    first = quiet.design.metadata
    meta = {
        "description": "multiple-model LQG: one Kalman filter per payload mass (the arm with that payload, "
                       "its drift along the path under tau_ff) and a model-trusting quiet filter of the unloaded "
                       "arm (flexarm.lqg_bank); arrays stacked over the filters, the quiet filter last",
        "masses_kg": masses, "quiet_scale": quiet_scale, "quiet_pole_radius": quiet_pole_radius,
        "posterior_floor": POSTERIOR_FLOOR, "quiet_reseed_below": QUIET_RESEED_BELOW,
        **{k: first[k] for k in ("sample_time_s", "trajectory_file", "trajectory_sha256", "parameter_file",
                                 "parameter_sha256", "commit", "created_utc", "versions", "weights",
                                 "measurements", "operating_times_s")},
        "designs": [b.design.metadata for b in models + [quiet]],
    }
    return PayloadBank(models, quiet, meta)


@functools.lru_cache(maxsize=2)
def load_bank(schedule: str = "200ms") -> PayloadBank:
    """The committed bank of a schedule, loaded once per process (treat it as read-only)."""
    return PayloadBank.load(schedule)


def bank_controller(gain_set: str = "gamma0.1", schedule: str = "200ms", loop_delay_samples: int = 0,
                    integral_action: bool = False, saturation=None, feedforward_correction=None) -> BankController:
    """The multiple-model LQG of the committed trajectory and bank (as :func:`flexarm.lqg.lqg_controller`;
    torque limits from the parameter file by default). It keeps no posterior history."""
    from .parameters import load_parameters

    sat = load_parameters().peak_torque if saturation is None else saturation
    c = BankController(default_trajectory_path(), load_bank(schedule), gain_set, loop_delay_samples,
                       integral_action, sat, feedforward_correction=feedforward_correction)
    c.history = None
    return c


@dataclass
class BankState:
    """What the bank carries from one sample to the next (see :class:`flexarm.lqg.LqgState`).

    Attributes
    ----------
    k : int
    x_post : ndarray, shape (n_models + 1, 22)
        Each filter's posterior error estimate at sample max(k − 1 − d, 0) (the quiet filter last).
    log_p : ndarray, shape (n_models,)
        Log posterior probabilities of the models.
    du : ndarray, shape (d + 1, 2)
        τ − τ_ff sent at samples k − 1 − d .. k − 1, N·m.
    xi : ndarray, shape (2,)
        Integrated joint-angle errors, rad·s.
    started : bool
    """

    k: int
    x_post: np.ndarray
    log_p: np.ndarray
    du: np.ndarray
    xi: np.ndarray
    started: bool = False

    def as_dict(self) -> dict:
        """JSON-serialisable form (FMU state)."""
        return {"k": self.k, "x_post": self.x_post.tolist(), "log_p": self.log_p.tolist(), "du": self.du.tolist(),
                "xi": self.xi.tolist(), "started": self.started}

    @classmethod
    def from_dict(cls, d: dict) -> BankState:
        """Inverse of :meth:`as_dict`."""
        return cls(int(d["k"]), np.array(d["x_post"], dtype=float).reshape(-1, N_STATE),
                   np.array(d["log_p"], dtype=float), np.array(d["du"], dtype=float).reshape(-1, 2),
                   np.array(d["xi"], dtype=float), bool(d["started"]))


class BankController:
    """Multiple-model LQG with the stepping API of :class:`flexarm.lqg.LqgController` (works with
    :func:`flexarm.lqg.simulate_lqg`).

    Parameters
    ----------
    trajectory : TrajectoryResult or path-like
    bank : PayloadBank
    gain_set : str
    loop_delay_samples : int
        0..10.
    integral_action : bool
    saturation : (float, float)
        Torque limits, N·m.
    select : {"mixture", "map"}
        Posterior-weighted sum of the models' feedback, or the most probable model's.
    floor : float
        Smallest posterior probability, in (0, 1/n_models).
    reseed_below : float
        Posterior of the unloaded model below which the quiet filter is re-seeded.
    feedforward_correction : array_like, shape (m, 2), optional
        A learned feedforward correction, N·m (as :class:`flexarm.lqg.LqgController`).
    """

    def __init__(self, trajectory, bank: PayloadBank, gain_set: str = "gamma0.1", loop_delay_samples: int = 0,
                 integral_action: bool = False, saturation=(7.0, 2.25), select: str = "mixture",
                 floor: float = POSTERIOR_FLOOR, reseed_below: float = QUIET_RESEED_BELOW,
                 feedforward_correction=None):
        delay, sat = check_loop_delay(loop_delay_samples), check_saturation(saturation)
        self.correction = check_correction(feedforward_correction)
        if select not in SELECTIONS:
            raise LqgError(f"select: {select!r} is not one of {SELECTIONS}")
        if not 0.0 < floor < 1.0 / len(bank.models):
            raise LqgError(f"floor: a probability in (0, 1/{len(bank.models)}), got {floor!r}")
        self.trajectory = as_trajectory(trajectory)
        self.z = desired_states(self.trajectory)
        self.bank = bank
        self.masses = bank.masses
        self._filters = bank.models + [bank.quiet]
        self.design = bank.quiet.design  # C, for simulate_lqg
        self.delay = delay
        self.integral_action = bool(integral_action)
        self.saturation = sat
        self.select, self.log_floor, self.reseed_below = select, float(np.log(floor)), float(reseed_below)
        self.dt = sample_time(self.trajectory)
        self.n_steps = self.trajectory.n_samples
        w = self.design.weight_index(gain_set)
        for b in self._filters:
            if not (np.array_equal(b.design.times, self.design.times) and np.array_equal(b.design.C, self.design.C)):
                raise LqgError(f"bank: the filter of {b.mass} kg has another schedule or measurement matrix")
        # Every filter's matrices stacked per schedule point, shape (n_points, n_filters, ...): one product
        # per sample for the whole bank.
        stack = lambda f: np.stack([f(b) for b in self._filters], axis=1)  # noqa: E731
        self._Phi, self._Gamma, self._M = (stack(lambda b, a=a: getattr(b.design, a)) for a in ("Phi", "Gamma", "M"))
        self._K = stack(lambda b: b.design.K_integral[:, w, :, :N_STATE] if integral_action else b.design.K[:, w])
        self._K_xi = stack(lambda b: b.design.K_integral[:, w, :, N_STATE:])
        self._S_inv = stack(lambda b: b.S_inv)[:, :len(bank.models)]
        self._log_det_S = stack(lambda b: b.log_det_S)[:, :len(bank.models)]
        self._drift = np.stack([b.drift for b in self._filters], axis=1)  # (n_steps + 1, n_filters, 22)
        self._index = np.array([self.design.index_at(k * self.dt) for k in range(self.n_steps + 1)])
        self._y_d = self.z @ self.design.C.T
        self._Cq = self.design.C[0:2]
        #: Posterior probabilities after each sample (a record for analysis), each shape (n_models,);
        #: None turns the record off (a long-lived controller, as in the FMU).
        self.history: list[np.ndarray] | None = []

    sample_index = LqgController.sample_index

    def desired_measurement(self, j: int) -> np.ndarray:
        """The ten measurements the trajectory predicts for the plant's sample j (zero innovation): the law's
        y_d, the row the native twin reads (fmus/native/lqg_resources.py writes the same expression)."""
        return self._y_d[self._c(max(int(j), 0))].copy()

    def _c(self, k: int) -> int:
        return min(k, self.n_steps)

    def feedforward(self, k: int) -> np.ndarray:
        """Nominal feedforward torque of sample k, N·m (0 after the slew)."""
        return self.trajectory.tau[k].copy() if k < self.n_steps else np.zeros(2)

    def initial_state(self) -> BankState:
        """On the trajectory, uniform posterior, nothing sent, integrators empty."""
        n_m = len(self.bank.models)
        return BankState(0, np.zeros((n_m + 1, N_STATE)), np.full(n_m, -np.log(n_m)),
                         np.zeros((self.delay + 1, 2)), np.zeros(2))

    def weights(self, log_p) -> np.ndarray:
        """Each filter's weight in the control law, shape (n_models + 1,): the quiet filter takes m = 0's."""
        p = np.exp(log_p)
        if self.select == "map":
            p = (np.arange(len(p)) == np.argmax(p)).astype(float)
        return np.append(0.0, np.append(p[1:], p[0]))

    def step(self, state: BankState, k: int, measurements) -> tuple[np.ndarray, BankState]:
        """Torques of sample k and the state after it (as :meth:`flexarm.lqg.LqgController.step`).

        Parameters
        ----------
        state : BankState
        k : int
            Sample index; must be ``state.k``.
        measurements : array_like, shape (10,)
            q1, q2 (rad), q̇1, q̇2 (rad/s), ε1..ε6 (rad) of the plant state at k − d.

        Returns
        -------
        tau : ndarray, shape (2,)
            N·m.
        new_state : BankState
        """
        m = check_sample_input(state.k, k, measurements)
        d = self.delay
        j = max(k - d, 0)
        fresh = k - d >= 0
        i_j = self._index[self._c(j)]
        sent = state.du[1:] if fresh else state.du[d + 1 - k:]  # torques of samples j .. k − 1
        x = state.x_post
        if state.started and j > 0 and fresh:  # time update from j − 1, drift included
            i_p = self._index[self._c(j - 1)]
            x = filter_law.time_update(self._Phi[i_p], self._Gamma[i_p], x, state.du[0], self._drift[self._c(j - 1)])
        e = filter_law.innovation(x, self.design.C, m, self._y_d[self._c(j)])  # (n_filters, 10)
        log_p = state.log_p.copy()
        if fresh and j > 0:
            n_m = len(log_p)
            log_p = filter_law.log_likelihood_update(log_p, e[:n_m], self._S_inv[i_j], self._log_det_S[i_j])
        x_post = filter_law.updated(x, self._M[i_j], e)
        x_now = x_post
        for q, du in enumerate(sent):  # predict across the delay with the torques sent
            i_s = self._index[self._c(j + q)]
            x_now = filter_law.time_update(self._Phi[i_s], self._Gamma[i_s], x_now, du, self._drift[self._c(j + q)])
        log_p, p = filter_law.normalised_posterior(log_p, self.log_floor)
        if self.history is not None:
            self.history.append(p)
        x_post[-1] = filter_law.reseeded(p[0], self.reseed_below, x_post[-1], x_post[0])
        x_now[-1] = filter_law.reseeded(p[0], self.reseed_below, x_now[-1], x_now[0])
        weights = self.weights(log_p)
        i_k = self._index[self._c(k)]
        ff = self.feedforward(k)
        integral = (self._K_xi[i_k], state.xi) if self.integral_action else ()
        u = filter_law.feedback(self._K[i_k], x_now, *integral)  # each model's on its own estimate, (n_filters, 2)
        command = control_law.corrected_feedforward(ff, correction_at(self.correction, k))
        tau_free = filter_law.bank_free_torque(command, weights, u)
        tau = control_law.saturate(tau_free, self.saturation)
        xi = state.xi
        if self.integral_action:
            xi = filter_law.integrated(xi, self.dt, self._Cq, filter_law.weighted_estimate(weights, x_now), tau,
                                       tau_free)
        return tau, BankState(k + 1, x_post, log_p, np.vstack([state.du[1:], tau - ff]), xi, True)
