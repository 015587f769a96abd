"""Sensors FMU: encoders, tachometers, strain gauges and accelerometers of the arm (FMI 2.0 co-simulation).

A thin wrapper over :class:`flexarm.sensors.SensorBank`: every filter, noise
and quantisation model lives there; this module only maps FMI variables to
and from it. The module name is unique among this project's FMUs (pythonfmu
imports it by name; see ``fmus/common/flexarm_fmu_base.py``).

Interface (full table in ``docs/fmu-interface.md``):

* inputs: the plant's true signals under the plant FMU's output names
  (``q1``, ``q2`` rad; ``qd1``, ``qd2`` rad/s; ``eps1`` … ``eps6`` rad;
  ``acc1_n``, ``acc2_n`` m/s2), so a master connects them by name;
* parameters: one per :class:`flexarm.sensors.SensorSettings` field, same
  name (the per-link gauge full scale as ``..._link1`` / ``..._link2``),
  plus ``sample_period`` (s);
* outputs: :data:`flexarm.sensors.MEASURED_SIGNAL_NAMES` (``q1_m`` … ``acc2_m``);
* ``sample_index`` in, ``sample_index_m`` out: the index of the plant sample measured, passed on as it
  was present at the sample (0: no sample yet; :mod:`flexarm.loop_index`). Inputs that are a master's
  placeholder (index 0 and every true signal exactly 0, fmpy's ``simulate_ssp`` over its first step) are not
  measured: the outputs are 0 with index 0, so the controller sees "no sample yet", the filters are primed by
  the first real sample, and nothing is drawn (the n-th real measurement gets the n-th draws, in every
  master). A measurement belongs to the
  plant sample it measures: the inputs of the sample measured at the last communication point again (its index,
  the same values; a Jacobi master sets the plant's outputs of t_(k-1) at t_k) get that measurement again, not a
  second sample of them (docs/sensors.md, "Which sample a measurement belongs to").

Defaults: noise off (``noise_enabled`` false), 1 ms sample period; the
default experiment lasts the committed trajectory's slew.

Sampling (direct feedthrough, :mod:`flexarm_feedthrough`): the outputs at
communication point t_k are the measurement of the inputs present at t_k.
The bank takes exactly one sample per communication point (one filter
update, one draw of the noise generator), whatever the number of reads.
A communication step h may be any whole multiple n of ``sample_period``:
the FMU then also samples at t_k + T, ..., t_k + (n - 1) T inside the step,
holding the inputs of t_k (zero-order hold), so the filters and the noise
stream run at their own period; the outputs after the step are the sample at
t_k + h of the inputs set then. With n = 1 (the default 1 ms step) this is
one sample per communication point.
"""

from __future__ import annotations

import copy
import math

import numpy as np
from flexarm_feedthrough import FeedthroughSlave, whole_samples
from flexarm_fmu_base import Var, pin_module_namespace, slew_experiment, variable_table

from flexarm.loop_index import is_placeholder, received_index
from flexarm.sensors import MEASURED_SIGNALS, TRUE_SIGNALS, SensorBank, SensorSettings
from flexarm.signals import signals

pin_module_namespace(globals())  # pythonfmu 0.7.0 drops a reference per instantiation (see there)

#: Default settings: the committed file flexarm/data/sensors_default.toml (in a built FMU, its own copy:
#: the FMU's flexarm is its own, under a private name, see fmu_build/isolate.py).
DEFAULTS = SensorSettings.from_toml(None)
#: The per-link tuple field, exposed as two scalar parameters.
_GAUGE_FS = "strain_gauge_full_scale_curvature_per_m"
_GAUGE_FS_NAMES = (f"{_GAUGE_FS}_link1", f"{_GAUGE_FS}_link2")
#: Smallest value of the parameters that must be > 0 (FMI ranges are inclusive).
_POSITIVE = 1e-9
#: Largest Integer an FMI 2.0 variable can hold.
_INT32_MAX = 2**31 - 1


def _param(name: str, unit: str | None, description: str, lo=None, hi=None, start=None) -> Var:
    value = getattr(DEFAULTS, name) if start is None else start
    typ = "Boolean" if isinstance(value, bool) else "Integer" if isinstance(value, int) else "Real"
    return Var(name, "parameter", "fixed", unit, description, value, lo, hi, typ)


_INPUTS = [Var(s.name, "input", "continuous", s.unit, f"True {s.description} (plant output {s.name})", 0.0)
           for s in TRUE_SIGNALS]
