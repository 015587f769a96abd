"""The native (C) LQG controller FMU against the Python one: the law, its stepping, its state, closed loop (the
single Kalman filter; the stepping and platform tests for both estimators, 1 kalman and 2 payload_bank; the
payload bank's own law and state in tests/test_native_lqg_bank.py).

What is compared: the two torques of ``controller_lqg`` over the whole slew plus a hold (2200 samples),
the native FMU against the Python FMU driven by the same inputs; and Table 2's four cases closed loop
(plant + sensors + controller_lqg) in the ``lqg`` and ``lqg_jacobi`` scenarios, native set against
Python set. The inputs follow the path with small perturbations of every measurement (the regime the
filter runs in); far off the path the filter's lightly damped modes accumulate rounding, and two correct
implementations differ by up to 1e-10 of the peak torque (measured with the robustness tests' inputs).
"""

from __future__ import annotations

import shutil
import struct
import subprocess
import zipfile

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
from fmu_harness import Slave, built_fmus
from native_fmus import compile_host, native_fmus, read_host_csv, run_fmpy, unpack_alone, wine_env

from flexarm.lqg import lqg_controller
from flexarm.lqg_bank import load_bank

N_STEPS = 2200  # the slew (2058 samples) and a hold after it
MEASURED = ("q1_m", "q2_m", "qd1_m", "qd2_m", "eps1_m", "eps2_m", "eps3_m", "eps4_m", "eps5_m", "eps6_m")
#: Perturbation amplitudes of the ten measurements (rad, rad/s, rad) and their periods (samples).
AMPLITUDE = np.array([2e-4, 2e-4, 5e-3, 5e-3] + [2e-5] * 6)
PERIOD = np.array([310, 170, 90, 130, 50, 70, 110, 40, 60, 80])


def _desired_measurements() -> np.ndarray:
    law = lqg_controller()
    return law.z @ law.design.C.T


_Y_D = _desired_measurements()


def lqg_inputs(k: int) -> dict[str, float]:
    """The desired measurements of sample k (the last one in the hold) plus a perturbation of each."""
    y = _Y_D[min(k, len(_Y_D) - 1)] + AMPLITUDE * np.sin(2 * np.pi * k / PERIOD + np.arange(10))
    return {n: float(v) for n, v in zip(MEASURED, y)}


#: delay 0 and 2, integral action off and on, gain sets gamma1 (1) and gamma0.1 (2); the integral runs with
#: a shoulder limit of 5 N.m, below the feedforward's 5.6 N.m peak: saturation and anti-windup active.
CASES = [{"loop_delay_samples": d, "integral_action": i, "gain_set": g, "schedule_period": p,
          **({"tau1_max": 5.0} if i else {})}
         for d in (0, 2) for i in (False, True) for g, p in ((1, 0.02), (2, 0.2))]
CASES.append({"loop_delay_samples": 10, "gain_set": 4, "schedule_period": 0.0, "tau2_max": 0.5})


#: The outputs compared: the torques (the sample-index outputs after them are compared in tests/test_loop_delay.py).
TORQUES = ["tau1", "tau2"]


def _agreement(got: np.ndarray, ref: np.ndarray) -> float:
    """Largest |native - Python| over samples, relative to each torque's peak (the first two columns; the
    sample-index outputs after them, when both have them, must be equal)."""
    if got.shape[1] > 2 and ref.shape[1] > 2:
        np.testing.assert_array_equal(got[:, 2:], ref[:, 2:])
    got, ref = got[:, :2], ref[:, :2]
    return float((np.abs(got - ref).max(axis=0) / np.abs(ref).max(axis=0)).max())


@pytest.mark.parametrize("params", CASES, ids=lambda p: "-".join(f"{k}={v}" for k, v in p.items()))
def test_native_lqg_matches_python(params):
    py, native = built_fmus()["controller_lqg"], native_fmus()["controller_lqg"]
    _, ref = run_fmpy(py, N_STEPS, lqg_inputs, params, outputs=TORQUES)
    _, got = run_fmpy(native, N_STEPS, lqg_inputs, params, outputs=TORQUES)
    assert _agreement(got, ref) <= 1e-10, (params, np.abs(got - ref).max(axis=0))
    limits = np.array([params.get("tau1_max", 7.0), params.get("tau2_max", 2.25)])
    assert (np.abs(got) <= limits).all()
    saturates = (np.abs(ref) == limits).any(axis=0)
    assert saturates.any() == ("tau1_max" in params or "tau2_max" in params), (params, saturates)
    assert np.abs(np.diff(got, axis=0)).max() > 0.01  # the filter and the feedback act


