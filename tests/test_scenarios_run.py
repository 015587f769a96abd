"""The master runs a scenario end to end, and its table matches the library closed loop."""

import numpy as np
import pytest

from flexarm import ArmModel, load_parameters
from flexarm.control import TrackingController, simulate_closed_loop
from flexarm.provenance import package_version
from flexarm.trajectory import load_trajectory
from scenarios.config import load_scenario
from scenarios.run.runner import run_scenario


@pytest.fixture(scope="module")
def table2_results(tmp_path_factory):
    sc = load_scenario("table2")
    sc.cases = [c for c in sc.cases if c.key in ("none", "tip")]
    out = tmp_path_factory.mktemp("results")
    return run_scenario(sc, out, progress=False), out


def test_results_written_with_provenance(table2_results):
    import json

    results, out = table2_results
    for r in results:
        meta = json.loads((out / "table2" / f"{r.key}.json").read_text())
        assert meta["status"] == "ok" and len(meta["commit"]) >= 7 and meta["commit"] != "unknown"
        assert meta["version"] == package_version()
        assert set(meta["fmu_sha256"]) == {"plant", "sensors", "controller"}
        assert meta["parameter_file"].endswith("sandia_arm.toml") and len(meta["parameter_file_sha256"]) == 64
        lines = (out / "table2" / f"{r.key}.csv").read_text().splitlines()
        assert len(lines) == meta["samples"] + 3  # the header, the units line, one row per communication point
        assert lines[1].startswith("# units: s,rad,") and lines[1].count(",") == lines[0].count(",")
        assert meta["verdict"]["verdict"] == "stable"


def test_fmu_cosimulation_equals_library_loop(table2_results):
    """Without noise the FMU chain and the library closed loop give the same states (1e-9)."""
    results, _ = table2_results
    traj = load_trajectory()
    for r in results:
        payload = 0.275 if r.key == "tip" else 0.0
        states = simulate_closed_loop(ArmModel(load_parameters(payload_mass=payload)),
                                      TrackingController(traj, "gamma0.1"))
        states = states[0] if isinstance(states, tuple) else states
        theta = np.column_stack([r.series[f"plant.theta{i}"] for i in range(1, 12)])
        n = min(len(theta), len(states))
        assert np.max(np.abs(theta[:n] - np.asarray(states)[:n, :11])) < 1e-9


def test_table2_qualitative_findings(table2_results):
    """Paper: the payload degrades velocity tracking far more than position tracking stays near."""
    results, _ = table2_results
    m = {r.key: r.metrics for r in results}
    assert m["none"]["rms_position_error"] < 0.1
    assert m["tip"]["rms_velocity_error"] > 5 * m["none"]["rms_velocity_error"]
    assert m["tip"]["peak_position_error"] < 20  # positions stay within degrees
    assert max(m["tip"]["peak_tau1"], m["none"]["peak_tau1"]) <= 7.0


@pytest.fixture(scope="module")
def table2_setup():
    from scenarios.run.setup import prepare

    return prepare(load_scenario("table2"))


def test_master_reuse_resets_every_fmu(table2_setup):
    """Two runs on one loaded master (fmi2Reset between) equal a run on freshly loaded FMUs, bit for bit."""
    setup = table2_setup
    params = setup.case_parameters({"sensors": {"noise_enabled": True, "noise_seed": 7}})
    record = setup.record + [("sensors", "q1_m")]
    with setup.open_master() as m:
        first = m.run(params, record, n_steps=300)
        second = m.run(params, record, n_steps=300)
    with setup.open_master() as fresh:
        third = fresh.run(params, record, n_steps=300)
    for key, values in first["signals"].items():
        assert np.array_equal(values, second["signals"][key]), key
        assert np.array_equal(values, third["signals"][key]), key


def test_stepping_algorithms_differ_by_one_sample_through_feedthrough(table2_setup):
    """Gauss-Seidel: the sensors sample the plant at t_k; Jacobi: at t_(k-1) (one step late)."""
    setup = table2_setup
    params = setup.case_parameters(setup.scenario.cases[0].parameters)  # no noise
    record = [("plant", "q1"), ("sensors", "q1_m"), ("controller", "tau1")]
    runs = {}
    for algorithm in ("gauss-seidel", "jacobi"):
        with setup.open_master(algorithm) as m:
            runs[algorithm] = m.run(params, record, n_steps=200)["signals"]
    gs, jac = runs["gauss-seidel"], runs["jacobi"]
    assert np.array_equal(gs["sensors.q1_m"], gs["plant.q1"])
    assert np.array_equal(jac["sensors.q1_m"][1:], jac["plant.q1"][:-1])
    assert not np.array_equal(jac["controller.tau1"], gs["controller.tau1"])


