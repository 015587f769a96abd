"""Controllers that use the delay the loop measures (issue 31): controller_lqg's automatic loop_delay_samples,
and a warning wherever a law's delay contradicts the measured one (FMI log, the run's JSON). Both FMU kinds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fmu_harness import built_fmus
from native_fmus import native_fmus

from scenarios.config import load_scenario
from scenarios.master import cosim as master
from scenarios.run import runner
from scenarios.run.loop_delay import INDEX_NAMES, loop_delay_record, loop_delay_warnings
from scenarios.run.setup import desired_states, desired_trajectory, prepare

DELAY = [("controller", "loop_delay"), ("controller", "loop_delay_assumed"), ("controller", "tau_index")]


@pytest.fixture(scope="module", params=["python", "native"])
def kind_fmus(request) -> tuple[str, dict[str, Path]]:
    return request.param, (built_fmus() if request.param == "python" else native_fmus())


def tolerance(reference: float) -> float:
    """Issue 31's acceptance: 5 % or 0.005 deg, whichever is larger (a master's start may differ by a sample)."""
    return max(0.05 * abs(reference), 0.005)


def run(kind_fmus, scenario: str, case: str, algorithm: str, controller: dict | None = None, n: int | None = None,
        drop: frozenset = frozenset()) -> dict:
    """One case in our master: metrics, the controller's delay outputs, the FMUs' log, the JSON's warnings."""
    kind, fmus = kind_fmus
    sc = load_scenario(scenario)
    folder = next(iter(fmus.values())).parent
    setup = prepare(sc, fmu_dir=folder, native_fmu_dir=folder, build=False, kind=kind, algorithm=algorithm)
    parameters = dict(next(c for c in sc.cases if c.key == case).parameters)
    parameters["controller"] = {**parameters.get("controller", {}), **(controller or {})}
    connections = [c for c in setup.connections if c.dst_var not in drop]  # inputs left unwired
    n = setup.n_steps if n is None else n
    with master.Master(setup.paths, sc.order, connections, algorithm) as m:
        out = m.run(setup.case_parameters(parameters), setup.record + DELAY, n, sc.step_size)
    assert out["status"] == "ok", out["message"]
    sig = out["signals"]
    delay = {name: np.asarray(sig[f"{inst}.{name}"]) for inst, name in DELAY}
    warnings = loop_delay_warnings({"signals": dict(sig), "time": out["time"]},
                                   loop_delay_record(setup.descriptions, setup.driver))
    theta = np.column_stack([sig[f"plant.theta{i}"] for i in range(1, 12)])
    omega = np.column_stack([sig[f"plant.omega{i}"] for i in range(1, 12)])
    tau = np.column_stack([sig["controller.tau1"], sig["controller.tau2"]])
    desired = desired_states(desired_trajectory(), out["time"])
    metrics = runner.table_metrics(tau, theta, omega, desired["theta"], desired["omega"])
    return {"metrics": metrics, "tau": tau, "log": out["log"], "warnings": warnings, **delay}


def _runner_case(kind_fmus, scenario: str, case: str, algorithm: str) -> tuple[dict, dict]:
    """One case through the scenario runner's own simulate (its metrics and warnings), stepping `algorithm`."""
    kind, fmus = kind_fmus
    sc = load_scenario(scenario)
    folder = next(iter(fmus.values())).parent
    setup = prepare(sc, fmu_dir=folder, native_fmu_dir=folder, build=False, kind=kind, algorithm=algorithm)
    parameters = next(c for c in sc.cases if c.key == case).parameters
    with setup.open_master(algorithm) as m:
        out, metrics = runner.simulate_case(setup, m, parameters)
    assert out["status"] == "ok", out["message"]
    return out, metrics


def delay_warnings(log: list[str]) -> list[str]:
    return [line for line in log if line.startswith("[controller] warning:") and "loop delay contradiction" in line]


