"""Controller FMU ``controller_lqg``: feedforward + discrete-time LQG with delay prediction and integral action.

Same interface as the other controllers (:mod:`flexarm_controller_base`) plus
``loop_delay_samples`` (Integer 0..10: samples between the plant state and the
measurement this FMU receives; 2 for Jacobi stepping with separate sensors and
controller FMUs, 0 for our Gauss-Seidel master) and ``integral_action``
(Boolean) and ``estimator`` (1 ``kalman``: one steady-state Kalman filter per
schedule point, :mod:`flexarm.lqg`; 2 ``payload_bank``: a bank of filters, one
per payload mass, :mod:`flexarm.lqg_bank`, 200 ms schedule only). ``gain_set``
names the LQR weights (their discrete-time design);
``omega7`` / ``omega7_estimate`` is accepted and not used (the Kalman filter
estimates every velocity). ``feedforward_correction_file`` (String, as the
other controllers): a learned feedforward correction (:mod:`flexarm.ilc`),
added to the feedforward; the filter's input includes it. The law: :mod:`flexarm.lqg`; the design files:
``flexarm/data/lqg/`` (:mod:`flexarm.lqg_design`).

The controller has a state (the filter's estimate, the torques sent, the
integrators) and runs at the trajectory's 1 ms sample. Its torques are a pure
function of that state and, with ``loop_delay_samples = 0`` only, of the
inputs present: reading them, any number of times, changes nothing; the
state advances at ``fmi2DoStep`` from the inputs present then.

* ``loop_delay_samples = 0`` (a Gauss-Seidel master, which sets the inputs
  before it reads): direct feedthrough. The torques at t_k are sample k of
  the law with the measurements present; ``fmi2DoStep`` commits that sample.
* ``loop_delay_samples = d > 0``: no direct feedthrough. ``fmi2DoStep(t_k, h)``
  runs the samples k + 1 .. k + n (h = n ms) with the inputs present at
  ``fmi2DoStep`` (held inside the step) and publishes the torques of sample
  k + n, held until the next ``fmi2DoStep``. The measurement received at
  sample s is taken as that of the plant at s - d; for s < d none exists
  yet, and the filter gets the one the committed trajectory predicts at
  t = 0 (zero innovation): sample 0's torques are computed at
  initialisation from the parameters and the trajectory alone, so the start
  does not depend on how a master initialises. A Jacobi master (reads, then
  sets, then steps every FMU) at 1 ms gives d = 2 exactly: the sensors'
  direct feedthrough delays by one sample, this hold by one.

A step of n = 0 samples (within 1e-9 s of 0, e.g. a last step shortened by
rounding) does nothing; a step that is no whole number of samples (within
1e-9 s) is refused naming ``step_size``. Design note: docs/control.md
("Sampling and the loop delay").
"""

from __future__ import annotations

import functools

import numpy as np
from flexarm_controller_base import FEEDFORWARD_CORRECTION, VARIABLES, ControllerSlave
from flexarm_feedthrough import whole_samples
from flexarm_fmu_base import Var, pin_module_namespace, variable_table

from flexarm.ilc import read_learned_feedforward
from flexarm.lqg import MAX_DELAY_SAMPLES, LqgController, lqg_controller
from flexarm.lqg_bank import BANK_SCHEDULES, BankController, bank_controller

pin_module_namespace(globals())  # pythonfmu 0.7.0 drops a reference per instantiation (see there)

#: ``estimator`` choices: how the 22 states are estimated.
ESTIMATOR_ITEMS = (
    (1, "kalman", "one steady-state Kalman filter per schedule point, the payload absorbed as process noise"),
    (2, "payload_bank", "a bank of Kalman filters, one per payload mass 0-0.4 kg, weighted by their innovations' "
                        "likelihood (schedule_period 0.2 s only)"),
)
DEFAULT_ESTIMATOR = 1


@functools.lru_cache(maxsize=16)
def _law(name: str, schedule: str, tau1_max: float, tau2_max: float, delay: int, integral: bool,
         estimator: int, correction: tuple = ("", "")) -> LqgController | BankController:
    """The control law of one configuration, built once per process (immutable; the state lives in the slave).
    `correction`: the learned-feedforward file and its SHA-256 (part of the cache key), ("", "") for none."""
    learned = read_learned_feedforward(correction[0]).correction if correction[0] else None
    if estimator == 2:
        if schedule not in BANK_SCHEDULES:
            raise ValueError(f"estimator = 2 (payload_bank) needs schedule_period = 0.2 s (the bank exists for "
                             f"{', '.join(BANK_SCHEDULES)}), got the {schedule} schedule")
        return bank_controller(name, schedule, delay, integral, (tau1_max, tau2_max), learned)
    if estimator != 1:
        raise ValueError(f"estimator: {estimator!r} is not one of "
                         + ", ".join(f"{v} ({n})" for v, n, _ in ESTIMATOR_ITEMS))
    return lqg_controller(name, schedule, delay, integral, (tau1_max, tau2_max), learned)


