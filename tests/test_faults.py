"""Fault suite (issue 16): each fault or bad input is injected and the honest outcome asserted.

Refused (exit 2, naming the field and the allowed values, or quoting the FMU), results folder unusable
(exit 3, one line), interrupted (exit 130, nothing recorded), or a typed outcome (unbounded: when and which
signal; error: which FMU, function, FMI status and the FMU's message). Nothing here may end with a wrong
result and exit 0, and nothing may hang: every subprocess has a timeout. Here: typed outcomes, interrupts, steps
and values; what a run reads and writes (data chain, folders, FMU files, journals) is in tests/test_faults_files.py.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from fmu_harness import built_fmus

from scenarios.__main__ import main
from scenarios.config import SCENARIO_DIR, load_scenario
from scenarios.master import fmu_files
from scenarios.master.values import check_value
from scenarios.run import runner
from scenarios.run.setup import prepare
from scenarios.sweep import load_sweep, run_sweep

TABLE2 = (SCENARIO_DIR / "table2.toml").read_text()
TIMEOUT = 600


def scenario_file(folder: Path, name: str, samples="200", step="0.001", extra_params: str = "",
                  cases: str = '[[cases]]\nkey = "none"\nlabel = "no tip mass, no noise"\n',
                  connections: str = "") -> Path:
    """table2.toml with one case, renamed, with the given run length, step and extra settings."""
    text = TABLE2.split("[[cases]]")[0]
    text = text.replace('name = "table2"', f'name = "{name}"').replace('samples = "trajectory"', f"samples = {samples}")
    text = text.replace("step_size_s = 0.001", f"step_size_s = {step}")
    text = text.replace('paper_table = "table2"\n', "")
    if connections:
        text = text.replace("[connections]\n", f"[connections]\n{connections}\n")
    path = folder / f"{name}.toml"
    path.write_text(text + extra_params + "\n" + cases)
    return path


def cli(args: list[str], env: dict | None = None, timeout: float = TIMEOUT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "scenarios", *args], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, **(env or {})})


def stderr_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    return err


def prepare_table2():
    """table2 prepared on the FMUs this test process built (a fresh clone has no build/fmus yet)."""
    return prepare(load_scenario("table2"), next(iter(built_fmus().values())).parent, build=False)


@pytest.fixture(scope="module")
def table2_setup():
    return prepare_table2()


# ---------------------------------------------------------------------------------------- 1. typed outcomes


def test_unbounded_names_the_time_and_the_signal(table2_setup):
    setup = table2_setup
    params = setup.case_parameters({"plant": {"payload_mass": 0.275}})
    with setup.open_master() as m:
        free = m.run(params, setup.record, 300)
        limit = 0.9 * np.nanmax(np.abs(free["signals"]["plant.omega1"]))
        out = m.run(params, setup.record, 300, divergence_limit=limit)
    o = out["outcome"]
    assert free["status"] == "ok" and o.status == "unbounded"
    values = np.column_stack([free["signals"][f"{i}.{v}"] for i, v in setup.record])
    k = int(np.argmax(np.any(np.abs(values) >= limit, axis=1)))  # first sample out of bounds
    assert o.time == pytest.approx(k * 1e-3) and o.signal == [f"{i}.{v}" for i, v in setup.record][
        int(np.argmax(np.abs(values[k]) >= limit))]
    assert f"t = {k * 1e-3:.6g} s" in o.message and o.signal in o.message
    assert np.isnan(out["signals"]["plant.theta1"][k + 1:]).all()  # nothing after the divergence is data


def test_fmu_error_carries_the_fmi_status_and_the_fmus_message(table2_setup):
    setup = table2_setup
    params = setup.case_parameters({"sensors": {"sample_period": 0.0015}})
    with setup.open_master() as m:
        out = m.run(params, setup.record, 50)
    o = out["outcome"]
    assert (o.status, o.fmu, o.function, o.fmu_status) == ("error", "sensors", "fmi2DoStep", "error")
    assert "sample_period" in o.fmu_message and o.fmu_message in out["message"]
    theta1 = out["signals"]["plant.theta1"]
    assert out["steps_done"] == 0 and np.isfinite(theta1[0]) and np.isnan(theta1[1:]).all()  # t_0 was read


def _wait_for(predicate, proc, timeout=300.0):
    t0 = time.monotonic()
    while not predicate():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < timeout, "the run never started"
        time.sleep(0.05)


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_ctrl_c_in_a_case_records_nothing_and_exits_130(tmp_path, sig, code):
    path = scenario_file(tmp_path, "longrun", samples="200000")
    out, unpack = tmp_path / "out", tmp_path / "unpack"
    (out / "longrun").mkdir(parents=True)
    (out / "longrun" / "none.json").write_text('{"earlier": true}')  # an earlier run's result stays as it was
    proc = subprocess.Popen([sys.executable, "-m", "scenarios", "run", str(path), "--out", str(out), "--no-plots"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**os.environ, fmu_files.UNPACK_ENV: str(unpack)})
    err = bytearray()
    reader = threading.Thread(target=lambda: [err.extend(c) for c in iter(lambda: proc.stderr.read1(256), b"")],
                              daemon=True)
    reader.start()
    try:
        _wait_for(lambda: b"longrun:none" in err, proc)  # the case's progress bar: it is running
        proc.send_signal(sig)
        rc = proc.wait(timeout=120)
    finally:
        proc.kill()
    reader.join(timeout=10)
    assert rc == code and b"Traceback" not in err and b"error" not in err
    assert b"interrupted" in err or sig == signal.SIGTERM
    assert json.loads((out / "longrun" / "none.json").read_text()) == {"earlier": True}
    assert sorted(p.name for p in out.iterdir()) == [".longrun.lock", "longrun"]  # no partial folder left
    assert list((unpack / "flexarm-fmus").iterdir()) == []  # unpacked FMUs removed


def test_ctrl_c_in_a_serial_sweep_then_resume(tmp_path):
    sweep = tmp_path / "three.toml"
    sweep.write_text("[sweep]\nname = 'three'\nscenario = 'table2'\ncase = 'none'\nsamples = 3000\n"
                     "[axes]\nplant.payload_mass = [0.0, 0.1, 0.2]\n")
    journal = tmp_path / "out" / "three" / "journal.jsonl"
    proc = subprocess.Popen([sys.executable, "-m", "scenarios", "sweep", str(sweep), "--serial", "--quiet",
                             "--no-plots", "--out", str(tmp_path / "out")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for(lambda: journal.is_file() and journal.read_text().count("\n") >= 1, proc)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130 and "interrupted" in err and "Traceback" not in err
    records = [json.loads(x) for x in journal.read_text().splitlines()]
    assert 1 <= len(records) < 3 and {r["status"] for r in records} == {"ok"}  # the interrupted point: absent
    res = run_sweep(sweep, tmp_path / "out", serial=True, plots=False, progress=False)
    assert res.ran == 3 - len(records) and res.skipped == len(records)
    assert [r["status"] for r in res.rows] == ["ok"] * 3


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_ctrl_c_in_a_dask_sweep_closes_the_cluster_and_exits_130(tmp_path, sig, code):
    """Started as a non-interactive shell starts a background job (`cmd &` in a script, CI under load): with
    SIGINT inherited ignored, where Python installs no KeyboardInterrupt (issue 35: the sweep ran on, exit 0)."""
    sweep = tmp_path / "dask.toml"
    sweep.write_text("[sweep]\nname = 'dask'\nscenario = 'table2'\ncase = 'none'\nsamples = 6000\n"
                     "[axes]\nplant.payload_mass = [0.0, 0.05, 0.1, 0.15, 0.2, 0.25]\n")
    journal = tmp_path / "out" / "dask" / "journal.jsonl"
    proc = subprocess.Popen([sys.executable, "-m", "scenarios", "sweep", str(sweep), "--workers", "2", "--quiet",
                             "--no-plots", "--out", str(tmp_path / "out")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        _wait_for(lambda: journal.is_file() and journal.read_text().count("\n") >= 1, proc)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)  # the cluster is closed: the process ends
    finally:
        proc.kill()
    assert proc.returncode == code and "Traceback" not in err, err
    assert "interrupted" in err or sig == signal.SIGTERM
    records = [json.loads(x) for x in journal.read_text().splitlines()]
    assert 1 <= len(records) < 6 and {r["status"] for r in records} == {"ok"}
    meta = json.loads((tmp_path / "out" / "dask" / "sweep.json").read_text())
    assert meta["interrupted"] is True and meta["run_now"] == len(records)


# ---------------------------------------------------------------------------------------- 2. steps


def test_metrics_are_aligned_in_time_for_a_2_ms_step(tmp_path):
    """At 2 ms the desired states are taken at the same times, so the errors stay as small as at 1 ms."""
    base = scenario_file(tmp_path, "at1ms", samples='"trajectory"')
    two = scenario_file(tmp_path, "at2ms", samples='"trajectory"', step="0.002")
    two.write_text(two.read_text().replace("[parameters.sensors]\n", "[parameters.sensors]\nsample_period = 0.002\n"))
    r1 = runner.run_scenario(load_scenario(base), tmp_path / "out", progress=False)[0]
    r2 = runner.run_scenario(load_scenario(two), tmp_path / "out", progress=False)[0]
    assert r1.status == r2.status == "ok"
    assert r2.series["time"][-1] == pytest.approx(r1.series["time"][-1])  # the same slew, half the samples
    assert len(r2.series["time"]) == (len(r1.series["time"]) - 1) // 2 + 1
    assert r2.metrics["rms_position_error"] < 0.1  # was 41.7 deg with desired states taken by sample index
    assert r2.metrics["rms_position_error"] < 10 * r1.metrics["rms_position_error"] + 0.01
    assert r2.metrics["peak_tau1"] == pytest.approx(r1.metrics["peak_tau1"], rel=0.1)


def test_a_step_the_fmus_refuse_is_refused_before_anything_runs(tmp_path, capsys):
    path = scenario_file(tmp_path, "odd_step", step="0.0015")
    code = main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet", "--no-plots"])
    err = stderr_line(capsys)
    assert code == 2 and "communication step 0.0015 s: refused by sensors (fmi2DoStep returned error)" in err
    assert "sample_period" in err  # the FMU's own message
    assert not (tmp_path / "out" / "odd_step").exists()


# ---------------------------------------------------------------------------------------- 3. values


@pytest.mark.parametrize("setting, field, allowed", [
    ("noise_enabled = \"false\"", "parameters.sensors.noise_enabled", "true or false (noise_enabled is Boolean)"),
    ("noise_seed = 1.7", "parameters.sensors.noise_seed", "an integer (noise_seed is Integer), got 1.7"),
    ("noise_seed = -3", "parameters.sensors.noise_seed", "a value in the FMU's range [0, 2147483647]"),
    ("sample_priod = 0.001", "parameters.sensors.sample_priod", "a parameter of FMU"),
])
def test_scenario_values_are_checked_against_the_model_description(tmp_path, capsys, setting, field, allowed):
    path = scenario_file(tmp_path, "bad_value")
    key = setting.split(" =")[0]
    lines = [x for x in path.read_text().splitlines() if not x.startswith(f"{key} =")]
    lines.insert(lines.index("[parameters.sensors]") + 1, setting)
    path.write_text("\n".join(lines) + "\n")
    code = main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet", "--no-plots"])
    err = stderr_line(capsys)
    assert code == 2 and field in err and allowed in err and "bad_value.toml" in err
    assert not (tmp_path / "out").exists() or not (tmp_path / "out" / "bad_value").exists()


def test_a_boolean_payload_is_refused_in_a_case(tmp_path, capsys):
    path = scenario_file(tmp_path, "bool_payload",
                         cases='[[cases]]\nkey = "tip"\nparameters.plant.payload_mass = true\n')
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet", "--no-plots"]) == 2
    err = stderr_line(capsys)
    assert "cases[tip].parameters.plant.payload_mass: a finite number (payload_mass is Real kg), got True" in err


def test_sweep_values_are_checked_the_same_way(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text("[sweep]\nname='s'\nscenario='table2'\n[axes]\nsensors.noise_enabled = ['false', 'true']\n")
    from scenarios.sweep import SweepError, plan_sweep

    with pytest.raises(SweepError, match=r"axes.sensors.noise_enabled: true or false \(noise_enabled is Boolean\), "
                                         r"got 'false'"):
        plan_sweep(load_sweep(path), build=False)


def test_enumeration_choice_names_map_to_their_integers():
    """Generic: any Enumeration's item names, from the model description, map to the item values."""
    items = [SimpleNamespace(name=n, value=str(v)) for n, v in (("gamma1", 1), ("gamma0.1", 2), ("gamma0", 3),
                                                                  ("eq32", 4))]
    var = SimpleNamespace(name="gain_set", type="Enumeration", unit=None, min=None, max=None,
                          declaredType=SimpleNamespace(name="GainSet", items=items))
    assert check_value("f.toml: gain_set", var, "gamma0") == 3 and check_value("f", var, "eq32") == 4
    from scenarios.config import ScenarioError

    with pytest.raises(ScenarioError, match=r"f.toml: gain_set: one of \['gamma1', 'gamma0.1', 'gamma0', 'eq32'\] "
                                            r"\(gain_set is Enumeration GainSet\), got 'gamma2'"):
        check_value("f.toml: gain_set", var, "gamma2")
    with pytest.raises(ScenarioError, match="got 2"):
        check_value("f.toml: gain_set", var, 2)  # files write names; the integer is the FMU's business
    # the same for an Integer that lists its choices in its description (libcosim cannot set Enumerations)
    choice = SimpleNamespace(name="omega7_estimate", type="Integer", unit=None, min="1", max="2", declaredType=None,
                             description="how the error is formed; choices: 1 = tachometer, 2 = rigid")
    assert check_value("f", choice, "rigid") == 2
    with pytest.raises(ScenarioError, match=r"one of \['tachometer', 'rigid'\] \(omega7_estimate is Integer "
                                            r"choice\), got 'tacho'"):
        check_value("f", choice, "tacho")


def test_two_connections_into_one_input_are_refused(tmp_path, capsys):
    wiring = ('explicit = [["plant.q1", "sensors.q1"], ["controller.tau1", "plant.tau1"], '
              '["controller.tau2", "plant.tau1"]]')
    path = scenario_file(tmp_path, "two_into_one", connections=wiring)
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet", "--no-plots"]) == 2
    err = stderr_line(capsys)
    assert "input plant.tau1 is already driven by controller.tau1; one input takes one connection" in err
