"""Shared part of the controller FMUs (FMI 2.0 co-simulation): one interface, several control laws.

A thin wrapper over :class:`flexarm.control.TrackingController`: the
feedforward, the gain schedules, the state reconstruction and the saturation
all live in :mod:`flexarm.control` / :mod:`flexarm.lqr`; this module only maps
FMI variables to and from them. Each controller FMU is a subclass in its own
slave module (unique module and class names, see
``fmus/common/flexarm_fmu_base.py``) that fixes the control mode and the
kind of gain set:

==================  ==========================  ==========================
FMU                 model identifier            law
==================  ==========================  ==========================
``controller``      ``FlexarmController``       feedforward + scheduled LQR
``controller_ff``   ``FlexarmControllerFF``     feedforward only (open loop)
``controller_fb``   ``FlexarmControllerFB``     scheduled LQR only
``controller_dlqr`` ``FlexarmControllerDLQR``   feedforward + discrete LQR
==================  ==========================  ==========================

All have the same variables, so a scenario swaps them with one line.
Defaults (nothing set): the paper's Table 2 law, ``gain_set`` = 2 (``gamma0.1``)
switched every 200 ms (``schedule_period`` = 0.2 s), the motors' peak
torques as saturation, the theta7 rate from the tachometer
(``omega7_estimate`` = 1); the default experiment lasts the slew. The two
choices are Integer parameters whose description lists the choices
(``...; choices: 1 = gamma1, 2 = gamma0.1, 3 = gamma0, 4 = eq32``); no
String parameters, and no FMI Enumeration either, because libcosim 0.11
ignores Enumeration variables. The
trajectory (``flexarm/data/trajectory.npz``) and the gain schedules
(``flexarm/data/gains/``) travel in the bundled ``flexarm`` package. A learned feedforward correction
(:mod:`flexarm.ilc`) is a file in the FMU's resources (:data:`FEEDFORWARD_CORRECTION`), not a parameter: it
travels with the FMU, and a tool that cannot set strings runs it.

Sampling (direct feedthrough, :mod:`flexarm_feedthrough`): the torques at
communication point t_k are a pure function of the measurements present at
t_k and the trajectory sample k = round(t_k / 1 ms) (reads change nothing);
the plant holds them over [t_k, t_k + h). A step must be a whole number of
samples (within 1e-9 s; 0 samples: nothing happens).
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import ClassVar

import numpy as np
from flexarm_feedthrough import FeedthroughSlave, whole_samples
from flexarm_fmu_base import Var, own_data_dir, slew_experiment, variable_table
from pythonfmu.enums import Fmi2Status

from flexarm.control import PEAK_TORQUE, TrackingController
from flexarm.control_law import saturate
from flexarm.gain_schedule import SCHEDULE_PERIOD_PARAMETER
from flexarm.learned_feedforward import LEARNED_RESOURCE, read_learned_feedforward
from flexarm.loop_index import NO_SAMPLE, index_of_time, is_placeholder, measured_delay, trajectory_index
from flexarm.lqg import MAX_DELAY_SAMPLES, LqgState, PredictedTracking
from flexarm.lqr import OMEGA7_CHOICES, canonical_name, default_trajectory_path
from flexarm.signals import names, signals

#: Measured signals the law uses (sensors FMU output names), in the order q, q̇, ε (catalogue group "feedback").
USED_INPUTS = names("controller", "input", "feedback")
#: Accepted for plug-compatibility with the sensors FMU, not used by the law (catalogue group "unused").
UNUSED_INPUTS = names("controller", "input", "unused")
#: ``schedule_period`` value (s) -> :data:`flexarm.lqr.SCHEDULES` label.
SCHEDULE_PERIODS = {period: label for label, period in SCHEDULE_PERIOD_PARAMETER.items()}
#: ``gain_set`` choices: value, :mod:`flexarm.lqr` weights name, description.
GAIN_SET_ITEMS = (
    (1, "gamma1", "LQR weights gamma = 1 (paper Table 1)"),
    (2, "gamma0.1", "LQR weights gamma = 0.1 (paper Table 2, the default)"),
    (3, "gamma0", "LQR weights gamma = 0 (paper Table 3)"),
    (4, "eq32", "LQR weights of the paper's experiments (eq. 32)"),
)
#: ``omega7_estimate`` choices: how the theta7-rate error is formed.
OMEGA7_ITEMS = (
    (1, "tachometer", "from the joint-2 tachometer (qd2 error)"),
    (2, "rigid", "from both tachometers, rigid-body (qd1 + qd2 errors)"),
)
DEFAULT_GAIN_SET = 2  # gamma0.1
#: In the FMU's resources: a learned feedforward correction (:data:`flexarm.ilc.LEARNED_RESOURCE`, written there
#: by ``fmu_build.learned.with_learned_feedforward``), or no such file for none.
FEEDFORWARD_CORRECTION = f"resources/{LEARNED_RESOURCE}"

VARIABLES = variable_table([
    *[Var(s.name, "input", "continuous", s.unit, s.description, 0.0) for s in signals("controller", "input")],
    Var("gain_set", "parameter", "fixed", None,
        "LQR gain set (weights); controller_dlqr uses their discrete-time design", DEFAULT_GAIN_SET, 1, 4,
        type="Integer", choices=GAIN_SET_ITEMS),
    Var("schedule_period", "parameter", "fixed", "s",
        "Gain-switching period: 0.2, 0.02, or 0 for one gain set (mid-slew)", 0.2, 0.0, 10.0),
    Var("tau1_max", "parameter", "fixed", "N.m", "Saturation |tau1| <= tau1_max (shoulder motor peak torque)",
        float(PEAK_TORQUE[0]), 1e-9, 1000.0),
    Var("tau2_max", "parameter", "fixed", "N.m", "Saturation |tau2| <= tau2_max (elbow motor peak torque)",
        float(PEAK_TORQUE[1]), 1e-9, 1000.0),
    Var("omega7_estimate", "parameter", "fixed", None,
        "How the theta7-rate error is formed: from the joint-2 tachometer (qd2 error) or rigid-body "
        "(qd1 + qd2 errors)", 1, 1, 2, type="Integer", choices=OMEGA7_ITEMS),
    *[Var(s.name, "output", "continuous", s.unit, s.description, depends_on=USED_INPUTS)
      for s in signals("controller", "output", indices=False)],
    # the index of the torques' sample: a function of the time alone (flexarm.loop_index)
    *[Var(s.name, "output", "continuous", s.unit, s.description,
          depends_on=("sample_index_m",) if s.name == "loop_delay" else (),
          initial_depends_on=("sample_index_m",) if s.name == "loop_delay" else ())
      for s in signals("controller", "output", "index")],
])


def gain_set_name(value: int, discrete: bool = False) -> str:
    """The :mod:`flexarm.lqr` name of a ``gain_set`` parameter value (1..4, see :data:`GAIN_SET_ITEMS`).

    Raises
    ------
    ValueError
        Naming ``gain_set`` and the allowed values.
    """
    names = {v: n for v, n, _ in GAIN_SET_ITEMS}
    if value not in names:
        raise ValueError(f"gain_set: {value!r} is not one of "
                         + ", ".join(f"{v} ({n})" for v, n in names.items()))
    return canonical_name(f"dlqr-{names[value]}" if discrete else names[value])


def schedule_label(period: float) -> str:
    """The :data:`flexarm.lqr.SCHEDULES` label of a ``schedule_period`` value in s."""
    for p, label in SCHEDULE_PERIODS.items():
        if abs(period - p) <= 1e-12:
            return label
    raise ValueError(f"schedule_period: {period!r} s is not one of "
                     + ", ".join(f"{p:g}" for p in SCHEDULE_PERIODS) + " (0: one gain set)")


@functools.lru_cache(maxsize=16)
def _tracking_controller(data: str | None, mode: str, name: str, schedule: str, tau1_max: float, tau2_max: float,
                         omega7: str, correction: tuple = ("", "")) -> TrackingController:
    """The control law of one configuration, built once per process (about 25 ms).

    Shared by the instances (and resets) with the same configuration and data folder: a
    TrackingController does not change after construction. `data` is this FMU's own
    ``resources/flexarm/data`` (FMUs in one process share the ``flexarm`` package imported first,
    which need not carry this FMU's trajectory and gains), or None for the package's. `correction`: the
    learned-feedforward file and its SHA-256 (part of the cache key: a file rewritten between runs is read anew),
    ("", "") for none.
    """
    gains = None
    if mode != "ff":  # feedforward only needs no gains (the name is still checked by the caller)
        from flexarm.lqr import GainSchedule

        gains = GainSchedule.load(name, schedule, directory=None if data is None else Path(data) / "gains")
    trajectory = default_trajectory_path() if data is None else Path(data) / "trajectory.npz"
    # checked against this FMU's own slew: the shared package imported first may be another FMU's (its data folder
    # the paper's slew, where this one carries a slew re-planned for a payload, fmu_build.learned.with_payload_data)
    learned = read_learned_feedforward(correction[0], data).correction if correction[0] else None
    return TrackingController(trajectory, gains, mode=mode, saturation=(tau1_max, tau2_max), omega7=omega7,
                              feedforward_correction=learned)


@functools.lru_cache(maxsize=16)
def _predictor(data: str | None, mode: str, key: tuple, delay: int) -> PredictedTracking:
    """The law of `key` (:meth:`ControllerSlave._law_key`) predicting over `delay` samples with the LQG design of
    its schedule (built once per process)."""
    from flexarm.lqg_design import LqgDesign

    design = LqgDesign.load(key[1], directory=None if data is None else Path(data) / "lqg")
    return PredictedTracking(_tracking_controller(data, mode, *key), design, delay)


class ControllerSlave(FeedthroughSlave):
    """A tracking controller as an FMI 2.0 co-simulation slave (direct feedthrough, stateless).

    Subclasses set :attr:`MODE` (a :data:`flexarm.control.MODES` entry) and
    :attr:`DISCRETE` (use the ``dlqr-`` design of the named weights).
    """

    VARIABLES = VARIABLES
    MODE: ClassVar[str] = "ff+fb"
    DISCRETE: ClassVar[bool] = False
    default_experiment = slew_experiment()

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.law: TrackingController | None = None
        self._key = None
        self._used_vrs = [self._vr[n] for n in USED_INPUTS]
        self._index_vr = self._vr["sample_index_m"]
        # the measured loop delay (docs/control.md, "The loop measures its own delay"): 0 until a step shows one;
        # then the law predicts over it (flexarm.lqg.PredictedTracking), its state and held outputs here
        self.delay = 0
        self.predictor: PredictedTracking | None = None
        self.state: LqgState | None = None
        self._tau: np.ndarray | None = None
        self._lag_vr = self._vr["tau_lag"]
        self._applied_vrs = (self._vr["tau1_applied"], self._vr["tau2_applied"])
        self.reset_loop()

    def reset_loop(self) -> None:
        """Forget what a run learnt about the loop (at every initialisation; the FMU state holds it, loop_state).

        ``start``: the master's sample at which the trajectory's sample 0 runs (docs/control.md, "The slew starts
        when the loop is live"), 1 when the first fmi2DoStep finds a master's placeholder, else 0;
        ``delay_contradictions``: fmi2DoSteps whose measured loop delay contradicted the law's (warn_delay);
        ``_foreign``: sample -> the torque the plant held over it, as reported, where that was not this law's;
        ``_switch_end``: 1 + the last sample whose torque the law before the switch to a measured delay published.
        """
        self.start, self.delay_contradictions, self._switch_end = 0, 0, 0
        self._foreign: dict[int, list[float]] = {}

    def loop_state(self) -> dict:
        """What :meth:`reset_loop` forgets, for the FMU state (JSON)."""
        return {"start": self.start, "delay_contradictions": self.delay_contradictions,
                "foreign": {str(s): v for s, v in self._foreign.items()}, "switch_end": self._switch_end}

    def set_loop_state(self, state: dict) -> None:
        """Restore what :meth:`loop_state` saved."""
        self.start, self.delay_contradictions = int(state.get("start", 0)), int(state.get("delay_contradictions", 0))
        self._foreign = {int(s): list(v) for s, v in state.get("foreign", {}).items()}
        self._switch_end = int(state.get("switch_end", 0))

    def _config(self) -> tuple:
        omega7 = dict((v, n) for v, n, _ in OMEGA7_ITEMS).get(self.value("omega7_estimate"))
        if omega7 not in OMEGA7_CHOICES:
            raise ValueError(f"omega7_estimate: {self.value('omega7_estimate')!r} is not one of "
                             + ", ".join(f"{v} ({n})" for v, n, _ in OMEGA7_ITEMS))
        name = gain_set_name(self.value("gain_set"), self.DISCRETE)
        return (name, schedule_label(self.value("schedule_period")), self.value("tau1_max"),
                self.value("tau2_max"), omega7)

    def _correction(self) -> tuple[str, str]:
        """The learned-feedforward file in this FMU's resources (absolute) and its SHA-256, ("", "") for none.

        Read at every initialisation (the SHA-256 keys the cached law): a file, not a String parameter, so that
        a tool that cannot set strings runs the learned controller, and the correction travels with the FMU.
        """
        if not self.resources:
            return ("", "")
        path = Path(self.resources) / LEARNED_RESOURCE
        if not path.is_file() and not path.with_suffix(".json").is_file():
            return ("", "")
        from flexarm.provenance import sha256_file

        if not path.is_file():
            raise ValueError(f"{FEEDFORWARD_CORRECTION}: missing beside its .json")
        return (str(path.resolve()), sha256_file(path))

    def _law_key(self) -> tuple:
        return (*self._config(), self._correction())

    def setup(self) -> None:
        self.reset_loop()
        self.delay, self.predictor, self.state, self._tau = 0, None, None, None
        key = self._law_key()
        if self.law is not None and key == self._key:
            return
        try:
            self.law = _tracking_controller(own_data_dir(self.resources), self.MODE, *key)
        except (ValueError, OSError) as exc:
            learned = f", {FEEDFORWARD_CORRECTION}" if key[-1][0] else ""
            raise ValueError(f"gain_set = {self.value('gain_set')!r}, schedule_period = "
                             f"{self.value('schedule_period')!r} s{learned}: {exc}") from None
        self._key = key

    def evaluate(self) -> np.ndarray:
        if self.delay > 0:  # predicting over a measured delay: the torques computed at the last fmi2DoStep
            return self._tau
        x = np.array([self._values[vr] for vr in self._used_vrs], dtype=float)  # q1_m .. eps6_m
        k, index = self.trajectory_sample(self.time), self.trajectory_index()
        # a master's placeholder (fmpy's first step: no index, all zero) is no measurement of q = 0, and one whose
        # index names an earlier sample (a Jacobi master's first step, before fmi2DoStep has measured the delay)
        # none of sample k: no feedback, as the predicting law has none before its first measurement
        if not is_placeholder(index, x) and not measured_delay(k, index) >= 1:
            tau = self.law.torque_from_measurements(k, x)
        else:
            tau = self.law.feedforward(k)
            if self.law.saturation is not None:
                tau = saturate(tau, self.law.saturation)
        return np.concatenate([tau, self.index_outputs(k, index, 0)])

    @property
    def predicts(self) -> bool:
        """Whether the law feeds back measurements, so that a loop delay matters (not the feedforward alone)."""
        return self.MODE != "ff"

    def _applied(self, k: int, any_lag: bool = False) -> tuple[int, list[float]] | None:
        """(k - 1, the torque the plant held over sample k - 1) when the plant reports that it was not this law's
        (tau_lag != 0) or, with `any_lag` (up to the switch to a measured delay), whatever tau_lag says (the law
        before the switch sent it). An unwired tau_lag holds 0 and unwired torques 0: nothing to remember."""
        if k < 1:
            return None
        torque = [float(self._values[vr]) for vr in self._applied_vrs]
        if self._values[self._lag_vr] != 0.0 or (any_lag and any(x != 0.0 for x in torque)):
            return k - 1, torque
        return None

    def _with_applied(self, state: LqgState, applied: tuple[int, list[float]] | None) -> LqgState:
        """`state` with the torque its filter assumes for sample s replaced by the one the plant held (a copy)."""
        if applied is None:
            return state
        s, torque = applied
        row = len(state.du) - (state.k - s)  # du: the torques of samples state.k - len(du) .. state.k - 1
        if not 0 <= row < len(state.du):
            return state
        du = state.du.copy()
        du[row] = np.asarray(torque) - self._nominal_feedforward(s)
        return dataclasses.replace(state, du=du)

    def _nominal_feedforward(self, s: int) -> np.ndarray:
        """The feedforward of sample s the filter's model is linearised about (the trajectory's, N·m)."""
        return self.predictor.filter.feedforward(s)

    def _remember(self, applied: tuple[int, list[float]] | None) -> None:
        """Keep the plant's report of the torque it held over a sample (the last few: a switch comes early)."""
        if applied is not None:
            self._foreign[applied[0]] = applied[1]
            for s in sorted(self._foreign)[:-16]:
                del self._foreign[s]

    def _sample(self, k: int, measurements, index: float) -> None:
        """Run sample k of the predicting law and hold its torques (flexarm.lqg.PredictedTracking.step).

        Before k = d there is no measurement (of the plant before t = 0): the desired one of t = 0; a master's
        placeholder is no measurement either (the desired one of its sample)."""
        d = self.delay
        if k < d:
            measurements, index = self.predictor.desired_measurement(0), NO_SAMPLE
        elif measurements is None or is_placeholder(index, measurements):
            measurements, index = self.predictor.desired_measurement(k - d), NO_SAMPLE
        tau, self.state = self.predictor.step(self.state, k, measurements)
        self._tau = np.concatenate([tau, self.index_outputs(k, index, d)])

    def _switch(self, t: float, k: int, delay: int, n: int, held, index: float) -> None:
        """The measurements present at fmi2DoStep(t_k) are `delay` - n samples old (the master reads the torques
        before it sets them): from now on predict over `delay` without feedthrough. Samples 0 .. k again from the
        trajectory alone, with the torques the plant held (as reported), then k + 1 .. k + n from the inputs."""
        self.delay = min(delay, MAX_DELAY_SAMPLES)
        self.predictor = _predictor(own_data_dir(self.resources), self.MODE, self._law_key(), self.delay)
        self._switch_end = k + 1
        self.log(f"{self.instance_name}: the loop delay measured at fmi2DoStep(t = {t!r} s) is {self.delay} samples "
                 "(the master reads the torques before it sets the measurements); predicting the state over it "
                 f"with the linearised model along the slew (Kalman filter) from sample {k + 1} on", Fmi2Status.ok)
        self.state = self.predictor.initial_state()
        for s in range(k + 1):
            self._sample(s, None, NO_SAMPLE)
            if s in self._foreign:
                self.state = self._with_applied(self.state, (s, self._foreign[s]))
        for _ in range(n):
            self._sample(self.state.k, held, index)

    def index_outputs(self, k: int, index: float, assumed: int) -> list[float]:
        """``tau_index``, ``loop_delay``, ``loop_delay_assumed``, ``slew_start_index`` of the torques of trajectory
        sample k computed from measurements carrying `index` (of the trajectory's samples) by a law that predicts
        over `assumed` samples. ``tau_index`` names the master's sample (the plant's clock)."""
        return [index_of_time((k + self.start) * self.law.dt), measured_delay(k, index), float(assumed),
                index_of_time(self.start * self.law.dt)]

    def trajectory_sample(self, t: float) -> int:
        """The trajectory's sample at the master's time t (before the slew's start: its sample 0)."""
        return max(self.law.sample_index(t) - self.start, 0)

    def trajectory_index(self) -> float:
        """``sample_index_m`` as an index of the trajectory's samples."""
        return trajectory_index(self._values[self._index_vr], self.start)

    def starts_late(self, t: float) -> bool:
        """At the first fmi2DoStep: whether the master exchanged nothing before it (read no output of this FMU since
        initialisation began, and left its placeholder at the inputs: fmpy's simulate_ssp), so that no torque of
        this FMU reached the plant over this step. Then the slew starts one sample later, at the next communication
        point, and this step runs no sample of it (True)."""
        if self.law.sample_index(t) != 0:  # (the only fmi2DoStep at t = 0 is the first, or one of a state before it)
            return False
        measurements = [self._values[vr] for vr in self._used_vrs]
        if self.outputs_read or not is_placeholder(self._values[self._index_vr], measurements):
            return False
        self.start = 1
        if self._tau is not None:  # torques held from initialisation (a delayed law's sample 0): now the next sample's
            self._tau[2:] = self.index_outputs(0, NO_SAMPLE, int(self._tau[4]))
        self.log(f"{self.instance_name}: the master exchanged nothing before its first step (no output read, its "
                 f"placeholder at the inputs of fmi2DoStep(t = {t!r} s): no torque of this FMU reached the plant "
                 f"over it); the slew starts one sample later, at t = {self.law.dt!r} s (slew_start_index = 2)",
                 Fmi2Status.ok)
        return True

    def warn_delay(self, t: float, measured: float, assumed: int, setting: str) -> None:
        """Say in the FMI log, once per run, that the loop delay measured at fmi2DoStep contradicts the law's.

        `measured` < 0 (no index) says nothing. At fmi2DoStep a feedthrough law sees the inputs the master set
        last: a delay of 1 there means the master reads the torques before it sets the measurements (Jacobi
        stepping), so the torques it applied were computed at least 2 samples after their measurement.
        """
        if measured < 0 or measured == assumed:
            return
        self.delay_contradictions += 1
        if self.delay_contradictions == 1:
            self.log(f"{self.instance_name}: loop delay contradiction at t = {t!r} s: the measurements present at "
                     f"fmi2DoStep are of the plant's sample {measured:g} sample(s) before the one the torques are "
                     f"for (tau_index - sample_index_m), but the law predicts over {assumed} ({setting}); the "
                     "master's stepping differs from the one the law is set for (a Jacobi master reads the "
                     "torques before it sets the measurements). Use controller_lqg with loop_delay_samples = -1 "
                     "(automatic), which measures the delay and predicts over it", Fmi2Status.warning)

    def commit(self, t: float, h: float, n: int) -> None:
        # the outputs were just evaluated from the inputs present at fmi2DoStep
        if self.starts_late(t) or not self.predicts:
            return
        k = self.law.sample_index(t) - self.start
        held = np.array([self._values[vr] for vr in self._used_vrs], dtype=float)
        index = self.trajectory_index()
        applied = self._applied(k, any_lag=self.delay == 0 or k <= self._switch_end)
        self._remember(applied)
        if self.delay > 0:  # samples k + 1 .. k + n; the last one's torques are published
            if self.state.k != k + 1:
                raise ValueError(f"current_time: {t!r} s is sample {k}, but the controller computed sample "
                                 f"{self.state.k - 1} last (one fmi2DoStep per communication point, from t = 0)")
            self.state = self._with_applied(self.state, applied)  # late, filled or (up to the switch) the old law's
            for _ in range(n):
                self._sample(self.state.k, held, index)
            self.warn_delay(t, self._tau[3], self.delay, "the delay measured at the switch")
            return
        measured = measured_delay(k, index)
        if measured >= 1:  # the master sets the measurements after it reads the torques
            self._switch(t, k, int(measured) + n, n, held, index)

    def samples_in_step(self, t: float, h: float) -> int:
        return whole_samples(h, self.law.dt, "the controller's sample (the trajectory's sample time)")

    def get_sample_state(self) -> dict:
        # with no delay measured the torque is a function of the time and the inputs
        return {"delay": self.delay, "state": None if self.state is None else self.state.as_dict(),
                "tau": None if self._tau is None else self._tau.tolist(), **self.loop_state()}

    def set_sample_state(self, state: dict) -> None:
        if self.law is None or self._key != self._law_key():
            self.setup()
        self.set_loop_state(state)
        self.delay = int(state.get("delay", 0))
        self.predictor = None if self.delay == 0 else _predictor(own_data_dir(self.resources), self.MODE,
                                                                 self._law_key(), self.delay)
        self.state = None if state.get("state") is None else LqgState.from_dict(state["state"])
        self._tau = None if state.get("tau") is None else np.array(state["tau"], dtype=float)
