"""A run is planned once (issue 33 item 2, "The data's path is short"): scenarios/run/plan.py.

The plan is frozen; every case's values are checked once, all before the first FMU is loaded; the trajectory is
loaded once per run; which FMUs run in a process of their own is decided in the plan, not patched in afterwards.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from fmu_harness import built_fmus

from scenarios.config import ScenarioError, load_scenario, select_cases
from scenarios.master import cosim
from scenarios.run import runner
from scenarios.run import setup as run_setup
from scenarios.run.plan import plan_run

TABLE2 = (Path(__file__).resolve().parents[1] / "scenarios" / "table2.toml").read_text()
#: A short run: Table 2's loop over 50 communication steps.
SHORT = TABLE2.replace('samples = "trajectory"', "samples = 50")


@pytest.fixture(scope="module")
def fmu_dir() -> Path:
    return built_fmus()["plant"].parent


def _scenario(folder: Path, name: str, cases: str) -> Path:
    """table2.toml, 50 steps, renamed, with the given cases."""
    text = SHORT.split("[[cases]]")[0].replace('name = "table2"', f'name = "{name}"').replace(
        'paper_table = "table2"\n', "")
    path = folder / f"{name}.toml"
    path.write_text(text + "\n" + cases)
    return path


def test_the_plan_is_frozen(fmu_dir):
    plan = plan_run(select_cases(load_scenario("table2"), ["none"]), fmu_dir=fmu_dir)
    (fmu_set, (case,)), = plan.groups
    with pytest.raises(dataclasses.FrozenInstanceError):
        plan.algorithm = "jacobi"
    with pytest.raises(dataclasses.FrozenInstanceError):
        fmu_set.isolate = list(fmu_set.paths)
    with pytest.raises(dataclasses.FrozenInstanceError):
        case.parameters = {}
    with pytest.raises(TypeError):  # the checked values are a read-only view
        case.parameters["plant"] = {}
    with pytest.raises(TypeError):
        plan.data.data_sha256["flexarm/data/trajectory.npz"] = "0" * 64
    assert case.parameters["plant"]["q1_0"] == fmu_set.start["q1_0"]  # the start on the trajectory, planned
    assert plan.scenario is plan.data.scenario and plan.algorithm == "gauss-seidel"


def test_each_case_is_checked_once_and_the_trajectory_loaded_once(tmp_path, monkeypatch, fmu_dir):
    """Before: each case's values were checked three times (validation, probe, run) and the trajectory loaded
    up to five times per run."""
    checked, loaded = [], []
    check = run_setup.FmuSetPlan.case_parameters
    load = run_setup.desired_trajectory
    monkeypatch.setattr(run_setup.FmuSetPlan, "case_parameters",
                        lambda self, p, where="": checked.append(where) or check(self, p, where))
    monkeypatch.setattr(run_setup, "desired_trajectory", lambda: loaded.append(1) or load())
    path = _scenario(tmp_path, "twice", '[[cases]]\nkey = "a"\n\n[[cases]]\nkey = "b"\n'
                                        'parameters.plant.payload_mass = 0.275\n')
    results = runner.run_scenario(load_scenario(path), tmp_path / "out", fmu_dir, progress=False, kind="python")
    assert [r.status for r in results] == ["ok", "ok"]
    assert checked == ["twice.toml: cases[a].parameters", "twice.toml: cases[b].parameters"]
    assert len(loaded) == 1


def test_a_refused_case_value_names_its_case_before_any_fmu_is_loaded(tmp_path, monkeypatch, fmu_dir):
    opened = []
    monkeypatch.setattr(cosim.Master, "__init__", lambda self, *a, **k: opened.append(a) or (_ for _ in ()).throw(
        AssertionError("a master was opened")))
    path = _scenario(tmp_path, "refused", '[[cases]]\nkey = "fine"\n\n[[cases]]\nkey = "bad"\n'
                                          'parameters.plant.payload_mass = -1.0\n')
    with pytest.raises(ScenarioError) as err:
        runner.run_scenario(load_scenario(path), tmp_path / "out", fmu_dir, progress=False)
    assert "refused.toml: cases[bad].parameters.plant.payload_mass" in str(err.value)
    assert opened == [] and not (tmp_path / "out" / "refused").exists()


def test_isolation_is_decided_in_the_plan(tmp_path, fmu_dir):
    scenario = select_cases(load_scenario("table2"), ["none"])
    (ours, _), = plan_run(scenario, fmu_dir=fmu_dir).groups
    assert ours.isolate == [] and ours.step_timeout == runner.DEFAULT_STEP_TIMEOUT_S  # our FMUs named by name
    (every, _), = plan_run(scenario, fmu_dir=fmu_dir, isolate="all", step_timeout=7.5).groups
    assert every.isolate == list(every.paths) and every.step_timeout == 7.5
    theirs = tmp_path / "their_controller.fmu"  # a controller given as a .fmu path is someone else's
    theirs.write_bytes(built_fmus()["controller"].read_bytes())
    (foreign, _), = plan_run(scenario, fmu_dir=fmu_dir, controller=str(theirs)).groups
    assert foreign.isolate == ["controller"]
    with pytest.raises(ScenarioError, match="--isolate: one of"):
        plan_run(scenario, fmu_dir=fmu_dir, isolate="some")


def test_a_sweep_point_is_checked_as_a_run_s_case(tmp_path, monkeypatch, fmu_dir):
    """The sweep's worker plans a point with the run's plan_case: one check, the run's converted values."""
    from scenarios.sweep import worker

    checked = []
    check = run_setup.FmuSetPlan.case_parameters
    monkeypatch.setattr(run_setup.FmuSetPlan, "case_parameters",
                        lambda self, p, where="": checked.append(p) or check(self, p, where))
    monkeypatch.setenv("FLEXARM_SWEEP_FMU_CACHE", str(tmp_path / "cache"))
    scenario = load_scenario(_scenario(tmp_path, "point", '[[cases]]\nkey = "none"\n'))
    fmus = {inst: built_fmus()[name] for inst, name in scenario.fmus.items()}
    store = worker.store_fmus(scenario.fmus, {inst: p.read_bytes() for inst, p in fmus.items()})
    task = {"key": "k", "index": 0, "scenario": scenario, "fmu_names": dict(scenario.fmus), "fmu_sha256": store,
            "parameters": {"plant": {"payload_mass": 0.275}}, "isolate": "foreign", "step_timeout": 60.0,
            "where": {"fmu_dir": fmu_dir}, "setup_key": "test-run-plan"}
    try:
        rec = worker.run_point(task)
    finally:
        worker.close_loaded()
    assert rec["status"] == "ok" and checked == [{"plant": {"payload_mass": 0.275}}]