_OUTPUTS = [Var(m.name, "output", "continuous", m.unit, f"Measured: {m.description}", depends_on=(s.name,))
            for s, m in zip(TRUE_SIGNALS, MEASURED_SIGNALS)]
#: The sample index passed through (flexarm.loop_index): the index of the plant sample measured.
(_INDEX_IN,) = signals("sensors", "input", "index")
(_INDEX_OUT,) = signals("sensors", "output", "index")
_INPUTS.append(Var(_INDEX_IN.name, "input", "continuous", _INDEX_IN.unit, _INDEX_IN.description, 0.0))
_OUTPUTS.append(Var(_INDEX_OUT.name, "output", "continuous", _INDEX_OUT.unit, _INDEX_OUT.description,
                    depends_on=(_INDEX_IN.name,)))

VARIABLES = variable_table([
    *_INPUTS,
    _param("noise_enabled", None, "Add the uniform sensor noise (the paper's 'with noise' case); default off",
           start=False),
    _param("noise_seed", None, "Seed of this instance's PCG64 noise generator", 0, _INT32_MAX),
    _param("encoder_noise_deg", "deg", "Encoder noise half-width (uniform on [-a, a))", 0.0),
    _param("encoder_quantization", None, "Round the encoder angles to whole counts"),
    _param("encoder_counts_per_rev", None, "Encoder counts per motor revolution", 2, 2**24),
    _param("tachometer_noise_deg_per_s", "deg/s", "Tachometer noise half-width", 0.0),
    _param("tachometer_full_scale_deg_per_s", "deg/s", "A/D full scale +-FS of the tachometer channels",
           _POSITIVE),
    _param("strain_gauge_noise_deg", "deg", "Noise half-width on each strain-gauge segment angle", 0.0),
    _param("strain_gauge_filter", None, "Apply the strain gauges' Butterworth low-pass filter"),
    _param("strain_gauge_cutoff_hz", "Hz", "Strain-gauge filter -3 dB frequency (below 1/(2 sample_period))",
           _POSITIVE),
    _param("strain_gauge_filter_order", None, "Strain-gauge Butterworth filter order", 1, 8),
    _param(_GAUGE_FS_NAMES[0], "1/m", "A/D full scale of the link-1 strain gauges, as curvature", _POSITIVE,
           start=DEFAULTS.strain_gauge_full_scale_curvature_per_m[0]),
    _param(_GAUGE_FS_NAMES[1], "1/m", "A/D full scale of the link-2 strain gauges, as curvature", _POSITIVE,
           start=DEFAULTS.strain_gauge_full_scale_curvature_per_m[1]),
    _param("accelerometer_noise_m_per_s2", "m/s2", "Accelerometer noise half-width", 0.0),
    _param("accelerometer_filter", None, "Apply the accelerometers' Butterworth low-pass filter"),
    _param("accelerometer_cutoff_hz", "Hz", "Accelerometer filter -3 dB frequency (below 1/(2 sample_period))",
           _POSITIVE),
    _param("accelerometer_filter_order", None, "Accelerometer Butterworth filter order", 1, 8),
    _param("accelerometer_full_scale_m_per_s2", "m/s2", "A/D full scale +-FS of the accelerometer channels",
           _POSITIVE),
    _param("adc_quantization", None, "Quantise the analogue channels (tachometers, gauges, accelerometers)"),
    _param("adc_bits", None, "A/D resolution, bits", 2, 24),
    Var("sample_period", "parameter", "fixed", "s",
        "Sample period of the bank (filters); every communication step must be a whole multiple of it",
        1e-3, 1e-6, 10.0),
    *_OUTPUTS,
])

#: Parameter names that are SensorSettings fields (all but the split tuple and sample_period).
_SETTING_NAMES = tuple(f for f in DEFAULTS.as_dict() if f != _GAUGE_FS)
_missing = [n for n in (*_SETTING_NAMES, *_GAUGE_FS_NAMES) if n not in {v.name for v in VARIABLES}]
if _missing:  # a new SensorSettings field needs a parameter row above
    raise RuntimeError(f"sensors FMU: no parameter for SensorSettings field(s) {_missing}")


