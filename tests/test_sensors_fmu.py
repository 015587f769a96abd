"""The sensors FMU: interface, direct feedthrough, same numbers as flexarm.sensors, two instances, FMU state."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
)
from fmpy.validation import validate_fmu
from fmu_harness import Slave, built_fmus

from flexarm.sensors import (
    MEASURED_SIGNAL_NAMES,
    N_SIGNALS,
    TRUE_SIGNAL_NAMES,
    SensorBank,
    SensorSettings,
)

ROOT = Path(__file__).resolve().parents[1]

DT = 1e-3
#: Every stage on: filters, noise (accelerometers too), both quantisers.
ALL_ON = dict(noise_enabled=True, noise_seed=7, accelerometer_noise_m_per_s2=0.05, strain_gauge_filter=True,
              accelerometer_filter=True, encoder_quantization=True, adc_quantization=True)
ALL_OFF = dict(noise_enabled=False, strain_gauge_filter=False, accelerometer_filter=False,
               encoder_quantization=False, adc_quantization=False)


@pytest.fixture(scope="module")
def fmus() -> dict[str, Path]:
    return built_fmus()  # the test process's one build of every FMU (tests/fmu_harness.py)


@pytest.fixture(scope="module")
def fmu_path(fmus) -> Path:
    return fmus["sensors"]


@pytest.fixture(scope="module")
def unzipped(fmu_path, tmp_path_factory):
    return extract(str(fmu_path), unzipdir=str(tmp_path_factory.mktemp("sensors_unzipped")))


def true_signals(n: int, seed: int = 0) -> np.ndarray:
    """Smooth test inputs (n, 12) in TRUE_SIGNALS order and units, inside every A/D range."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)[:, None] * DT
    freq = rng.uniform(0.5, 20.0, N_SIGNALS)
    phase = rng.uniform(0, 2 * np.pi, N_SIGNALS)
    scale = np.array([1.0, 1.0, 2.0, 2.0, 1e-3, 1e-3, 1e-3, 1e-2, 1e-2, 1e-2, 20.0, 20.0])
    return scale * np.sin(2 * np.pi * freq * t + phase) + 0.3 * scale


def run_fmu(sensors: Slave, x: np.ndarray, reads: int = 1) -> np.ndarray:
    """Master loop: set the inputs at t_k, read the outputs `reads` times, step. Returns (n, 12)."""
    out = []
    for xk in x:
        sensors.set_vector(TRUE_SIGNAL_NAMES, xk)
        ys = [sensors.get(MEASURED_SIGNAL_NAMES) for _ in range(reads)]
        for y in ys[1:]:
            np.testing.assert_array_equal(y, ys[0])
        out.append(ys[0])
        sensors.step()
    return np.array(out)


def settings_of(params: dict) -> SensorSettings:
    return SensorSettings.from_toml().replace(**params)


# -- model description ---------------------------------------------------------------
def test_validate_fmu_reports_no_problems(fmu_path):
    assert validate_fmu(str(fmu_path)) == []


def test_inputs_are_the_plant_outputs_and_outputs_the_measured_names(fmus):
    md = read_model_description(str(fmus["sensors"]))
    plant = read_model_description(str(fmus["plant"]))
    inputs = [v.name for v in md.modelVariables if v.causality == "input"]
    outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    plant_outputs = {v.name: v for v in plant.modelVariables if v.causality == "output"}
    assert inputs == [*TRUE_SIGNAL_NAMES, "sample_index"]  # and the loop's sample index (docs/control.md)
    assert outputs == [*MEASURED_SIGNAL_NAMES, "sample_index_m"]
    by_name = {v.name: v for v in md.modelVariables}
    for name in inputs:  # the master connects plant.NAME -> sensors.NAME
        assert name in plant_outputs and plant_outputs[name].unit == by_name[name].unit
    # direct feedthrough, channel by channel: output i depends on input i only
    for unknown, true_name in zip(md.outputs, [*TRUE_SIGNAL_NAMES, "sample_index"]):
        assert [v.name for v in unknown.dependencies] == [true_name]


