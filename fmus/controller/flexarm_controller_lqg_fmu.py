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
estimates every velocity). A learned feedforward correction (:mod:`flexarm.ilc`) in the FMU's
``resources/learned_feedforward.npz``, as in the other controllers, is added to the feedforward; the filter's
input includes it. The law: :mod:`flexarm.lqg`; the design files:
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
from pythonfmu.enums import Fmi2Status

from flexarm.learned_feedforward import read_learned_feedforward
from flexarm.loop_index import AUTOMATIC, NO_SAMPLE, is_placeholder, measured_delay, received_index
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
        *VARIABLES,
        Var("loop_delay_samples", "parameter", "fixed", None,
            "Samples between the plant state measured and the sample whose torques use it; the estimator "
            "predicts across them. -1 (automatic, the start value): measured from the sample indices "
            "(sample_index_m, tau_index), direct feedthrough while the delay is 0 (Gauss-Seidel master), "
            "no feedthrough and a prediction over the measured delay from the first step that shows one "
            "(Jacobi master); 0: direct feedthrough; d > 0: no direct feedthrough, the torques are computed "
            "at fmi2DoStep and held (Jacobi master at n ms with separate sensors and controller FMUs: 2n). "
            "An explicit value that contradicts the measured delay is warned in the log",
            AUTOMATIC, AUTOMATIC, MAX_DELAY_SAMPLES, type="Integer"),
        Var("integral_action", "parameter", "fixed", None,
            "Feed back the integrated joint-angle errors (anti-windup: frozen while a torque saturates)",
            False, type="Boolean"),
        Var("estimator", "parameter", "fixed", None,
            "State estimator: one Kalman filter (kalman) or a bank of filters, one per payload mass (payload_bank)",
            DEFAULT_ESTIMATOR, 1, len(ESTIMATOR_ITEMS), type="Integer", choices=ESTIMATOR_ITEMS),
    ])
    DISCRETE = True
    description = "Sandia two-link flexible arm: feedforward + discrete-time LQG controller (Kalman filter, " \
                  "delay predictor, optional integral action)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.state = None  # LqgState or BankState (the estimator's), committed
        self._pending = None  # feedthrough (delay 0): the state after the sample the outputs show (derived)
        self._tau = None  # delay > 0: the outputs held until the next doStep (torques, then the index outputs)
        self.delay = 0  # the delay the law in force predicts over (loop_delay_samples, or the measured one)
        self._unwired_warned = False

    def _config(self) -> tuple:
        name, schedule, tau1_max, tau2_max, _omega7 = super()._config()
        return (name, schedule, tau1_max, tau2_max, int(self.value("loop_delay_samples")),
                bool(self.value("integral_action")), int(self.value("estimator")), self._correction())

    @property
    def automatic(self) -> bool:
        return self._key[4] == AUTOMATIC

    def _build(self, delay: int) -> None:
        """The law of the configuration with the loop delay `delay` (samples)."""
        key = self._config()
        try:
            self.law = _law(*key[:4], delay, *key[5:])
        except (ValueError, OSError) as exc:
            raise ValueError(f"gain_set = {self.value('gain_set')!r}, schedule_period = "
                             f"{self.value('schedule_period')!r} s, loop_delay_samples = "
                             f"{self.value('loop_delay_samples')!r}, estimator = {self.value('estimator')!r}"
                             f"{', ' + FEEDFORWARD_CORRECTION if key[-1][0] else ''}: {exc}") from None
        self._key, self.delay = key, delay

    def setup(self) -> None:
        self.reset_loop()
        self._unwired_warned = False
        requested = int(self.value("loop_delay_samples"))
        if requested < AUTOMATIC:
            raise ValueError(f"loop_delay_samples: {requested!r} is not -1 (automatic) or 0..{MAX_DELAY_SAMPLES}")
        # automatic starts as a Gauss-Seidel master's law (delay 0, direct feedthrough): exactly it while the
        # measured delay stays 0 (docs/control.md, "The loop measures its own delay")
        self._build(0 if requested == AUTOMATIC else requested)
        self.state = self.law.initial_state()
        self._pending = self._tau = None
        if self.law.delay > 0:  # sample 0 from the trajectory alone (no measurement exists yet)
            self._sample(self.law.sample_index(self.time), None, NO_SAMPLE)

    def _measurements(self) -> np.ndarray:
        return np.array([self._values[vr] for vr in self._used_vrs], dtype=float)  # q1_m .. eps6_m

    def _desired(self, j: int) -> np.ndarray:
        """The measurement the trajectory predicts for the plant's sample j (zero innovation)."""
        return self.law.desired_measurement(j)

    def _sample(self, k: int, measurements, index: float) -> None:
        """Run sample k of the delayed law (delay > 0): commit it and hold its torques.

        The measurement of sample k is that of the plant at k - d; before k = d there is none and the filter
        gets the measurement the trajectory predicts at t = 0 (zero innovation on the zero initial error); a
        master's placeholder (no index, all zero) is no measurement either.
        """
        if k < self.law.delay:
            measurements, index = self.law.design.C @ self.law.z[0], NO_SAMPLE
        elif measurements is None or is_placeholder(index, measurements):
            measurements, index = self._desired(k - self.law.delay), NO_SAMPLE
        tau, self.state = self.law.step(self.state, k, measurements)
        self._tau = np.concatenate([tau, self.index_outputs(k, index, self.law.delay)])

    def evaluate(self) -> np.ndarray:
        if self.law.delay > 0:
            return self._tau
        k = self.trajectory_sample(self.time)
        measurements, index = self._measurements(), self.trajectory_index()
        # fmpy's first step: no sample yet, not a measurement of q = 0; automatic, an index naming an earlier sample
        # (a Jacobi master's first steps, before fmi2DoStep switches to the measured delay): no measurement of sample
        # k (an explicit 0 is honoured: the law it names runs on what it gets, and the FMU warns)
        # (such inputs are those of an earlier communication point: the plant's report of the torque it held
        # is as old, so it is no report on sample k - 1 either)
        if is_placeholder(index, measurements) or (self.automatic and measured_delay(k, index) >= 1):
            measurements, applied = self._desired(k), None
        else:
            applied = self._applied(k)
        tau, self._pending = self.law.step(self._with_applied(self.state, applied), k, measurements)
        return np.concatenate([tau, self.index_outputs(k, index, 0)])

    def _nominal_feedforward(self, s: int) -> np.ndarray:
        return self.law.feedforward(s)

    def commit(self, t: float, h: float, n: int) -> None:
        if self.starts_late(t):  # the master's placeholder at the first step: the slew starts at the next one
            return
        held = self._measurements()  # the inputs present at fmi2DoStep, held inside the step
        index = self.trajectory_index()
        k = self.law.sample_index(t) - self.start
        self._warn_unwired(t, index, held)
        # automatic: the torques held over the samples up to the switch were the law's before it (its own reports too)
        applied = self._applied(k, any_lag=self.automatic and (self.law.delay == 0 or k <= self._switch_end))
        self._remember(applied)
        if self.law.delay > 0:  # samples k + 1 .. k + n; the last one's torques are published
            if self.state.k != k + 1:
                raise ValueError(f"current_time: {t!r} s is sample {k}, but the controller "
                                 f"computed sample {self.state.k - 1} last (one fmi2DoStep per communication "
                                 "point, from t = 0)")
            self.state = self._with_applied(self.state, applied)
            for _ in range(n):
                self._sample(self.state.k, held, index)
            self.warn_delay(t, self._tau[3], self.law.delay, self._setting())
            return
        measured = measured_delay(k, index)
        if self.automatic and measured >= 1:  # the master sets the measurements after it reads the torques
            self._switch(t, k, int(measured) + n, n, held, index)  # the last of the n samples is published
            return
        self.warn_delay(t, measured, 0, self._setting())
        state, self._pending = self._pending, None  # sample k, evaluated from the inputs present (and torque held)
        for _ in range(n - 1):
            _, state = self.law.step(state, state.k, held)
        self.state = state

    def _setting(self) -> str:
        return f"loop_delay_samples = {self._key[4]}" + (" (automatic)" if self.automatic else "")

    def _switch(self, t: float, k: int, delay: int, n: int, held, index: float) -> None:
        """Automatic delay: the measurements present at fmi2DoStep(t_k) are `delay` - n samples old, so the master
        reads before it sets (Jacobi stepping) and the torques published after this step of n samples are
        `delay` samples late (2n in a Jacobi master at n ms, the explicit guidance). From now on
        the law predicts over `delay` without feedthrough, as loop_delay_samples = `delay` would: its samples
        0 .. k are run again from the trajectory alone (before k = delay such a law has no measurement; a
        switch happens at the first steps), then k + 1 .. k + n from the inputs present."""
        delay = min(delay, MAX_DELAY_SAMPLES)
        self._build(delay)
        self._switch_end = k + 1
        self.log(f"{self.instance_name}: loop_delay_samples = -1 (automatic): the loop delay measured at "
                 f"fmi2DoStep(t = {t!r} s) is {delay} samples (the master reads the torques before it sets the "
                 f"measurements); predicting over {delay} samples from sample {k + 1} on", Fmi2Status.ok)
        self.state, self._pending = self.law.initial_state(), None
        for s in range(k + 1):
            self._sample(s, None, NO_SAMPLE)
            if s in self._foreign:  # the plant held another torque over s than this law's (fmpy's first step)
                self.state = self._with_applied(self.state, (s, self._foreign[s]))
        for _ in range(n):
            self._sample(self.state.k, held, index)

    def _warn_unwired(self, t: float, index: float, measurements) -> None:
        """Say once that the measurements carry no index (sample_index_m not wired): no delay can be measured."""
        if self._unwired_warned or received_index(index) is not None or is_placeholder(index, measurements):
            return
        self._unwired_warned = True
        self.log(f"{self.instance_name}: sample_index_m is {index!r} at t = {t!r} s while the measurements are "
                 "not a master's placeholder: the sample index is not wired (connect the plant's sample_index to "
                 "the sensors and the sensors' sample_index_m to this FMU, or the plant's sample_index here "
                 f"directly), so the loop delay cannot be measured; {self._setting()} is taken as given "
                 "(automatic: 0, a Gauss-Seidel master's)", Fmi2Status.warning)

    def samples_in_step(self, t: float, h: float) -> int:
        return whole_samples(h, self.law.dt, "the controller's 1 ms sample (controller_lqg is a sampled filter "
                             "and runs the samples inside a longer step with its inputs held)")

    def get_sample_state(self) -> dict:
        as_dict = lambda s: None if s is None else s.as_dict()  # noqa: E731
        return {"lqg": as_dict(self.state), "pending": as_dict(self._pending),
                "tau": None if self._tau is None else self._tau.tolist(), "delay": self.delay,
                "unwired_warned": self._unwired_warned, **self.loop_state()}

    def set_sample_state(self, state: dict) -> None:
        delay = int(state.get("delay", self.delay))
        if self.law is None or self._key != self._config() or self.delay != delay:
            self._build(delay)
        state_type = type(self.law.initial_state())
        from_dict = lambda d: None if d is None else state_type.from_dict(d)  # noqa: E731
        if state.get("lqg") is not None:
            self.state = from_dict(state["lqg"])
        self._pending = from_dict(state.get("pending"))
        self._tau = None if state.get("tau") is None else np.array(state["tau"], dtype=float)
        self._unwired_warned = bool(state.get("unwired_warned", False))
        self.set_loop_state(state)