class FlexarmSensors(FeedthroughSlave):
    """The arm's sensor bank as an FMI 2.0 co-simulation slave (direct feedthrough).

    State: one :class:`flexarm.sensors.SensorBank` (noise generator, filter
    states), advanced once per communication point; ``_pre`` holds its
    checkpoint before the current sample so that re-setting the inputs before
    ``fmi2DoStep`` re-measures from the same state (the bank rewinds).
    """

    VARIABLES = VARIABLES
    EXTRA_UNITS = {
        "deg": {"base": {"rad": 1, "factor": math.pi / 180.0}},
        "deg/s": {"base": {"rad": 1, "s": -1, "factor": math.pi / 180.0}},
        "1/m": {"base": {"m": -1}},
    }
    description = "Sandia two-link flexible arm: encoders, tachometers, strain gauges, accelerometers (sensors)"
    default_experiment = slew_experiment()

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.bank: SensorBank | None = None
        self._pre: dict | None = None  # bank checkpoint before the sample of the current communication point
        # (plant sample, inputs' bytes, measurement) of the communication point's sample (_pending) and of the
        # last committed one (_last): the same sample with the same values is the same measurement
        self._pending: tuple | None = None
        self._last: tuple | None = None
        self._true_vrs = [self._vr[s.name] for s in TRUE_SIGNALS]
        self._index_vr = self._vr[_INDEX_IN.name]

    def settings(self) -> SensorSettings:
        """The :class:`SensorSettings` of the current parameter values (validated)."""
        values = {name: self.value(name) for name in _SETTING_NAMES}
        values[_GAUGE_FS] = tuple(self.value(n) for n in _GAUGE_FS_NAMES)
        return SensorSettings(**values)

    def setup(self) -> None:
        self.bank = SensorBank(self.settings(), dt=self.value("sample_period"))
        self._pre = None
        self._pending = self._last = None

    def evaluate(self) -> np.ndarray:
        if self._pre is None:
            self._pre = self.bank.checkpoint()
        else:  # inputs changed after a read at this communication point: measure again from the same state
            self.bank.rewind(self._pre)
        values = self._values
        true = np.array([values[vr] for vr in self._true_vrs], dtype=float)
        sample, key = received_index(values[self._index_vr]), true.tobytes()
        last = self._last
        if sample is not None and last is not None and last[0] == sample and last[1] == key:
            measured = last[2].copy()  # that sample again: its measurement (the bank stays as committed)
        else:
            measured = self._sample(true)
        self._pending = (sample, key, measured)
        return np.append(measured, values[self._index_vr])  # the index of the plant sample measured

    def _sample(self, true: np.ndarray) -> np.ndarray:
        """One sample of the bank; a master's placeholder (no index, every input exactly 0) is not measured:
        zeros are passed on with index 0, the filters stay as they are (:meth:`SensorBank.skip`)."""
        if is_placeholder(self._values[self._index_vr], true):
            return self.bank.skip()
        return self.bank.measure(true)

    def commit(self, t: float, h: float, n: int) -> None:
        # A step of n sample periods: the sample at t was taken; the n - 1 samples inside the step
        # measure the inputs held since t (one filter update and one noise draw each).
        held = np.array([self._values[vr] for vr in self._true_vrs], dtype=float)
        for _ in range(n - 1):
            self._sample(held)
        self._last = self._pending if n == 1 else None  # samples of the held inputs since: the next one is new
        self._pre = None

    def samples_in_step(self, t: float, h: float) -> int:
        return whole_samples(h, self.value("sample_period"),
                             "the parameter sample_period (the filters are discretised for that period; the FMU "
                             "samples at its period inside a longer step, holding its inputs)")

    def get_sample_state(self) -> dict:
        return {"bank": _bank_state_as_lists(self.bank.get_state()),
                "pre": None if self._pre is None else copy.deepcopy(_bank_state_as_lists(self._pre)),
                "pending": _sample_as_lists(self._pending), "last": _sample_as_lists(self._last)}

    def set_sample_state(self, state: dict) -> None:
        settings = self.settings()
        if self.bank is None or self.bank.settings != settings or self.bank.dt != self.value("sample_period"):
            self.bank = SensorBank(settings, dt=self.value("sample_period"))
        self.bank.set_state(state["bank"])
        self._pre = state["pre"]
        self._pending, self._last = _sample_from_lists(state["pending"]), _sample_from_lists(state["last"])


def _bank_state_as_lists(bank_state: dict) -> dict:
    """A :meth:`SensorBank.get_state` snapshot with the filter arrays as nested lists (JSON, exact)."""
    return {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in bank_state.items()}


def _sample_as_lists(sample: tuple | None) -> list | None:
    """A (plant sample, inputs' bytes, measurement) record as JSON-exact lists (the bytes as their hex)."""
    return None if sample is None else [sample[0], sample[1].hex(), sample[2].tolist()]


def _sample_from_lists(saved: list | None) -> tuple | None:
    return None if saved is None else (saved[0], bytes.fromhex(saved[1]), np.array(saved[2], dtype=float))
