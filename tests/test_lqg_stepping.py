"""controller_lqg (Python and native) stepped at whole multiples of its 1 ms sample (issue 12: drop-in stepping).

With loop_delay_samples = 0 (direct feedthrough) a step of n samples commits the sample of t from the inputs
present at fmi2DoStep and runs the n - 1 samples inside the step with them held; with a loop delay d > 0 (no
feedthrough) fmi2DoStep runs the n samples after t with the inputs present and holds the last one's torques,
sample 0 coming from the trajectory alone and samples before d taking no measurement. Either way the FMU
equals the library law stepped every 1 ms with each measurement held until the next communication point.
Steps that are no whole multiple are refused.
"""

from __future__ import annotations

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmu_harness import ERROR, Slave, built_fmus
from native_fmus import native_fmus, unpack_alone
from test_native_lqg import MEASURED, lqg_inputs

from flexarm.control import PEAK_TORQUE
from flexarm.lqg import lqg_controller
from flexarm.lqg_bank import bank_controller

GAIN_SETS = {1: "gamma1", 2: "gamma0.1", 3: "gamma0", 4: "eq32"}
SCHEDULES = {0.2: "200ms", 0.02: "20ms", 0.0: "single"}
CASES = [
    {"loop_delay_samples": 0, "gain_set": 1, "schedule_period": 0.02},
    {"loop_delay_samples": 8, "integral_action": True, "tau1_max": 5.0},  # Jacobi at 4 ms: 2 x 4 samples
    {"loop_delay_samples": 10, "gain_set": 4, "schedule_period": 0.0, "tau2_max": 0.5},
]
#: The payload bank (estimator = 2), 200 ms schedule only.
BANK_CASES = [
    {"estimator": 2, "loop_delay_samples": 8, "integral_action": True, "tau1_max": 5.0},
    {"estimator": 2, "loop_delay_samples": 0, "gain_set": 1, "tau2_max": 0.5},
]
N_SAMPLES = 2200  # the slew (2058 samples) and a hold


def _ids(p: dict) -> str:
    return "-".join(f"{k}={v}" for k, v in p.items())


def library_law(params: dict):
    """The flexarm law of an FMU parameter set."""
    factory = bank_controller if params.get("estimator", 1) == 2 else lqg_controller
    return factory(GAIN_SETS[params.get("gain_set", 2)], SCHEDULES[params.get("schedule_period", 0.2)],
                   params.get("loop_delay_samples", 0), params.get("integral_action", False),
                   (params.get("tau1_max", PEAK_TORQUE[0]), params.get("tau2_max", PEAK_TORQUE[1])))


def library_held(params: dict, steps: list[int], inputs=None) -> np.ndarray:
    """flexarm.lqg stepped every 1 ms, the measurement of each communication point held until the next.

    Returns the torques at the communication points (len(steps) + 1 rows); the inputs present at the point of
    sample s are ``inputs(s)`` (default :func:`lqg_inputs`). Delay 0: the torques at s are sample s of the
    inputs at s. Delay d > 0: sample 0 from the trajectory, and at a point s the samples s + 1 .. s + n from
    the inputs at s, the last one's torques held; a sample before d takes the desired measurement of t = 0.
    """
    inputs = inputs or lqg_inputs
    law = library_law(params)
    d, state = law.delay, law.initial_state()
    if d == 0:
        s, rows = 0, []
        for n in [*steps, 1]:
            m = list(inputs(s).values())
            for i in range(n):
                tau, state = law.step(state, s + i, m)
                if i == 0:
                    rows.append(tau)
            s += n
        return np.array(rows[:len(steps) + 1])
    y0 = law.design.C @ law.z[0]
    tau, state = law.step(state, 0, y0)
    s, rows = 0, [tau]
    for n in steps:
        m = list(inputs(s).values())
        for i in range(1, n + 1):
            tau, state = law.step(state, s + i, y0 if s + i < d else m)
        rows.append(tau)
        s += n
    return np.array(rows)