def _jacobi_run(fmu, params: dict, n: int, extra_reads: bool, h: float = 1e-3) -> np.ndarray:
    """A Jacobi master stepping h: read the torques, then set the inputs, then doStep.

    Inputs are set (and the torques read) in initialisation mode, and changed before the first step. With
    `extra_reads` the torques are also read after every set, and every third point the inputs are set twice
    with a read in between: only the inputs present at fmi2DoStep may count, and no read may change anything.
    """
    md = read_model_description(str(fmu))
    var = {v.name: v for v in md.modelVariables}
    s = FMU2Slave(guid=md.guid, unzipDirectory=str(unpack_alone(fmu, fmu.parent / f"jacobi_{fmu.stem}_{extra_reads}")),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="jacobi")
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    for name, value in params.items():
        setter = {"Integer": s.setInteger, "Boolean": s.setBoolean, "Real": s.setReal}[var[name].type]
        setter([var[name].valueReference], [value])
    taus = [var["tau1"].valueReference, var["tau2"].valueReference]
    meas = [var[m].valueReference for m in MEASURED]
    s.setReal(meas, list(lqg_inputs(5).values()))
    if extra_reads:
        s.getReal(taus)
    s.exitInitializationMode()
    rows = [s.getReal(taus)]
    s.setReal(meas, list(lqg_inputs(9).values()))
    s.doStep(0.0, h)
    samples = int(round(h / 1e-3))  # 1 ms samples per step: the inputs follow the path at the step's samples
    for k in range(1, n):
        rows.append(s.getReal(taus))
        if extra_reads and k % 3 == 0:
            s.setReal(meas, list(lqg_inputs(samples * k + 7).values()))
            s.getReal(taus)
        s.setReal(meas, list(lqg_inputs(samples * k - 1).values()))
        if extra_reads:
            s.getReal(taus)
            s.getReal(taus)
        s.doStep(k * h, h)
    s.terminate()
    s.freeInstance()
    return np.array(rows)


@pytest.mark.parametrize("estimator", [1, 2])
@pytest.mark.parametrize("h", [1e-3, 4e-3])
def test_native_lqg_in_jacobi_stepping_ignores_reads(tmp_path, h, estimator):
    """Jacobi stepping (read, set, doStep) at 1 ms and 4 ms (the samples inside the step with the inputs
    held): native and Python compute the same torques, both estimators (the bank within 1e-9 of the peak
    torque: see the module docstring), and extra reads, also between two sets, change nothing at all."""
    params = {"loop_delay_samples": 2, "integral_action": True, "estimator": estimator}
    fmus = {}
    for kind, fmu in (("python", built_fmus()["controller_lqg"]), ("native", native_fmus()["controller_lqg"])):
        fmus[kind] = tmp_path / kind / fmu.name
        fmus[kind].parent.mkdir()
        shutil.copy2(fmu, fmus[kind])
    ref = _jacobi_run(fmus["python"], params, 600, False, h)
    got = _jacobi_run(fmus["native"], params, 600, False, h)
    # the bank's likelihoods on these off-model inputs: measured up to 5.9e-10 (committing another sample: ~1 N.m)
    assert _agreement(got, ref) <= (1e-10 if estimator == 1 else 1e-9)
    for kind in fmus:
        np.testing.assert_array_equal(_jacobi_run(fmus[kind], params, 600, True, h), ref if kind == "python" else got)


def test_native_lqg_state_reset_and_errors(tmp_path):
    """FMU state get/set and (de)serialise into another instance repeat bit for bit; fmi2Reset starts over;
    a step that is no whole multiple of 1 ms and a bad schedule_period are refused naming them."""
    native = native_fmus()["controller_lqg"]
    unz = unpack_alone(native, tmp_path / "lqg")
    params = {"loop_delay_samples": 3, "integral_action": True, "tau1_max": 5.0}

    def drive(s: Slave, k0: int, n: int) -> np.ndarray:
        rows = []
        for k in range(k0, k0 + n):
            u = lqg_inputs(k)
            s.set_vector(list(u), list(u.values()))
            rows.append(s.get(["tau1", "tau2"]))
            s.fmu.doStep(k * 1e-3, 1e-3)
        return np.array(rows)

    a = Slave(native, unz, "a", **params)
    from_start = drive(a, 0, 1000)
    state = a.fmu.getFMUstate()
    blob = a.fmu.serializeFMUstate(state)
    first = drive(a, 1000, 60)
    a.fmu.setFMUstate(state)
    np.testing.assert_array_equal(drive(a, 1000, 60), first)
    b = Slave(native, unz, "b")  # another configuration and history: the state brings the parameters along
    drive(b, 0, 5)
    b.fmu.setFMUstate(b.fmu.deSerializeFMUstate(blob))
    np.testing.assert_array_equal(drive(b, 1000, 60), first)
    a.fmu.freeFMUstate(state)
    a.fmu.reset()
    a.start(**params)
    np.testing.assert_array_equal(drive(a, 0, 1000), from_start)
    with pytest.raises(FMICallException):
        a.fmu.doStep(1.0, 1.5e-3)
    assert any("step_size" in m and "1 ms" in m for _, m in a.messages)
    a.fmu.doStep(1.0, 1e-3)  # the instance carries on
    for s in (a, b):
        s.fmu.freeInstance()
    c = Slave(native, unz, "c", start=False)
    c.fmu.setupExperiment(startTime=0.0)
    c.fmu.enterInitializationMode()
    c.set(schedule_period=0.1)
    with pytest.raises(FMICallException):
        c.fmu.exitInitializationMode()
    assert any("schedule_period" in m and "0.02" in m for _, m in c.messages)
    c.set(schedule_period=0.0)
    c.fmu.exitInitializationMode()
    c.fmu.freeInstance()