def test_bad_wiring_and_records_are_named(table2_setup):
    from scenarios.master import cosim as master

    setup = table2_setup
    bad = setup.connections + [master.Connection("plant", "q1", "sensorz", "q1")]
    with pytest.raises(master.CoSimulationError, match="sensorz"):
        master.Master(setup.paths, setup.scenario.order, bad)
    with setup.open_master() as m:
        with pytest.raises(master.CoSimulationError, match="no variable 'tip_z'"):
            m.run(setup.case_parameters({}), [("plant", "tip_z")], n_steps=3)
    with pytest.raises(master.CoSimulationError, match="algorithm"):
        master.Master(setup.paths, setup.scenario.order, setup.connections, algorithm="parallel")


def test_records_are_values_after_all_inputs_are_set(table2_setup):
    """Sensors evaluated before the plant (plant -> sensors becomes a feedback edge): their recorded
    outputs, which depend on those late inputs, are read again, so they still equal the plant's at t_k."""
    from scenarios.master import cosim as master

    setup = table2_setup
    order = ["sensors", "controller", "plant"]
    record = [("plant", "q1"), ("sensors", "q1_m"), ("sensors", "eps3_m")]
    with master.Master(setup.paths, order, setup.connections) as m:
        out = m.run(setup.case_parameters(setup.scenario.cases[0].parameters), record, n_steps=100)
    sig = out["signals"]
    assert out["status"] == "ok"
    assert np.array_equal(sig["sensors.q1_m"], sig["plant.q1"])
    assert np.any(sig["sensors.eps3_m"] != 0.0)


def test_case_option_selects_cases_and_refuses_an_unknown_key(capsys):
    """`run NAME --case KEY` keeps those cases in the file's order; an unknown key is refused (exit 2), naming
    the scenario's keys, before anything runs."""
    from scenarios.__main__ import main
    from scenarios.config import select_cases

    sc = load_scenario("table2")
    assert [c.key for c in select_cases(sc, ["tip", "none"]).cases] == ["none", "tip"]
    assert select_cases(sc, None) is sc and len(sc.cases) == 4
    assert main(["run", "table2", "--case", "none", "--case", "nope", "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "--case: one of the cases of table2 (none, noise, tip, tip_noise), got 'nope'" in err


def test_progress_is_a_bar_on_a_terminal_and_one_line_in_a_log():
    import io

    from scenarios.run.runner import _bar

    class Tty(io.StringIO):
        def isatty(self):
            return True

    log, tty = io.StringIO(), Tty()
    for stream in (log, tty):
        update = _bar("table2:none", stream)
        for k in range(0, 2059, 20):
            update(k, 2058)
        update(2058, 2058)
    assert "\r" not in log.getvalue() and log.getvalue().count("\n") == 1
    assert log.getvalue().startswith("table2:none") and log.getvalue().endswith("running, 2058 steps\n")
    assert tty.getvalue().count("\r") > 50 and tty.getvalue().endswith("100%\n")


def test_numba_notice_only_where_numba_compiles(monkeypatch, capsys, tmp_path):
    """A run of Python FMUs says the plant will compile its kernels, unless Numba is off or missing, or the
    kernels of that FMU build are cached already (flexarm._numba_cache)."""
    import importlib.util
    import zipfile

    from scenarios.run.fmus import _say_numba_compile, numba_compiles

    monkeypatch.delenv("FLEXARM_NO_NUMBA", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    has_numba = importlib.util.find_spec("numba") is not None
    _say_numba_compile()
    err = capsys.readouterr().err
    assert ("compiles its Numba kernels" in err) == has_numba
    fmu = tmp_path / "plant.fmu"  # the layout of a Python FMU's private packages
    with zipfile.ZipFile(fmu, "w") as z:
        z.writestr("resources/_flexarm_plant_0123456789ab/__init__.py", "")
    assert numba_compiles(fmu) == has_numba
    cached = tmp_path / "cache" / "flexarm-fmi" / "numba" / "_flexarm_plant_0123456789ab"
    cached.mkdir(parents=True)
    (cached / "_kernels.advance-455.py311.nbi").write_bytes(b"")
    assert numba_compiles(fmu) is False  # that build's kernels are cached
    _say_numba_compile(fmu)
    assert capsys.readouterr().err == ""
    monkeypatch.setenv("FLEXARM_NO_NUMBA", "1")
    _say_numba_compile()
    assert capsys.readouterr().err == "" and numba_compiles() is False