class FlexarmControllerLQG(ControllerSlave):
    """Feedforward + LQG (Kalman filter on the ten measurements, discrete LQR of the ``gain_set`` weights)."""

    VARIABLES = variable_table([
        *[v for v in VARIABLES if v.name != FEEDFORWARD_CORRECTION],  # last here too (value references kept)
        Var("loop_delay_samples", "parameter", "fixed", None,
            "Samples between the plant state measured and the sample whose torques use it; the estimator "
            "predicts across them. 0: direct feedthrough (Gauss-Seidel master); d > 0: no direct feedthrough, "
            "the torques are computed at fmi2DoStep and held (Jacobi master at n ms with separate sensors "
            "and controller FMUs: 2n)",
            0, 0, MAX_DELAY_SAMPLES, type="Integer"),
        Var("integral_action", "parameter", "fixed", None,
            "Feed back the integrated joint-angle errors (anti-windup: frozen while a torque saturates)",
            False, type="Boolean"),
        Var("estimator", "parameter", "fixed", None,
            "State estimator: one Kalman filter (kalman) or a bank of filters, one per payload mass (payload_bank)",
            DEFAULT_ESTIMATOR, 1, len(ESTIMATOR_ITEMS), type="Integer", choices=ESTIMATOR_ITEMS),
        *[v for v in VARIABLES if v.name == FEEDFORWARD_CORRECTION],
    ])
    DISCRETE = True
    description = "Sandia two-link flexible arm: feedforward + discrete-time LQG controller (Kalman filter, " \
                  "delay predictor, optional integral action)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.state = None  # LqgState or BankState (the estimator's), committed
        self._pending = None  # loop_delay_samples = 0: the state after the sample the outputs show (derived)
        self._tau = None  # loop_delay_samples > 0: the torques held until the next doStep

    def _config(self) -> tuple:
        name, schedule, tau1_max, tau2_max, _omega7 = super()._config()
        return (name, schedule, tau1_max, tau2_max, int(self.value("loop_delay_samples")),
                bool(self.value("integral_action")), int(self.value("estimator")), self._correction())

    def setup(self) -> None:
        try:
            key = self._config()
            self.law = _law(*key)
        except (ValueError, OSError) as exc:
            raise ValueError(f"gain_set = {self.value('gain_set')!r}, schedule_period = "
                             f"{self.value('schedule_period')!r} s, loop_delay_samples = "
                             f"{self.value('loop_delay_samples')!r}, estimator = {self.value('estimator')!r}, "
                             f"{FEEDFORWARD_CORRECTION} = {self.value(FEEDFORWARD_CORRECTION)!r}: {exc}") from None
        self._key = key
        self.state = self.law.initial_state()
        self._pending = self._tau = None
        if self.law.delay > 0:  # sample 0 from the trajectory alone (no measurement exists yet)
            self._sample(self.law.sample_index(self.time), None)

    def _measurements(self) -> np.ndarray:
        return np.array([self._values[vr] for vr in self._used_vrs], dtype=float)  # q1_m .. eps6_m

    def _sample(self, k: int, measurements) -> None:
        """Run sample k of the delayed law (loop_delay_samples > 0): commit it and hold its torques.

        The measurement of sample k is that of the plant at k - d; before k = d there is none and the filter
        gets the measurement the trajectory predicts at t = 0 (zero innovation on the zero initial error).
        """
        if k < self.law.delay:
            measurements = self.law.design.C @ self.law.z[0]
        self._tau, self.state = self.law.step(self.state, k, measurements)

    def evaluate(self) -> np.ndarray:
        if self.law.delay > 0:
            return self._tau
        tau, self._pending = self.law.step(self.state, self.law.sample_index(self.time), self._measurements())
        return tau

    def commit(self, t: float, h: float, n: int) -> None:
        held = self._measurements()  # the inputs present at fmi2DoStep, held inside the step
        if self.law.delay > 0:  # samples k + 1 .. k + n; the last one's torques are published
            if self.state.k != self.law.sample_index(t) + 1:
                raise ValueError(f"current_time: {t!r} s is sample {self.law.sample_index(t)}, but the controller "
                                 f"computed sample {self.state.k - 1} last (one fmi2DoStep per communication "
                                 "point, from t = 0)")
            for _ in range(n):
                self._sample(self.state.k, held)
            return
        state, self._pending = self._pending, None  # sample k, evaluated from the inputs present
        for _ in range(n - 1):
            _, state = self.law.step(state, state.k, held)
        self.state = state

    def samples_in_step(self, t: float, h: float) -> int:
        return whole_samples(h, self.law.dt, "the controller's 1 ms sample (controller_lqg is a sampled filter "
                             "and runs the samples inside a longer step with its inputs held)")

    def get_sample_state(self) -> dict:
        as_dict = lambda s: None if s is None else s.as_dict()  # noqa: E731
        return {"lqg": as_dict(self.state), "pending": as_dict(self._pending),
                "tau": None if self._tau is None else self._tau.tolist()}

    def set_sample_state(self, state: dict) -> None:
        if self.law is None or self._key != self._config():
            self.setup()
        state_type = type(self.law.initial_state())
        from_dict = lambda d: None if d is None else state_type.from_dict(d)  # noqa: E731
        if state.get("lqg") is not None:
            self.state = from_dict(state["lqg"])
        self._pending = from_dict(state.get("pending"))
        self._tau = None if state.get("tau") is None else np.array(state["tau"], dtype=float)