def test_automatic_is_the_gauss_seidel_law_bit_for_bit_in_a_gauss_seidel_master(kind_fmus):
    auto = run(kind_fmus, "lqg", "none", "gauss-seidel", {"loop_delay_samples": -1}, n=300)
    zero = run(kind_fmus, "lqg", "none", "gauss-seidel", {"loop_delay_samples": 0}, n=300)
    np.testing.assert_array_equal(auto["tau"], zero["tau"])
    assert np.array_equal(auto["loop_delay"], np.zeros(301)) and np.array_equal(auto["loop_delay_assumed"],
                                                                                 np.zeros(301))
    assert not delay_warnings(auto["log"]) and not auto["warnings"]


def test_automatic_predicts_over_the_jacobi_masters_two_samples(kind_fmus):
    """The same parameters in a Jacobi master: the law sees the delay at the second step and predicts over it;
    the answer is the Gauss-Seidel one within the issue's tolerance (without: the paper's 0 diverges)."""
    gs = run(kind_fmus, "lqg", "none", "gauss-seidel", {"loop_delay_samples": -1})
    jacobi = run(kind_fmus, "lqg", "none", "jacobi", {"loop_delay_samples": -1})
    for metric in ("rms_position_error", "rms_velocity_error"):  # deg, deg/s
        ref = gs["metrics"][metric]
        limit = tolerance(ref) if metric == "rms_position_error" else max(0.05 * ref, 0.05)
        assert abs(jacobi["metrics"][metric] - ref) <= limit, (metric, jacobi["metrics"][metric], ref)
    assert np.array_equal(jacobi["loop_delay_assumed"][2:], np.full(len(jacobi["tau"]) - 2, 2.0))
    assert np.array_equal(jacobi["loop_delay"][3:], np.full(len(jacobi["tau"]) - 3, 2.0))
    assert not delay_warnings(jacobi["log"]) and not jacobi["warnings"]


@pytest.mark.parametrize("algorithm, setting", [("gauss-seidel", 2), ("jacobi", 0)])
def test_a_contradicting_explicit_delay_is_warned_in_the_log_and_the_json(kind_fmus, algorithm, setting):
    """Issue 31's acceptance: 2 in a Gauss-Seidel master, 0 in a Jacobi one."""
    out = run(kind_fmus, "lqg", "none", algorithm, {"loop_delay_samples": setting}, n=30)
    said = delay_warnings(out["log"])
    assert len(said) == 1 and f"loop_delay_samples = {setting}" in said[0], out["log"]  # once per run
    assert len(out["warnings"]) == 1 and "loop delay" in out["warnings"][0]
    assert np.all(out["loop_delay_assumed"][3:] == setting) and np.all(out["loop_delay"][3:] != setting)


def test_the_papers_controller_predicts_over_a_jacobi_masters_delay(kind_fmus):
    """The paper's law measures the delay and predicts over it (flexarm.lqg.PredictedTracking): in a Jacobi master
    its rms position error is its Gauss-Seidel figure within the issue's tolerance (2.25 deg without the
    prediction: the loop goes unstable). Its rms velocity error: the Gauss-Seidel figure + 12.6 % (0.957 against
    0.850 deg/s; the law before, the reduced gain on the filter's whole state, gave + 106 %). Of it, + 6.0 % is the
    filter's prediction over 2 ms (the library loop gives 0.901: tests/test_predicted_tracking.py), the rest the
    first sample: its torque comes from a measurement of sample 0 taken as current (a master without
    initialisation exchanges hands over one without index there, which the law cannot tell from an unwired index:
    docs/control.md). Bounded at + 15 %."""
    gs = run(kind_fmus, "table2", "none", "gauss-seidel")
    jacobi = run(kind_fmus, "table2", "none", "jacobi")
    assert np.array_equal(gs["loop_delay_assumed"], np.zeros(len(gs["tau"])))  # the paper's law, no delay
    ref = gs["metrics"]["rms_position_error"]
    assert abs(jacobi["metrics"]["rms_position_error"] - ref) <= tolerance(ref), (jacobi["metrics"], ref)
    assert jacobi["metrics"]["rms_velocity_error"] < 1.15 * gs["metrics"]["rms_velocity_error"]
    assert np.array_equal(jacobi["loop_delay_assumed"][2:], np.full(len(jacobi["tau"]) - 2, 2.0))
    assert np.array_equal(jacobi["loop_delay"][3:], np.full(len(jacobi["tau"]) - 3, 2.0))
    for out in (gs, jacobi):
        assert not delay_warnings(out["log"]) and not out["warnings"]