def test_closing_a_worker_stops_its_running_point_before_freeing_its_fmus(tmp_path, monkeypatch, fmu_dir):
    """Closing a sweep's workers while a point still steps (a cancelled Dask task runs on in its thread):
    the point stops at its next progress call and only then are its FMUs freed (freeing them under it
    corrupted the worker's heap, CI after a Ctrl-C)."""
    import threading

    from scenarios.sweep import worker

    monkeypatch.setenv("FLEXARM_SWEEP_FMU_CACHE", str(tmp_path / "cache"))
    scenario = load_scenario(_scenario(tmp_path, "point", '[[cases]]\nkey = "none"\n'))
    fmus = {inst: built_fmus()[name] for inst, name in scenario.fmus.items()}
    store = worker.store_fmus(scenario.fmus, {inst: p.read_bytes() for inst, p in fmus.items()})
    task = {"key": "k", "index": 0, "scenario": scenario, "fmu_names": dict(scenario.fmus), "fmu_sha256": store,
            "parameters": {}, "isolate": "foreign", "step_timeout": 60.0, "where": {"fmu_dir": fmu_dir},
            "setup_key": "test-close-while-running"}
    stepping, closed, steps_seen, after_close = threading.Event(), threading.Event(), [], []
    check = worker._stop_requested

    def progress(k, n):
        steps_seen.append((k, n))
        if closed.is_set():
            after_close.append(k)
        stepping.set()
        check(k, n)

    monkeypatch.setattr(worker, "_stop_requested", progress)
    records = []
    point = threading.Thread(target=lambda: records.append(worker.run_point(task)))
    point.start()
    try:
        assert stepping.wait(120)
        assert worker.close_loaded() == 0  # waited for the point, which freed its own FMUs as it stopped
        closed.set()
        assert not worker._LOADED and not worker._STOP.is_set()
    finally:
        point.join(120)
        worker.close_loaded()
    rec, = records
    assert rec["status"] == "error" and "PointStopped" in rec["message"]
    k, n = steps_seen[-1]
    assert k < n and not after_close  # stopped part-way, and no step after close_loaded returned

