"""The native (C) sensors FMU against the Python sensors FMU: NumPy's PCG64 stream, filters, quantisation."""

from __future__ import annotations

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmu_harness import _sensor_inputs, built_fmus
from native_fmus import native_fmus, run_fmpy, unpack_alone

N_STEPS = 300
#: Bit for bit: both kinds design the filters with flexarm/filter_design.py (the native C generated from it), from
#: the tangent of their own C library (Python) and the portable one (native), which agree here.
IDENTICAL = {
    "noise": {"noise_enabled": True, "noise_seed": 11, "accelerometer_noise_m_per_s2": 0.05},
    "noise and quantisation": {"noise_enabled": True, "noise_seed": 12345, "encoder_quantization": True,
                               "adc_quantization": True, "adc_bits": 10},
    "seed 0": {"noise_enabled": True, "noise_seed": 0},
    "largest seed": {"noise_enabled": True, "noise_seed": 2**31 - 1},
    "filters": {"strain_gauge_filter": True, "accelerometer_filter": True, "strain_gauge_filter_order": 4},
    "orders 5 and 8": {"strain_gauge_filter": True, "strain_gauge_filter_order": 5, "strain_gauge_cutoff_hz": 37.0,
                       "accelerometer_filter": True, "accelerometer_filter_order": 8, "accelerometer_cutoff_hz": 3.3},
    "everything": {"noise_enabled": True, "noise_seed": 11, "accelerometer_noise_m_per_s2": 0.05,
                   "strain_gauge_filter": True, "accelerometer_filter": True, "adc_quantization": True},
}


@pytest.fixture(scope="module")
def sensors():
    return built_fmus()["sensors"], native_fmus()["sensors"]


@pytest.mark.parametrize("case", list(IDENTICAL))
def test_native_sensors_equal_python_bit_for_bit(sensors, case):
    python, native = sensors
    names, ref = run_fmpy(python, N_STEPS, _sensor_inputs, IDENTICAL[case])
    names_n, got = run_fmpy(native, N_STEPS, _sensor_inputs, IDENTICAL[case])
    assert names == names_n
    np.testing.assert_array_equal(got, ref)
    if IDENTICAL[case].get("noise_enabled"):
        _, clean = run_fmpy(native, N_STEPS, _sensor_inputs, {})
        assert not np.array_equal(got, clean)  # the noise is there


def test_native_sensors_odd_filter_orders_agree_to_1e12(sensors):
    """Order 7 at 200 Hz: the two kinds' designs (one source) end a few ulps apart here, which the closed filter
    carries to the outputs' last bits: 1e-12 of each channel's range."""
    params = {"strain_gauge_filter": True, "strain_gauge_filter_order": 3, "accelerometer_filter": True,
              "accelerometer_filter_order": 7, "accelerometer_cutoff_hz": 200.0}
    python, native = sensors
    _, ref = run_fmpy(python, N_STEPS, _sensor_inputs, params)
    _, got = run_fmpy(native, N_STEPS, _sensor_inputs, params)
    scale = np.abs(ref).max(axis=0)
    assert (np.abs(got - ref) <= 1e-12 * scale).all()


def test_native_sensors_step_of_several_periods_samples_inside(sensors, tmp_path):
    """A 5 ms step = five 1 ms samples with the inputs held (noise stream and filters run at their period)."""
    native = sensors[1]
    params = {"noise_enabled": True, "noise_seed": 3, "strain_gauge_filter": True}
    held = {k: v for k, v in _sensor_inputs(0).items()}
    _, fine = run_fmpy(native, 10, lambda k: held, params)
    _, coarse = run_fmpy(native, 2, lambda k: held, params, dt=5e-3)
    np.testing.assert_array_equal(coarse, fine[::5])


def test_native_sensors_refuse_bad_steps_and_cutoffs(sensors, tmp_path):
    from fmu_harness import Slave

    native = sensors[1]
    unz = unpack_alone(native, tmp_path / "s")
    s = Slave(native, unz)
    with pytest.raises(FMICallException):
        s.fmu.doStep(0.0, 1.5e-3)
    assert any("step_size" in m and "sample_period" in m for _, m in s.messages)
    s.fmu.doStep(0.0, 1e-3)  # the refused step changed nothing
    s.fmu.freeInstance()
    s = Slave(native, unz, start=False)
    s.fmu.setupExperiment(startTime=0.0)
    s.fmu.enterInitializationMode()
    s.set(strain_gauge_filter=True, strain_gauge_cutoff_hz=600.0)
    with pytest.raises(FMICallException):
        s.fmu.exitInitializationMode()
    assert any("strain_gauge_cutoff_hz" in m and "Nyquist" in m for _, m in s.messages)
    s.set(strain_gauge_cutoff_hz=100.0)
    s.fmu.exitInitializationMode()
    s.fmu.freeInstance()


@pytest.mark.parametrize("name", ["sensors", "plant"])
def test_native_fmu_state_restores_bit_for_bit(name, tmp_path):
    """fmi2GetFMUstate / serialise / deserialise / fmi2SetFMUstate, also into a second instance."""
    from fmu_harness import Slave, drive

    native = native_fmus()[name]
    unz = unpack_alone(native, tmp_path / name)
    params = {"noise_enabled": True, "noise_seed": 5, "strain_gauge_filter": True} if name == "sensors" else \
        {"payload_mass": 0.275}
    a = Slave(native, unz, "a", **params)
    drive(a, name, 0, 20)
    state = a.fmu.getFMUstate()
    blob = a.fmu.serializeFMUstate(state)
    first = drive(a, name, 20, 30)
    a.fmu.setFMUstate(state)
    np.testing.assert_array_equal(drive(a, name, 20, 30), first)
    b = Slave(native, unz, "b", **params)
    b.fmu.setFMUstate(b.fmu.deSerializeFMUstate(blob))
    np.testing.assert_array_equal(drive(b, name, 20, 30), first)
    a.fmu.freeFMUstate(state)
    a.fmu.freeInstance()
    b.fmu.freeInstance()