def test_a_loop_without_the_indices_warns_and_keeps_the_setting(kind_fmus):
    """Only the paper's signals wired: the explicit behaviour (automatic: 0) and a warning naming the index."""
    wired = run(kind_fmus, "lqg", "none", "gauss-seidel", n=50)
    bare = run(kind_fmus, "lqg", "none", "gauss-seidel", n=50, drop=INDEX_NAMES)
    np.testing.assert_array_equal(bare["tau"][1:], wired["tau"][1:])
    said = [line for line in bare["log"] if "sample index is not wired" in line]
    assert len(said) == 1 and said[0].startswith("[controller] warning:")
    assert np.all(bare["loop_delay"] == -1.0) and not bare["warnings"]


def test_fmpy_simulate_ssps_zero_fill_is_no_measurement(kind_fmus):
    """fmpy's first step feeds every input 0: the controller takes no measurement from it (loop_delay -1 there)
    and, seeing that placeholder at its first fmi2DoStep, starts the slew one sample later (slew_start_index 2:
    the plant held no torque over that step), then measures the Jacobi delay. The run's metrics compare the arm
    with the slew as started, and its warnings say so: the figure is the Jacobi master's (issue 31: within 5 %
    or 0.005 deg of the Gauss-Seidel one), where the first millisecond's loss left 0.066 deg before."""
    out = run(kind_fmus, "lqg", "none", "fmpy-ssp", {"loop_delay_samples": -1})
    assert out["loop_delay"][0] == -1.0 and out["loop_delay_assumed"][-1] == 2.0
    assert not delay_warnings(out["log"])
    (late_out, late_metrics), (jacobi_out, jacobi_metrics) = (_runner_case(kind_fmus, "lqg", "none", a)
                                                              for a in ("fmpy-ssp", "jacobi"))
    assert [w for w in late_out["warnings"] if "started the slew 1 sample(s) late" in w], late_out["warnings"]
    assert not [w for w in jacobi_out["warnings"] if "started the slew" in w]  # initialisation exchanged values
    late, ref = late_metrics["rms_position_error"], jacobi_metrics["rms_position_error"]
    print(f"lqg/none, automatic delay: rms position error fmpy-ssp {late:.6f} deg, jacobi {ref:.6f} deg")
    assert abs(late - ref) <= max(0.05 * ref, 0.005)  # one sample's torques apart (tests/test_loop_index.py)
    assert late < 0.005  # the 1 ms loss cost 0.066 deg


def _paper_law_jacobi(fmu: Path, n: int, save_at: int | None = None) -> np.ndarray:
    """controller.fmu alone in a Jacobi loop (the measurements of sample k - 1, with their index, set at t_k;
    the desired ones plus a perturbation), torques read before the set. With `save_at` the state is saved there,
    the run goes on to n, the state (serialised and read back) is restored and the rest run again: returns both
    tails stacked."""
    from fmpy import read_model_description
    from fmpy.fmi2 import FMU2Slave
    from native_fmus import unpack_alone
    from test_native_lqg import MEASURED, lqg_inputs

    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    s = FMU2Slave(guid=md.guid, unzipDirectory=str(unpack_alone(fmu, fmu.parent / f"paper_{fmu.stem}_{save_at}")),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="paper")
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    ins = [vr[m] for m in MEASURED] + [vr["sample_index_m"]]
    taus = [vr["tau1"], vr["tau2"], vr["loop_delay_assumed"]]

    def steps(k0: int, k1: int) -> list:
        rows = []
        for k in range(k0, k1):
            rows.append(s.getReal(taus))
            if k >= 1:
                s.setReal(ins, [*lqg_inputs(k - 1).values(), float(k)])  # sample k - 1 carries index k
            s.doStep(k * 1e-3, 1e-3)
        return rows

    rows = steps(0, save_at or n)
    if save_at is not None:
        state = s.deSerializeFMUstate(s.serializeFMUstate(s.getFMUstate()))
        first = steps(save_at, n)
        s.setFMUstate(state)
        rows = first + steps(save_at, n)
    s.terminate()
    s.freeInstance()
    return np.array(rows)