def test_native_lqg_interface_and_resources():
    """The Python FMU's variables exactly; the matrices travel as resources, written from flexarm/data/lqg."""
    from fmu_build.native_resources import SCHEDULES, TRAJECTORY_RESOURCE, bank_resource, design_resource

    native = native_fmus()["controller_lqg"]
    md, py_md = read_model_description(str(native)), read_model_description(str(built_fmus()["controller_lqg"]))
    fields = ("name", "valueReference", "type", "causality", "variability", "unit", "start", "min", "max",
              "description")
    assert [[getattr(v, f) for f in fields] for v in md.modelVariables] == \
        [[getattr(v, f) for f in fields] for v in py_md.modelVariables]
    assert md.coSimulation.modelIdentifier == "FlexarmControllerLQGNative"
    with zipfile.ZipFile(native) as z:
        resources = sorted(n.removeprefix("resources/") for n in z.namelist() if n.startswith("resources/"))
        assert resources == sorted([TRAJECTORY_RESOURCE, *(design_resource(s) for s in SCHEDULES),
                                    bank_resource("200ms")])
        text = z.read(f"resources/{design_resource('200ms')}").decode()
        bank_text = z.read(f"resources/{bank_resource('200ms')}").decode()
    from flexarm.lqg_design import LqgDesign

    design = LqgDesign.load("200ms")
    lines = text.splitlines()
    at = lines.index(f"M {design.M.size}")
    first = [struct.unpack(">d", bytes.fromhex(h))[0] for h in lines[at + 1].split()]
    np.testing.assert_array_equal(first, design.M.ravel()[:8])  # bit patterns, exact
    bank = load_bank("200ms")
    lines = bank_text.splitlines()
    for name, values in (("psi", np.array([b.psi for b in bank.filters])),
                         ("delta_acceleration", np.array([b.delta_acceleration for b in bank.filters])),
                         ("S_inv", np.array([b.S_inv for b in bank.filters]))):
        at = lines.index(f"{name} {values.size}")
        row = values[0].size // 8 + 3  # a row inside the second filter's array
        got = [struct.unpack(">d", bytes.fromhex(h))[0] for h in lines[at + 1 + row].split()]
        np.testing.assert_array_equal(got, values.ravel()[8 * row:8 * row + 8], err_msg=name)
    assert "bank_200ms.npz sha256 " in bank_text.splitlines()[1]


def test_native_lqg_refuses_a_changed_resource_when_it_reads_it(tmp_path):
    """Each design is read (and checked against its SHA-256) when its schedule is first in force: a changed
    lqg_20ms.txt is refused by name at initialisation with schedule_period = 0.02, and a run of another schedule
    never reads it. A resource read at instantiation (the trajectory) is refused there."""
    native = native_fmus()["controller_lqg"]
    unz = unpack_alone(native, tmp_path / "changed")
    path = unz / "resources" / "lqg_20ms.txt"
    path.write_bytes(path.read_bytes() + b"\n")
    s = Slave(native, unz, "other_schedule", schedule_period=0.2)  # reads lqg_200ms.txt only
    s.fmu.doStep(0.0, 1e-3)
    s.fmu.freeInstance()
    s = Slave(native, unz, "changed", start=False)
    s.fmu.setupExperiment(startTime=0.0)
    s.fmu.enterInitializationMode()
    s.set(schedule_period=0.02)
    with pytest.raises(FMICallException):
        s.fmu.exitInitializationMode()
    assert any("lqg_20ms.txt" in m and "SHA-256" in m and "schedule_period = 0.02" in m for _, m in s.messages), \
        s.messages
    s.fmu.freeInstance()
    trajectory = unz / "resources" / "lqg_trajectory.txt"
    trajectory.write_bytes(trajectory.read_bytes() + b"\n")
    with pytest.raises(Exception, match="instantiate"):
        Slave(native, unz, "changed_trajectory", start=False)