def test_every_sensor_setting_is_a_parameter(fmu_path):
    md = read_model_description(str(fmu_path))
    by_name = {v.name: v for v in md.modelVariables}
    defaults = SensorSettings.from_toml()
    for field, value in defaults.as_dict().items():
        if isinstance(value, tuple):
            names = [f"{field}_link1", f"{field}_link2"]
        else:
            names = [field]
        for i, name in enumerate(names):
            var = by_name[name]
            assert var.causality == "parameter" and var.variability == "fixed", name
            expected = value[i] if isinstance(value, tuple) else value
            typ = {bool: "Boolean", int: "Integer", float: "Real"}[type(expected)]
            assert var.type == typ, name
            start = {"Boolean": lambda s: s == "true", "Integer": int, "Real": float}[typ](var.start)
            if name == "noise_enabled":  # the FMU's default is off (issue 12: defaults give the paper's no-noise case)
                assert start is False, name
                continue
            assert start == expected, name
    assert by_name["noise_enabled"].type == "Boolean" and by_name["noise_seed"].type == "Integer"
    assert (int(by_name["noise_seed"].min), int(by_name["noise_seed"].max)) == (0, 2**31 - 1)
    assert by_name["encoder_noise_deg"].unit == "deg" and by_name["strain_gauge_cutoff_hz"].unit == "Hz"
    assert float(by_name["sample_period"].start) == DT and by_name["sample_period"].unit == "s"


# -- numbers ---------------------------------------------------------------------------
def test_everything_off_passes_the_inputs_through_exactly(fmu_path, unzipped):
    x = true_signals(50, seed=1)
    sensors = Slave(fmu_path, unzipped, **ALL_OFF)
    try:
        y = run_fmu(sensors, x, reads=2)
        np.testing.assert_array_equal(y, x)
        assert not sensors.errors()
    finally:
        sensors.close()


