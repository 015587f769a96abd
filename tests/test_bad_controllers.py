"""Issue 35: a controller that is not ours raises, hangs or exits; the master survives it, says so and goes on.

The bad controllers (tests/bad_controllers.py) are small pythonfmu FMUs built here, run through the command
line as a user would (``--controller X.fmu``). They run in a process of their own (scenarios/master/fmu_proxy.py):
each case they break ends ``error`` with exit code 1, naming the FMU, the FMI call, the time and the status.
Every subprocess has a generous timeout: a hang guard only, never a measure of speed.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from bad_controllers import build_bad_controller
from fmu_harness import built_fmus

from scenarios.config import SCENARIO_DIR, load_scenario
from scenarios.master.cosim import Master
from scenarios.run.setup import prepare

#: Hang guard for one command: far above a run's minute on a loaded machine, far below a hang's forever.
GUARD_S = 600


@pytest.fixture(scope="module")
def bad(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("bad")
    return {kind: build_bad_controller(kind, folder) for kind in ("raise", "hang", "exit", "slow")}


@pytest.fixture(scope="module")
def fmu_dir() -> Path:
    return next(iter(built_fmus().values())).parent  # the FMUs this test process built


def run_cli(args: list[str], fmu_dir: Path, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "scenarios", *args, "--fmu-dir", str(fmu_dir)],
                          capture_output=True, text=True, timeout=GUARD_S, **kwargs)


def case_json(out: Path, key: str = "none") -> dict:
    return json.loads((out / "table2" / f"{key}.json").read_text())


@pytest.mark.parametrize("kind, status, says", [
    ("raise", "fatal", "fmi2DoStep returned fatal"),  # pythonfmu returns fmi2Fatal for an exception in do_step
    ("exit", "crashed", "fmi2DoStep did not return: its process ended with exit code 7"),
])
def test_a_raising_or_exiting_controller_ends_its_case_with_exit_1_naming_it(tmp_path, bad, fmu_dir, kind, status,
                                                                              says):
    out = tmp_path / "out"
    res = run_cli(["run", "table2", "--case", "none", "--controller", str(bad[kind]), "--out", str(out),
                   "--no-plots", "--quiet"], fmu_dir)
    assert res.returncode == 1, res.stderr  # never the FMU's own exit code (7), never a crash (139)
    assert "Traceback" not in res.stderr
    line = next(x for x in res.stdout.splitlines() if x.strip().startswith("none: error"))
    assert "t = 1.000 s" in line and "controller" in line and says in line
    o = case_json(out)["outcome"]
    assert (o["status"], o["fmu"], o["function"], o["fmu_status"]) == ("error", "controller", "fmi2DoStep", status)
    if kind == "raise":
        assert "a bug in the controller" in o["fmu_message"]  # the FMU's own logged message


def test_a_hanging_controller_ends_its_case_after_the_step_timeout(tmp_path, bad, fmu_dir):
    out = tmp_path / "out"
    res = run_cli(["run", "table2", "--case", "none", "--case", "noise", "--controller", str(bad["hang"]),
                   "--out", str(out), "--no-plots", "--quiet", "--step-timeout", "2"], fmu_dir)
    assert res.returncode == 1, res.stderr
    for key in ("none", "noise"):  # the first case's hang does not keep the second from running (and failing)
        o = case_json(out, key)["outcome"]
        assert (o["fmu"], o["function"], o["fmu_status"]) == ("controller", "fmi2DoStep", "timeout")
        assert "did not return within 2 s" in o["message"] and "t = 1.000 s" in o["message"]


def _alive(pid: int) -> bool:
    """Whether process `pid` runs (a zombie, dead but not yet reaped, does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except (FileNotFoundError, ProcessLookupError):
        return False


def _children(pid: int) -> list[int]:
    tasks = Path(f"/proc/{pid}/task")
    return [int(c) for t in tasks.iterdir() for c in (t / "children").read_text().split()] if tasks.is_dir() else []


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_during_the_hang_ends_the_run_with_its_code(tmp_path, bad, fmu_dir, sig, code):
    """fail_at = 0: the controller hangs in the probe's first step, inside an FMU call, with no step timeout near."""
    proc = subprocess.Popen([sys.executable, "-m", "scenarios", "run", "table2", "--case", "none", "--controller",
                             str(bad["hang"]), "--set", "controller.fail_at=0", "--out", str(tmp_path / "out"),
                             "--no-plots", "--quiet", "--step-timeout", "3000", "--fmu-dir", str(fmu_dir)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.monotonic()
        while not _children(proc.pid):  # the controller's own process: loaded, then hanging in the probe
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() - t0 < GUARD_S, "the controller's process never started"
            time.sleep(0.05)
        child = _children(proc.pid)[0]
        time.sleep(3.0)  # into the hang: load and instantiate take well under this (and a signal before is fine too)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)  # hang guard: without the fix it waits for 3000 s
    finally:
        proc.kill()
    assert proc.returncode == code, err
    assert "Traceback" not in err
    assert not _alive(child)  # the hung controller's process went with the run
    assert not (tmp_path / "out" / "table2").exists()  # nothing of the interrupted run is recorded


def test_a_sweep_point_with_a_hanging_controller_is_recorded_as_failed_and_the_sweep_goes_on(tmp_path, bad,
                                                                                          fmu_dir):
    scenario = (SCENARIO_DIR / "table2.toml").read_text().replace('name = "table2"', 'name = "swap"')
    start = scenario.index("[parameters.controller]")  # our controllers' gains: the swapped-in ones have none
    (tmp_path / "swap.toml").write_text(scenario[:start] + scenario[scenario.index("[[cases]]"):])
    sweep = tmp_path / "three.toml"
    sweep.write_text("[sweep]\nname = 'three'\nscenario = 'swap.toml'\ncase = 'none'\nsamples = 1500\n"
                     f"[axes]\nfmus.controller = ['controller', '{bad['hang']}', 'controller_ff']\n")
    res = run_cli(["sweep", str(sweep), "--serial", "--quiet", "--no-plots", "--out", str(tmp_path / "out"),
                   "--step-timeout", "2"], fmu_dir)
    assert res.returncode == 1, res.stderr
    records = [json.loads(x) for x in (tmp_path / "out" / "three" / "journal.jsonl").read_text().splitlines()]
    assert len(records) == 3 and sorted(r["status"] for r in records) == ["error", "ok", "ok"], records
    failed = next(r for r in records if r["status"] == "error")
    assert (failed["outcome"]["fmu"], failed["outcome"]["fmu_status"]) == ("controller", "timeout")
    assert "t = 1.000 s" in failed["message"]


def test_after_fmi2fatal_nothing_more_is_called_and_the_next_run_starts_afresh(bad):
    """FMI 2.0: after fmi2Fatal no function of the FMU may be called; the next run gets a new process."""
    with Master({"c": bad["raise"]}, ["c"], [], isolate=["c"], step_timeout=60) as m:
        first = m.run({"c": {"fail_at": 0.002}}, [("c", "tau1")], 5)
        process = m.units["c"].slave
        second = m.run({"c": {"fail_at": 1.0}}, [("c", "tau1")], 5)
        assert m.units["c"].slave is not process and process.gone == "not called after fatal"
    assert (first["outcome"].fmu_status, first["steps_done"]) == ("fatal", 2)
    assert second["status"] == "ok" and second["steps_done"] == 5


def test_isolated_fmus_give_the_same_numbers_as_in_process(fmu_dir):
    """Values cross the process boundary as IEEE doubles: Table 2's closed loop, bit for bit the same run."""
    setup = prepare(load_scenario("table2"), fmu_dir, build=False)
    params = setup.case_parameters({"sensors": {"noise_enabled": True}})
    runs = []
    for isolate in ("foreign", "all"):  # none of ours is foreign: none isolated, then every one
        with prepare(load_scenario("table2"), fmu_dir, build=False, isolate=isolate).open_master() as m:
            runs.append(m.run(params, setup.record, 300))
    assert runs[0]["status"] == runs[1]["status"] == "ok"
    for name in runs[0]["signals"]:
        assert runs[0]["signals"][name].tobytes() == runs[1]["signals"][name].tobytes(), name


def test_a_step_timeout_that_is_no_number_of_seconds_is_refused(tmp_path, fmu_dir):
    for bad_value in ("0", "-1", "nan", "inf", "soon"):
        res = run_cli(["run", "table2", "--step-timeout", bad_value, "--out", str(tmp_path)], fmu_dir)
        assert res.returncode == 2 and "--step-timeout: a number of seconds > 0" in res.stderr


def test_children_stop_when_the_master_is_killed(tmp_path, bad):
    """A hung FMU's process does not outlive a master killed outright (SIGKILL): it dies with its parent."""
    code = ("import sys; from pathlib import Path; from scenarios.master.cosim import Master\n"
            f"m = Master({{'c': Path({str(bad['hang'])!r})}}, ['c'], [], isolate=['c'])\n"
            "print('loaded', flush=True)\n"
            "m.run({'c': {'fail_at': 0.0}}, [('c', 'tau1')], 3)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    try:
        assert proc.stdout.readline().strip() == "loaded"
        child = _children(proc.pid)[0]
        time.sleep(1.0)
        proc.kill()
        proc.wait(timeout=60)
        t0 = time.monotonic()
        while _alive(child) and time.monotonic() - t0 < 60:
            time.sleep(0.05)
    finally:
        proc.kill()
    assert not _alive(child)


def test_a_folder_named_fmus_in_the_current_directory_hides_nothing(tmp_path):
    """``python -m`` puts the current directory first; with an editable install (its finder after the path) a
    user's ``fmus/`` folder (no __init__.py) became our ``fmus`` package: a TypeError in fmu_build/registry.py."""
    root = Path(__file__).resolve().parents[1]
    (tmp_path / "fmus").mkdir()
    (tmp_path / "fmus" / "TheirController.fmu").write_bytes(b"")
    code = f"""
import importlib.machinery, os, runpy, sys
class Editable:  # what `pip install -e` adds: this checkout's packages, found after sys.path
    @classmethod
    def find_spec(cls, name, path=None, target=None):
        if name in ("flexarm", "fmus", "fmu_build", "scenarios"):
            return importlib.machinery.PathFinder.find_spec(name, [{str(root)!r}])
        return None
sys.meta_path.insert(sys.meta_path.index(importlib.machinery.PathFinder) + 1, Editable)
sys.path.insert(0, os.getcwd())
sys.argv = ["scenarios", "run", "table2", "--controller", "controller_xyz", "--out", "out"]
runpy.run_module("scenarios", run_name="__main__", alter_sys=True)
"""
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=GUARD_S,
                         env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"})
    assert "Traceback" not in res.stderr and res.returncode == 2, res.stderr
    assert "an FMU name of this project" in res.stderr  # it got as far as our fmu_build's list of names


def test_a_zip_without_a_model_description_is_refused_in_one_plain_sentence(tmp_path, capsys):
    import zipfile

    from scenarios.__main__ import main

    fmu = tmp_path / "empty.fmu"
    with zipfile.ZipFile(fmu, "w") as z:
        z.writestr("binaries/linux64/readme.txt", "no model description here")
    code = main(["run", "table2", "--controller", str(fmu), "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err == f"error: fmus.controller: {fmu}: not an FMU (a zip archive without modelDescription.xml)"


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_ends_the_run_even_inside_an_fmu_call_in_this_process_that_never_returns(tmp_path, bad, sig, code):
    """An FMU in the master's own process hangs (here the hanging controller, not isolated): the signal cannot
    be acted on between steps, so the watchdog ends the process after its grace period, with the signal's code,
    and removes the unpacked FMUs."""
    unpack = tmp_path / "unpack"
    script = ("import signal, sys; from pathlib import Path; from scenarios.master.cosim import Master\n"
              "signal.signal(signal.SIGTERM, lambda *a: sys.exit(143))  # as python -m scenarios does\n"
              f"m = Master({{'c': Path({str(bad['hang'])!r})}}, ['c'], [])\n"
              "print('loaded', flush=True)\n"
              "m.run({'c': {'fail_at': 0.0}}, [('c', 'tau1')], 3)\n")
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]),
                                 "FLEXARM_UNPACK_DIR": str(unpack)})
    try:
        assert proc.stdout.readline().strip() == "loaded"
        time.sleep(1.0)  # into the hang (a signal before it would end the run all the same)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)  # hang guard: without the watchdog it never ends
    finally:
        proc.kill()
    assert proc.returncode == code, err
    assert "did not return within" in err and "Traceback" not in err
    assert list((unpack / "flexarm-fmus").iterdir()) == []


def test_an_isolated_fmus_error_status_reads_as_in_process_and_it_is_reset_for_the_next_run(fmu_dir):
    """fmi2Error from an FMU in its own process: the same outcome, FMU message included; then fmi2Reset (FMI
    2.0.5 allows it after fmi2Error, fmi2Terminate it does not) and the next run is ok."""
    setup = dataclasses.replace(prepare(load_scenario("table2"), fmu_dir, build=False),
                                isolate=["sensors", "controller"])  # sensors refuse; controller pipelined
    with setup.open_master() as m:
        bad = m.run(setup.case_parameters({"sensors": {"sample_period": 0.0015}}), setup.record, 50)
        good = m.run(setup.case_parameters({}), setup.record, 50)
    o = bad["outcome"]
    assert (o.status, o.fmu, o.function, o.fmu_status) == ("error", "sensors", "fmi2DoStep", "error")
    assert "sample_period" in o.fmu_message and o.fmu_message in bad["message"]
    assert good["status"] == "ok" and good["steps_done"] == 50


def test_the_step_timeout_bounds_every_step_but_a_runs_first(bad):
    """FMUs do lazy work in their first step (our Python plant compiles its kernels): it gets START_TIMEOUT_S;
    every later step the step timeout. A controller whose every step takes 2 s, with a step timeout of 1 s."""
    with Master({"c": bad["slow"]}, ["c"], [], isolate=["c"], step_timeout=1.0) as m:
        out = m.run({"c": {"fail_at": 0.0}}, [("c", "tau1")], 3)
    o = out["outcome"]
    assert (o.fmu, o.function, o.fmu_status, out["steps_done"]) == ("c", "fmi2DoStep", "timeout", 1)
    assert "step 1 (t = 0.001 s)" in o.message and "within 1 s (the step timeout, --step-timeout)" in o.message