def run_steps(s: Slave, steps: list[int], s0: int = 0) -> np.ndarray:
    """Gauss-Seidel at the communication points: set the inputs of sample s, read the torques, step n ms.

    Returns the torques at the len(steps) + 1 points, from sample s0 on.
    """
    rows, k = [], s0
    for n in [*steps, None]:
        s.set_vector(MEASURED, list(lqg_inputs(k).values()))
        rows.append(s.get(["tau1", "tau2"]))
        if n is not None:
            s.fmu.doStep(k * 1e-3, n * 1e-3)
            k += n
    return np.array(rows)


def _run(fmu, params: dict, steps: list[int], tmp_path) -> np.ndarray:
    s = Slave(fmu, str(unpack_alone(fmu, tmp_path / fmu.stem)), "lqg", **params)
    try:
        return run_steps(s, steps)
    finally:
        s.close()


def _agreement(got: np.ndarray, ref: np.ndarray) -> float:
    return float((np.abs(got - ref).max(axis=0) / np.abs(ref).max(axis=0)).max())


@pytest.mark.parametrize("params", CASES + BANK_CASES, ids=_ids)
def test_python_lqg_at_4ms_is_the_library_law_with_held_measurements(params, tmp_path):
    """(a) 4 ms steps = the library stepped every 1 ms, each measurement held over its 4 samples."""
    steps = [4] * (N_SAMPLES // 4)
    got = _run(built_fmus()["controller_lqg"], params, steps, tmp_path)
    ref = library_held(params, steps)
    np.testing.assert_array_equal(got, ref)  # bit for bit: the same law, the same products
    # the held measurements matter: every 1 ms with fresh measurements gives other torques at the same samples
    fresh = library_held(params, [1] * N_SAMPLES)[::4]
    assert np.abs(fresh - ref).max() > 1e-4


def test_python_lqg_with_variable_steps_is_the_library_law(tmp_path):
    """Any sequence of whole multiples (1, 3, 2, 7, 4 ms, ...) is the library law with the inputs held."""
    steps = [int(n) for n in np.random.default_rng(12).integers(1, 8, size=300)]
    got = _run(built_fmus()["controller_lqg"], CASES[1], steps, tmp_path)
    np.testing.assert_array_equal(got, library_held(CASES[1], steps))


@pytest.mark.parametrize("kind", ["python", "native"])
def test_lqg_in_jacobi_stepping_at_4ms_uses_the_inputs_present_at_do_step(kind, tmp_path):
    """Jacobi at 4 ms (read the torques, then set the inputs, then step), with inputs set in initialisation
    mode and extra reads: the torques read at a point are those the previous fmi2DoStep computed from the
    inputs present then (held over its 4 samples); what was set in initialisation and every read change
    nothing."""
    fmu = (built_fmus() if kind == "python" else native_fmus())["controller_lqg"]
    params = CASES[1]
    n_points = 550
    s = Slave(fmu, str(unpack_alone(fmu, tmp_path)), "lqg", start=False)
    s.fmu.setupExperiment(startTime=0.0)
    s.fmu.enterInitializationMode()
    s.set(**params)
    s.set_vector(MEASURED, list(lqg_inputs(0).values()))
    s.get(["tau1", "tau2"])
    s.fmu.exitInitializationMode()
    got = []
    try:
        for k in range(n_points):
            got.append(s.get(["tau1", "tau2"]))
            s.set_vector(MEASURED, list(lqg_inputs(4 * k + 3).values()))
            np.testing.assert_array_equal(s.get(["tau1", "tau2"]), got[-1])  # no feedthrough: reads see the same
            s.fmu.doStep(k * 4e-3, 4e-3)
    finally:
        s.close()
    ref = library_held(params, [4] * (n_points - 1), lambda s: lqg_inputs(s + 3))
    got = np.array(got)
    assert _agreement(got, ref) <= (0.0 if kind == "python" else 1e-10), np.abs(got - ref).max(axis=0)


@pytest.mark.parametrize("params", CASES, ids=_ids)
def test_native_lqg_at_4ms_equals_python(params, tmp_path):
    """(b) the native FMU stepped at 4 ms = the Python FMU stepped at 4 ms (1e-10 of the peak torque)."""
    steps = [4] * (N_SAMPLES // 4)
    ref = _run(built_fmus()["controller_lqg"], params, steps, tmp_path / "python")
    got = _run(native_fmus()["controller_lqg"], params, steps, tmp_path / "native")
    assert _agreement(got, ref) <= 1e-10, np.abs(got - ref).max(axis=0)
    assert np.abs(np.diff(got, axis=0)).max() > 0.01  # the filter and the feedback act


@pytest.mark.parametrize("kind", ["python", "native"])
def test_a_step_off_the_multiples_is_refused_and_changes_nothing(kind, tmp_path):
    """(d) 1.5 ms is refused (fmi2Error naming step_size and the allowed steps); the instance carries on."""
    fmu = (built_fmus() if kind == "python" else native_fmus())["controller_lqg"]
    params, steps = CASES[1], [2, 1, 4, 3]
    s = Slave(fmu, str(unpack_alone(fmu, tmp_path)), "lqg", **params)
    try:
        first = run_steps(s, steps)  # at sample 10, torques read, not stepped yet
        for h in (1.5e-3, 0.5e-3, 4.0001e-3):
            n = len(s.messages)
            with pytest.raises(FMICallException):
                s.fmu.doStep(10e-3, h)
            refusals = [m for status, m in s.messages[n:] if status >= ERROR]
            assert any("step_size" in m and "n * 0.001 s" in m for m in refusals), s.messages[n:]
        after = run_steps(s, [4, 1, 2], s0=10)
    finally:
        s.close()
    np.testing.assert_array_equal(after[0], first[-1])
    ref = library_held(params, [*steps, 4, 1, 2])
    np.testing.assert_allclose(np.vstack([first, after[1:]]), ref, rtol=0, atol=1e-10 * np.abs(ref).max())


def test_ssp_export_sets_the_loop_delay_of_its_step(tmp_path):
    """A Jacobi master stepping 4 ms through sensors and controller delays by 8 samples: the export says so."""
    import re
    import zipfile

    from scenarios.config import load_scenario
    from scenarios.conformance.ssp import export_ssp

    sc = load_scenario("lqg_jacobi")
    sc.cases = [c for c in sc.cases if c.key == "none"]
    sc.cases[0].parameters.setdefault("controller", {})["loop_delay_samples"] = 2  # an explicit value is honoured
    delays = {}
    for h in (1e-3, 4e-3):
        sc.step_size = h
        with zipfile.ZipFile(export_ssp(sc, tmp_path / f"{h:g}", fmu_dir=tmp_path / "fmus")["none"]) as z:
            text = "".join(z.read(n).decode() for n in z.namelist() if n.endswith(".ssv"))
        found = re.findall(r'name="loop_delay_samples"[^<]*<ssv:Integer value="(\d+)"', text)
        assert len(found) == 1, text[:2000]
        delays[h] = int(found[0])
    assert delays == {1e-3: 2, 4e-3: 8}


def test_python_bank_state_restores_bit_for_bit_and_bad_estimators_are_refused(tmp_path):
    """The payload bank's FMU state (filters, posterior, torques sent, integrators) round-trips through
    fmi2GetFMUstate / fmi2SetFMUstate; an unknown estimator, or the bank on a schedule without one, is refused
    by name."""
    fmu = built_fmus()["controller_lqg"]
    s = Slave(fmu, str(unpack_alone(fmu, tmp_path / "state")), "lqg", **BANK_CASES[0])
    try:
        run_steps(s, [1] * 300)
        saved = s.fmu.getFMUState()
        first = run_steps(s, [1] * 200, s0=300)
        s.fmu.setFMUState(saved)
        again = run_steps(s, [1] * 200, s0=300)
        s.fmu.freeFMUState(saved)
    finally:
        s.close()
    np.testing.assert_array_equal(again, first)
    for bad, words in (({"estimator": 3}, ("estimator", "kalman", "payload_bank")),
                       ({"estimator": 2, "schedule_period": 0.02}, ("estimator", "schedule_period"))):
        s = Slave(fmu, str(unpack_alone(fmu, tmp_path / f"bad{len(bad)}")), "lqg", start=False)
        try:
            s.fmu.setupExperiment(startTime=0.0)
            with pytest.raises(FMICallException):
                s.fmu.enterInitializationMode()
                s.set(**bad)
                s.fmu.exitInitializationMode()
            text = " ".join(m for status, m in s.messages if status >= ERROR)
            assert all(w in text for w in words), (bad, s.messages)
        finally:
            s.close()
