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
estimates every velocity). The law: :mod:`flexarm.lqg`; the design files:
``flexarm/data/lqg/`` (:mod:`flexarm.lqg_design`).

The controller has a state (the filter's estimate, the torques sent, the
integrators) and runs at the trajectory's 1 ms sample. A communication step h
may be any whole multiple n of it (others are refused naming ``step_size``).
The sample it commits at ``fmi2DoStep`` is the one whose torques the master
*read* last (what the plant got), not a re-evaluation with inputs set after
that read; with n > 1 the filter then runs the n - 1 samples inside the step
with the inputs held (those present at ``fmi2DoStep``), as a sampled-data
controller does between a master's communication points, so the torques read
after the step are those of sample (t + h) / 1 ms. ``loop_delay_samples``
counts 1 ms samples.
A Gauss-Seidel master sets the inputs and then reads (the measurement of the
state at t_k: delay 0); a Jacobi master reads first and sets the inputs after,
so the torques it takes at t_k come from the inputs it set at t_(k-1), the
sensors' sample of the plant at t_(k-2): delay 2. Either way the filter knows
exactly which torque acted when, which its predictor needs.
"""

from __future__ import annotations

import functools

import numpy as np
from flexarm_controller_base import VARIABLES, ControllerSlave
from flexarm_fmu_base import Var, pin_module_namespace, variable_table

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
         estimator: int) -> LqgController | BankController:
    """The control law of one configuration, built once per process (immutable; the state lives in the slave)."""
    if estimator == 2:
        if schedule not in BANK_SCHEDULES:
            raise ValueError(f"estimator = 2 (payload_bank) needs schedule_period = 0.2 s (the bank exists for "
                             f"{', '.join(BANK_SCHEDULES)}), got the {schedule} schedule")
        return bank_controller(name, schedule, delay, integral, (tau1_max, tau2_max))
    if estimator != 1:
        raise ValueError(f"estimator: {estimator!r} is not one of "
                         + ", ".join(f"{v} ({n})" for v, n, _ in ESTIMATOR_ITEMS))
    return lqg_controller(name, schedule, delay, integral, (tau1_max, tau2_max))


class FlexarmControllerLQG(ControllerSlave):
    """Feedforward + LQG (Kalman filter on the ten measurements, discrete LQR of the ``gain_set`` weights)."""

    VARIABLES = variable_table([
        *VARIABLES,
        Var("loop_delay_samples", "parameter", "fixed", None,
            "Samples between the plant state and the measurement received (Jacobi master with separate "
            "sensors and controller FMUs: 2; Gauss-Seidel: 0); the estimator predicts across them",
            0, 0, MAX_DELAY_SAMPLES, type="Integer"),
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
        self.state = None  # LqgState or BankState (the estimator's)
        self._pending = None  # the state after the last evaluated sample
        self._delivered = None  # ... of the evaluation whose torques were last read

    def _config(self) -> tuple:
        name, schedule, tau1_max, tau2_max, _omega7 = super()._config()
        return (name, schedule, tau1_max, tau2_max, int(self.value("loop_delay_samples")),
                bool(self.value("integral_action")), int(self.value("estimator")))

    def setup(self) -> None:
        key = self._config()
        try:
            self.law = _law(*key)
        except (ValueError, OSError) as exc:
            raise ValueError(f"gain_set = {self.value('gain_set')!r}, schedule_period = "
                             f"{self.value('schedule_period')!r} s, loop_delay_samples = "
                             f"{self.value('loop_delay_samples')!r}, estimator = {self.value('estimator')!r}: "
                             f"{exc}") from None
        self._key = key
        self.state = self.law.initial_state()
        self._pending = None
        self._delivered = None

    def evaluate(self) -> np.ndarray:
        x = np.array([self._values[vr] for vr in self._used_vrs], dtype=float)  # q1_m .. eps6_m
        tau, self._pending = self.law.step(self.state, self.law.sample_index(self.time), x)
        return tau

    def get_real(self, vrs):
        values = super().get_real(vrs)
        if self._ready and not self._output_vr_set.isdisjoint(vrs):
            self._delivered = self._pending  # the master has these torques: they are the sample's
        return values

    def commit(self, t: float, h: float) -> None:
        state = self._delivered if self._delivered is not None else self._pending
        if self._samples_in(h) > 1:  # the samples inside the step, of the inputs held since t
            held = np.array([self._values[vr] for vr in self._used_vrs], dtype=float)
            for _ in range(self._samples_in(h) - 1):
                _, state = self.law.step(state, state.k, held)
        self.state = state
        self._pending = self._delivered = None

    def _samples_in(self, h: float) -> int:
        return round(h / self.law.dt)

    def check_step(self, t: float, h: float) -> None:
        dt = self.law.dt
        if self._samples_in(h) < 1 or abs(h / dt - self._samples_in(h)) > 1e-6:
            raise ValueError(f"step_size: {h!r} s is not a whole multiple of the controller's 1 ms sample "
                             f"(allowed: n * {dt:g} s, n = 1, 2, ...; controller_lqg is a sampled filter and "
                             "runs the samples inside a longer step with its inputs held)")
        super().check_step(t, h)

    def get_sample_state(self) -> dict:
        as_dict = lambda s: None if s is None else s.as_dict()  # noqa: E731
        return {"lqg": as_dict(self.state), "pending": as_dict(self._pending), "delivered": as_dict(self._delivered)}

    def set_sample_state(self, state: dict) -> None:
        if self.law is None or self._key != self._config():
            self.setup()
        state_type = type(self.law.initial_state())
        from_dict = lambda d: None if d is None else state_type.from_dict(d)  # noqa: E731
        if state.get("lqg") is not None:
            self.state = from_dict(state["lqg"])
        self._pending, self._delivered = from_dict(state.get("pending")), from_dict(state.get("delivered"))
