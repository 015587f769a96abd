"""The native (C) controller FMUs against the Python ones: control law, gain scheduling, saturation."""

from __future__ import annotations

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmu_harness import Slave, _controller_inputs, built_fmus
from native_fmus import native_fmus, run_fmpy, unpack_alone

CONTROLLERS = ("controller", "controller_ff", "controller_fb", "controller_dlqr")
N_STEPS = 2200  # past the end of the slew (2110 steps): the hold phase too


def _python_params(py_fmu, native_params: dict) -> dict:
    """The same configuration for the Python FMU (Strings there until the interface's Enumerations land)."""
    md = read_model_description(str(py_fmu))
    types = {v.name: v.type for v in md.modelVariables}
    out = dict(native_params)
    names = {1: "gamma1", 2: "gamma0.1", 3: "gamma0", 4: "eq32"}
    if types.get("gain_set") == "String" and "gain_set" in out:
        out["gain_set"] = names[out["gain_set"]]
    if "omega7_estimate" in out and "omega7_estimate" not in types:
        out["omega7"] = {1: "tachometer", 2: "rigid"}[out.pop("omega7_estimate")]
    return out


CASES = [
    {},
    {"gain_set": 1, "schedule_period": 0.02},
    {"gain_set": 4, "schedule_period": 0.0, "omega7_estimate": 2, "tau1_max": 3.0},
]


@pytest.mark.parametrize("name", CONTROLLERS)
def test_native_controller_matches_python(name):
    py, native = built_fmus()[name], native_fmus()[name]
    for params in CASES:
        _, ref = run_fmpy(py, N_STEPS, _controller_inputs, _python_params(py, params))
        _, got = run_fmpy(native, N_STEPS, _controller_inputs, params)
        np.testing.assert_array_equal(got[:, 2:], ref[:, 2:])  # the sample-index outputs: exact
        got, ref = got[:, :2], ref[:, :2]  # the torques
        scale = np.abs(ref).max(axis=0)
        assert (np.abs(got - ref) <= 1e-10 * scale).all(), (params, np.abs(got - ref).max())
        limits = np.array([params.get("tau1_max", 7.0), params.get("tau2_max", 2.25)])
        assert (np.abs(got) <= limits).all()
        if name != "controller_ff":
            assert (np.abs(got) == limits).any()  # these inputs drive the saturation


def test_native_controller_interface_equals_the_python_one_and_is_lean():
    """Choices are Integers listing them (libcosim cannot set Enumerations), exactly as the Python FMU's."""
    from scenarios.master.values import parse_choices

    fmus = native_fmus()
    md = read_model_description(str(fmus["controller"]))
    python_md = read_model_description(str(built_fmus()["controller"]))
    var = {v.name: v for v in md.modelVariables}
    python_var = {v.name: v for v in python_md.modelVariables}
    for name in ("gain_set", "omega7_estimate"):
        assert var[name].type == python_var[name].type == "Integer"
        assert var[name].description == python_var[name].description
        assert int(var[name].start) == int(python_var[name].start)
    assert parse_choices(var["gain_set"].description) == {"gamma1": 1, "gamma0.1": 2, "gamma0": 3, "eq32": 4}
    assert int(var["gain_set"].start) == 2
    # no String, as in the Python FMU (issue 31: a learned feedforward is a file in the resources)
    assert [v.name for v in md.modelVariables if v.type == "String"] == []
    import zipfile

    with zipfile.ZipFile(fmus["controller_ff"]) as z:  # open loop: no gains inside
        assert sorted(n for n in z.namelist() if n.startswith("resources/")) == ["resources/trajectory.txt"]


def test_native_controller_refuses_off_grid_steps_and_bad_schedules(tmp_path):
    native = native_fmus()["controller"]
    unz = unpack_alone(native, tmp_path / "c")
    s = Slave(native, unz)
    with pytest.raises(FMICallException):
        s.fmu.doStep(0.0, 1.5e-3)
    assert any("step_size" in m for _, m in s.messages)
    s.fmu.doStep(0.0, 2e-3)  # any multiple of 1 ms
    s.fmu.freeInstance()
    s = Slave(native, unz, start=False)
    s.fmu.setupExperiment(startTime=0.0)
    s.fmu.enterInitializationMode()
    s.set(schedule_period=0.1)
    with pytest.raises(FMICallException):
        s.fmu.exitInitializationMode()
    assert any("schedule_period" in m and "0.02" in m for _, m in s.messages)
    s.set(schedule_period=0.02)
    s.fmu.exitInitializationMode()
    s.fmu.freeInstance()


def test_the_paper_s_law_reads_its_predictor_only_when_it_measures_a_delay(tmp_path):
    """The predictor's design (lqg_200ms.txt) is read and checked when the loop delay is first measured: a
    changed file leaves a Gauss-Seidel run untouched, and the first fmi2DoStep that measures a delay refuses it
    by name (fmi2Error, never a run on another build's numbers)."""
    native = native_fmus()["controller"]
    unz = unpack_alone(native, tmp_path / "c")
    path = unz / "resources" / "lqg_200ms.txt"
    path.write_bytes(path.read_bytes() + b"\n")
    for name, lag in (("gauss_seidel", 0), ("jacobi", 1)):
        s = Slave(native, unz, name)
        s.get(["tau1"])  # a master that reads at t = 0 (no late start: docs/control.md)
        for k in range(5):
            s.set(sample_index_m=float(k - lag + 1))  # the index of plant sample j is j + 1 (0: none yet)
            if lag and k == 1:
                with pytest.raises(FMICallException):
                    s.fmu.doStep(k * 1e-3, 1e-3)
                break
            s.fmu.doStep(k * 1e-3, 1e-3)
        changed = [m for _, m in s.messages if "lqg_200ms.txt" in m and "SHA-256" in m]
        assert bool(changed) == bool(lag), s.messages
        s.fmu.freeInstance()