@pytest.mark.parametrize("estimator", [1, 2])
def test_win64_lqg_under_wine_matches_linux64(tmp_path, estimator):
    """Both estimators (1 kalman, 2 payload_bank): the win64 binary under wine gives linux64's bits."""
    wine = shutil.which("wine") or shutil.which("wine64")
    if wine is None:
        pytest.skip("wine is not installed (Debian: apt-get install wine64); the win64 binary was built but not run")
    unz = unpack_alone(native_fmus()["controller_lqg"], tmp_path / "fmu")
    csv = tmp_path / "meas.csv"
    csv.write_text(",".join(MEASURED) + "\n" + "".join(
        ",".join(repr(v) for v in lqg_inputs(k).values()) + "\n" for k in range(N_STEPS)))
    args = [str(unz), "--steps", str(N_STEPS), "--inputs", str(csv), "--quiet", "--set", "loop_delay_samples=2",
            "--set", "integral_action=true", "--set", "tau1_max=5.0", "--set", f"estimator={estimator}"]
    runs = []
    for cmd, env in (([str(compile_host(tmp_path))], {}),  # env -i: no Python anywhere
                     ([wine, str(compile_host(tmp_path, target="win64"))], wine_env())):
        run = subprocess.run([*cmd, *args, "--check-errors"], capture_output=True, text=True, env=env, timeout=600)
        assert run.returncode == 0, run.stderr[-2000:]
        runs.append(read_host_csv(run.stdout[run.stdout.index("time,"):]))
    (header_l, linux), (header_w, windows) = runs
    assert header_l == header_w
    assert np.abs(linux[:, header_l.index("tau1")]).max() == 5.0  # saturated at the limit set
    np.testing.assert_array_equal(windows, linux)  # bit for bit


# -- closed loop ---------------------------------------------------------------------------------------------
TABLE2_CASES = ("none", "noise", "tip", "tip_noise")


def _run_scenario(scenario: str, fmus: dict, folder, keys, controller: dict | None = None) -> dict:
    """The recorded signals of the cases `keys` of `scenario`, the controller's parameters updated by `controller`."""
    from scenarios.config import load_scenario
    from scenarios.run.runner import simulate_case
    from scenarios.run.setup import prepare

    folder.mkdir(parents=True)
    for name in ("plant", "sensors", "controller_lqg"):
        shutil.copy2(fmus[name], folder / f"{name}.fmu")
    sc = load_scenario(scenario)
    signals = {}
    for case in sc.cases:
        if case.key not in keys:
            continue
        setup = prepare(sc, folder, names=case.fmus or None, build=False)
        with setup.open_master(sc.algorithm) as m:
            parameters = {**case.parameters, "controller": {**case.parameters.get("controller", {}),
                                                            **(controller or {})}}
            out, _ = simulate_case(setup, m, parameters)
            assert out["status"] == "ok", out.get("message")
        signals[case.key] = out["signals"]
    return signals


def _signal_bound(name: str, bound: float) -> float:
    """Relative bound for a recorded signal: the accelerometers (recorded as what the controller saw, not used by
    its law) come from a linear solve per sample, where native and Python differ by about 5e-9 of their peak
    (measured; as in tests/test_native_scenarios.py)."""
    return max(bound, 1e-7) if name.startswith("sensors.acc") else bound


@pytest.mark.parametrize("scenario, keys", [("lqg", TABLE2_CASES), ("lqg_jacobi", (*TABLE2_CASES, "tip_integral"))])
def test_closed_loop_native_set_equals_python_set(tmp_path, scenario, keys):
    """Plant + sensors + controller_lqg, native against Python: every recorded signal within 1e-10 of its peak
    (or 1e-12 absolute), Gauss-Seidel (delay 0) and Jacobi stepping (delay 2, and with integral action)."""
    python, native = built_fmus(), native_fmus()
    ref = _run_scenario(scenario, python, tmp_path / "python", keys)
    got = _run_scenario(scenario, native, tmp_path / "native", keys)
    assert set(ref) == set(keys)
    for key in keys:
        assert set(ref[key]) == set(got[key])
        for name, r in ref[key].items():
            r, g = np.asarray(r), np.asarray(got[key][name])
            assert np.abs(g - r).max() <= max(_signal_bound(name, 1e-10) * np.abs(r).max(), 1e-12), (
                scenario, key, name)
