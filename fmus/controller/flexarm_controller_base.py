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
(``flexarm/data/gains/``) travel in the bundled ``flexarm`` package.

Sampling (direct feedthrough, :mod:`flexarm_feedthrough`): the torques at
communication point t_k are a pure function of the measurements present at
t_k and the trajectory sample k = round(t_k / 1 ms) (reads change nothing);
the plant holds them over [t_k, t_k + h). A step must be a whole number of
samples (within 1e-9 s; 0 samples: nothing happens).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import ClassVar

import numpy as np
from flexarm_feedthrough import FeedthroughSlave, whole_samples
from flexarm_fmu_base import Var, own_data_dir, slew_experiment, variable_table
from pythonfmu.enums import Fmi2Status

from flexarm.control import PEAK_TORQUE, TrackingController
from flexarm.ilc import read_learned_feedforward  # imported here, so the build bundles it (fmu_build traces imports)
from flexarm.loop_index import index_of_time, measured_delay
from flexarm.lqr import OMEGA7_CHOICES, canonical_name, default_trajectory_path
from flexarm.signals import names, signals

#: Measured signals the law uses (sensors FMU output names), in the order q, q̇, ε (catalogue group "feedback").
USED_INPUTS = names("controller", "input", "feedback")
#: Accepted for plug-compatibility with the sensors FMU, not used by the law (catalogue group "unused").
UNUSED_INPUTS = names("controller", "input", "unused")
#: ``schedule_period`` value (s) -> :data:`flexarm.lqr.SCHEDULES` label.
SCHEDULE_PERIODS = {0.2: "200ms", 0.02: "20ms", 0.0: "single"}
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
#: String parameter: a learned feedforward correction file (:func:`flexarm.ilc.write_learned_feedforward`).
FEEDFORWARD_CORRECTION = "feedforward_correction_file"

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
          depends_on=("sample_index_m",) if s.name == "loop_delay" else ())
      for s in signals("controller", "output", "index")],
    # Last, so that the native twins (no Strings in their glue) leave it out without a gap in the references.
    Var(FEEDFORWARD_CORRECTION, "parameter", "fixed", None,
        "Learned feedforward correction: path of a flexarm.ilc design file (.npz with its .json); "
        "empty: none", "", type="String"),
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
    raise ValueError(f"schedule_period: {period!r} s is not one of 0.2, 0.02 or 0 (one gain set)")


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
    learned = read_learned_feedforward(correction[0]).correction if correction[0] else None
    return TrackingController(trajectory, gains, mode=mode, saturation=(tau1_max, tau2_max), omega7=omega7,
                              feedforward_correction=learned)


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
        self.delay_contradictions = 0  # fmi2DoSteps whose measured loop delay contradicted the law's (warn_delay)

    def _config(self) -> tuple:
        omega7 = dict((v, n) for v, n, _ in OMEGA7_ITEMS).get(self.value("omega7_estimate"))
        if omega7 not in OMEGA7_CHOICES:
            raise ValueError(f"omega7_estimate: {self.value('omega7_estimate')!r} is not one of "
                             + ", ".join(f"{v} ({n})" for v, n, _ in OMEGA7_ITEMS))
        name = gain_set_name(self.value("gain_set"), self.DISCRETE)
        return (name, schedule_label(self.value("schedule_period")), self.value("tau1_max"),
                self.value("tau2_max"), omega7)

    def _correction(self) -> tuple[str, str]:
        """The learned-feedforward file (absolute) and its SHA-256, ("", "") for none."""
        path = self.value(FEEDFORWARD_CORRECTION)
        if not path:
            return ("", "")
        from flexarm.provenance import sha256_file

        if not Path(path).is_file():
            raise ValueError(f"{FEEDFORWARD_CORRECTION}: no file {path!r}")
        return (str(Path(path).resolve()), sha256_file(path))

    def _law_key(self) -> tuple:
        return (*self._config(), self._correction())

    def setup(self) -> None:
        self.delay_contradictions = 0
        key = self._law_key()
        if self.law is not None and key == self._key:
            return
        try:
            self.law = _tracking_controller(own_data_dir(self.resources), self.MODE, *key)
        except (ValueError, OSError) as exc:
            raise ValueError(f"gain_set = {self.value('gain_set')!r}, schedule_period = "
                             f"{self.value('schedule_period')!r} s, {FEEDFORWARD_CORRECTION} = "
                             f"{self.value(FEEDFORWARD_CORRECTION)!r}: {exc}") from None
        self._key = key

    def evaluate(self) -> np.ndarray:
        x = np.array([self._values[vr] for vr in self._used_vrs], dtype=float)  # q1_m .. eps6_m
        k = self.law.sample_index(self.time)
        return np.concatenate([self.law.torque_from_measurements(k, x),
                               self.index_outputs(k, self._values[self._index_vr], 0)])

    def index_outputs(self, k: int, index: float, assumed: int) -> list[float]:
        """``tau_index``, ``loop_delay``, ``loop_delay_assumed`` of the torques of sample k computed from
        measurements carrying `index` by a law that predicts over `assumed` samples."""
        return [index_of_time(k * self.law.dt), measured_delay(k, index), float(assumed)]

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
        self.warn_delay(t, self._values[self._vr["loop_delay"]], 0, "the paper's law assumes no delay")

    def samples_in_step(self, t: float, h: float) -> int:
        return whole_samples(h, self.law.dt, "the controller's sample (the trajectory's sample time)")

    def get_sample_state(self) -> dict:
        # stateless: the torque is a function of the time and the inputs; the warning is said once per run
        return {"delay_contradictions": self.delay_contradictions}

    def set_sample_state(self, state: dict) -> None:
        if self.law is None or self._key != self._law_key():
            self.setup()
        self.delay_contradictions = int(state.get("delay_contradictions", 0))