def test_outputs_in_initialization_mode_reflect_the_inputs_just_set(fmu_path, unzipped):
    md = read_model_description(str(fmu_path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="init")
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu.instantiate()
    try:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.setBoolean([vr["noise_enabled"]], [False])
        fmu.setReal([vr["q1"], vr["eps4"]], [0.25, -1e-3])
        assert fmu.getReal([vr["q1_m"], vr["eps4_m"], vr["q2_m"]]) == [0.25, -1e-3, 0.0]
        fmu.setReal([vr["q1"]], [0.5])
        assert fmu.getReal([vr["q1_m"]]) == [0.5]
        fmu.exitInitializationMode()
        assert fmu.getReal([vr["q1_m"]]) == [0.5]
        fmu.setReal([vr["q1"]], [0.75])  # the sample at t0 is taken with the inputs present at t0
        assert fmu.getReal([vr["q1_m"]]) == [0.75]
        fmu.terminate()
    finally:
        fmu.freeInstance()


@pytest.mark.parametrize("params", [ALL_ON, dict(noise_enabled=True, noise_seed=123)], ids=["all_on", "noise"])
def test_fmu_equals_sensor_bank_bit_for_bit(fmu_path, unzipped, params):
    """The FMU layer changes nothing: same settings and seed -> the same numbers as SensorBank."""
    n = 300
    x = true_signals(n, seed=2)
    bank = SensorBank(settings_of(params), dt=DT)
    expected = np.array([bank.measure(xk) for xk in x])
    sensors = Slave(fmu_path, unzipped, **params)
    try:
        y = run_fmu(sensors, x, reads=3)
        np.testing.assert_array_equal(y, expected)
        assert np.any(y != x)
    finally:
        sensors.close()


def test_one_sample_per_communication_point_whatever_the_master_reads(fmu_path, unzipped):
    """Unread points still take their sample; inputs changed after a read are re-measured from the same state."""
    n = 120
    x = true_signals(n, seed=3)
    bank = SensorBank(settings_of(ALL_ON), dt=DT)
    expected = np.array([bank.measure(xk) for xk in x])
    sensors = Slave(fmu_path, unzipped, **ALL_ON)
    try:
        for k, xk in enumerate(x):
            if k % 3 == 1:  # a wrong input first, read, then the right one
                sensors.set_vector(TRUE_SIGNAL_NAMES, xk + 0.1)
                sensors.get(MEASURED_SIGNAL_NAMES)
            sensors.set_vector(TRUE_SIGNAL_NAMES, xk)
            if k % 3 != 2:  # every third point is never read
                np.testing.assert_array_equal(sensors.get(MEASURED_SIGNAL_NAMES), expected[k])
            sensors.step()
    finally:
        sensors.close()


def test_two_instances_with_different_seeds_are_independent(fmu_path, unzipped):
    n = 2000
    x = np.zeros((n, N_SIGNALS))
    params = dict(noise_enabled=True, accelerometer_noise_m_per_s2=1.0)
    a = Slave(fmu_path, unzipped, name="a", noise_seed=1, **params)
    b = Slave(fmu_path, unzipped, name="b", noise_seed=2, **params)
    c = Slave(fmu_path, unzipped, name="c", noise_seed=1, **params)
    try:
        na, nb, nc = [], [], []
        for k, xk in enumerate(x):  # interleaved, as a master would
            for s, out in ((a, na), (b, nb), (c, nc)):
                # all-zero signals with the sample's index: a measurement of zero (without the index they would be
                # a master's placeholder, which is not measured: tests/test_sensors_placeholder.py)
                s.set_vector([*TRUE_SIGNAL_NAMES, "sample_index"], [*xk, k + 1.0])
                out.append(s.get(MEASURED_SIGNAL_NAMES))
            for s in (a, b, c):
                s.step()
        na, nb, nc = map(np.array, (na, nb, nc))
        np.testing.assert_array_equal(na, nc)  # same seed: same stream, other instances notwithstanding
        assert np.all(na != nb)
        for ch in range(N_SIGNALS):
            r = np.corrcoef(na[:, ch], nb[:, ch])[0, 1]
            assert abs(r) < 4.0 / np.sqrt(n), (MEASURED_SIGNAL_NAMES[ch], r)
        # uniform on [-a, a): the encoder channel's half-width is 0.1 deg
        assert np.abs(na[:, 0]).max() <= np.radians(0.1)
        assert np.std(na[:, 0]) == pytest.approx(np.radians(0.1) / np.sqrt(3), rel=0.05)
    finally:
        for s in (a, b, c):
            s.close()


def test_get_set_fmu_state_reproduces_bit_for_bit(fmu_path, unzipped):
    x = true_signals(200, seed=4)
    sensors = Slave(fmu_path, unzipped, **ALL_ON)
    try:
        run_fmu(sensors, x[:50])
        # snapshot at a communication point whose inputs are set and already read
        sensors.set_vector(TRUE_SIGNAL_NAMES, x[50])
        first = sensors.get(MEASURED_SIGNAL_NAMES)
        state = sensors.fmu.getFMUstate()
        serialized = sensors.fmu.serializeFMUstate(state)
        t_snap = sensors.time
        sensors.step()
        reference = np.vstack([first, run_fmu(sensors, x[51:])])

        for restore in ("state", "serialized"):
            if restore == "state":
                sensors.fmu.setFMUstate(state)
            else:
                restored = sensors.fmu.deSerializeFMUstate(serialized)
                sensors.fmu.setFMUstate(restored)
                sensors.fmu.freeFMUstate(restored)
            sensors.time = t_snap
            again = sensors.get(MEASURED_SIGNAL_NAMES)
            sensors.step()
            np.testing.assert_array_equal(np.vstack([again, run_fmu(sensors, x[51:])]), reference)
        sensors.fmu.freeFMUstate(state)
        assert not sensors.errors()
    finally:
        sensors.close()


# -- errors ----------------------------------------------------------------------------
def test_step_size_must_be_a_whole_multiple_of_sample_period(fmu_path, unzipped):
    sensors = Slave(fmu_path, unzipped, **ALL_OFF)
    try:
        sensors.set_vector(TRUE_SIGNAL_NAMES, np.ones(N_SIGNALS))
        with pytest.raises(FMICallException):
            sensors.fmu.doStep(0.0, 1.5e-3)
        assert any("sample_period" in m and "0.0015" in m and "whole multiple" in m for m in sensors.errors())
        sensors.step(DT)  # the right step still works afterwards
        np.testing.assert_array_equal(sensors.get(["q1_m"]), [1.0])
    finally:
        sensors.close()
    other = Slave(fmu_path, unzipped, sample_period=2e-3, **ALL_OFF)
    try:
        with pytest.raises(FMICallException):
            other.fmu.doStep(0.0, 1e-3)  # shorter than the sample period
        other.step(2e-3)
    finally:
        other.close()


@pytest.mark.parametrize("n", [2, 4])
def test_a_step_of_n_periods_samples_n_times_holding_the_inputs(fmu_path, unzipped, n):
    """h = n T, noise and filters on: n samples of T with the inputs held, bit for bit (the noise stream too)."""
    points = 60
    x = true_signals(points, seed=5)
    bank = SensorBank(settings_of(ALL_ON), dt=DT)
    expected = []
    for xk in x:  # the bank sampled every T; the inputs change only at the communication points
        expected.append(bank.measure(xk))
        for _ in range(n - 1):
            bank.measure(xk)
    long = Slave(fmu_path, unzipped, **ALL_ON)
    try:
        got = []
        for xk in x:
            long.set_vector(TRUE_SIGNAL_NAMES, xk)
            got.append(long.get(MEASURED_SIGNAL_NAMES))
            long.step(n * DT)
        np.testing.assert_array_equal(np.array(got), np.array(expected))
        assert not long.errors()
    finally:
        long.close()


def test_bad_parameters_are_rejected_with_their_name_and_range(fmu_path, unzipped):
    sensors = Slave(fmu_path, unzipped, start=False)
    try:
        sensors.fmu.setupExperiment(startTime=0.0)
        sensors.fmu.enterInitializationMode()
        for name, value in (("noise_seed", -1), ("strain_gauge_filter_order", 9)):
            with pytest.raises(FMICallException) as exc:
                sensors.set(**{name: value})
            assert exc.value.status == 3  # fmi2Error
        errors = " ".join(sensors.errors())
        assert "noise_seed: -1 is outside the allowed range [0, " in errors
        assert "strain_gauge_filter_order" in errors and "[1, 8]" in errors
        with pytest.raises(FMICallException, match="fmi2ExitInitializationMode"):
            sensors.fmu.exitInitializationMode()
        sensors.set(noise_seed=1, strain_gauge_filter_order=2)  # valid values: initialisation goes through
        sensors.fmu.exitInitializationMode()
        sensors.step()
    finally:
        sensors.close()
    # a cut-off above the Nyquist frequency of the sample period fails initialisation with a clear message
    sensors = Slave(fmu_path, unzipped, start=False)
    try:
        sensors.fmu.setupExperiment(startTime=0.0)
        sensors.fmu.enterInitializationMode()
        sensors.set(strain_gauge_filter=True, strain_gauge_cutoff_hz=600.0)
        with pytest.raises(FMICallException, match="fmi2ExitInitializationMode"):
            sensors.fmu.exitInitializationMode()
        assert any("strain_gauge_cutoff_hz" in m and "500" in m for m in sensors.errors())
        assert sensors.status("doStep", 0.0, DT) == 3  # still in initialisation mode
        sensors.set(strain_gauge_cutoff_hz=100.0)
        sensors.fmu.exitInitializationMode()
        sensors.step()
    finally:
        sensors.close()


def test_many_instances_in_one_process(fmu_path, unzipped):
    """pythonfmu 0.7.0 drops a reference to the slave module per instantiation (see pin_module_namespace)."""
    import gc

    for i in range(30):
        sensors = Slave(fmu_path, unzipped, f"s{i}", **ALL_OFF)
        sensors.step()
        sensors.close()
        gc.collect()