def test_the_papers_predicting_law_restores_bit_for_bit_and_the_kinds_agree(tmp_path):
    """In its predicting mode the paper's law has a state (the filter, the torques sent): a saved, serialised and
    restored state gives the rest of the run bit for bit, in both kinds; the kinds agree to 1e-9 N.m (the same
    law in NumPy and C, compensated sums)."""
    runs = {}
    for kind, fmus in (("python", built_fmus()), ("native", native_fmus())):
        fmu = Path(tmp_path / kind / "controller.fmu")
        fmu.parent.mkdir()
        fmu.write_bytes(fmus["controller"].read_bytes())
        whole = _paper_law_jacobi(fmu, 400)
        assert np.all(whole[5:, 2] == 2.0)  # predicting over the measured two samples
        twice = _paper_law_jacobi(fmu, 400, save_at=250)
        np.testing.assert_array_equal(twice[:150], twice[150:])
        np.testing.assert_array_equal(twice[:150], whole[250:])
        runs[kind] = whole
    np.testing.assert_allclose(runs["native"][:, :2], runs["python"][:, :2], rtol=0, atol=1e-9)


def test_a_logged_warning_leaves_the_step_ok_in_both_kinds(kind_fmus, tmp_path):
    """The contradiction warning reaches the host's logger and fmi2DoStep still returns fmi2OK, in both kinds.
    The Python kind returned fmi2Warning from the step that logged it, and OMSimulator takes fmi2Warning from
    fmi2DoStep for a failed step: the Python set stopped at the second step there, the native one ran on."""
    import json
    import subprocess
    import sys

    _, fmus = kind_fmus
    host = Path(__file__).resolve().parent / "fmi_loop_host.py"
    spec = {"fmus": {"plant": str(fmus["plant"]), "sensors": str(fmus["sensors"]),
                     "controller": str(fmus["controller_lqg"])},
            "stepping": "gauss-seidel", "n_steps": 30, "parameters": {"controller": {"loop_delay_samples": 2}}}
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    proc = subprocess.run([sys.executable, str(host), str(tmp_path / "spec.json"), str(tmp_path / "out.npz")],
                          capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    warned = [line for line in proc.stderr.splitlines()
              if line.startswith("[controller] status 1:") and "loop delay contradiction" in line]
    assert len(warned) == 1, proc.stderr[-4000:]
    with np.load(tmp_path / "out.npz") as z:
        assert z["run0_step_status"].shape == (30, 3) and not z["run0_step_status"].any()


def test_the_slew_start_a_controller_reports_is_taken_or_refused():
    """The runner compares the arm with the slew as the controller started it (its slew_start_index): 1 is t = 0,
    2 one sample later; a value that names no sample (0, a fraction) is refused (no figures), never read as 0."""
    from scenarios.run.loop_delay import slew_start

    record = [("controller", "slew_start_index")]
    for values, want in (([1.0, 1.0], 0), ([1.0, 2.0, 2.0, np.nan], 1)):
        assert slew_start({"signals": {"controller.slew_start_index": np.array(values)}}, record) == want
    assert slew_start({"signals": {}}, []) == 0  # a controller without the output: t = 0
    for bad in (0.0, 2.5, -1.0):
        with pytest.raises(ValueError, match="slew_start_index"):
            slew_start({"signals": {"controller.slew_start_index": np.array([1.0, bad])}}, record)
