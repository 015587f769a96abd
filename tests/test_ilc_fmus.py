"""Iterative learning control through the FMUs (scenarios/ilc/): the learned correction inside both kinds of our
controller FMUs, a short learning run through the FMUs (resumed from its journal), its failures and refusals, and
docs/ilc.md as its committed results. The learning's mathematics are in tests/test_ilc.py.
"""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from flexarm import ilc
from flexarm.control import TrackingController
from flexarm.gain_schedule import StaleDataError
from flexarm.trajectory.io import DEFAULT_TRAJECTORY_FILE

SCENARIO = Path(__file__).resolve().parent.parent / "scenarios" / "ilc_payload.toml"


def test_scenario_refuses_bad_settling_weights(tmp_path):
    from scenarios.config import ScenarioError
    from scenarios.ilc.scenario import load_ilc

    for key, value in (("settling_weight", "-1.0"), ("settling_weight", "2e6"), ("settling_tip_weight", "-5.0"),
                       ("settling_tip_weight", "true"), ("settling_model_payload_mass", "-0.1"),
                       ("settling_q_filter_cutoff_hz", "500.0"), ("evaluate_samples", "3000")):
        scen = tmp_path / "ilc_bad.toml"
        text = "\n".join(line for line in SCENARIO.read_text().splitlines() if not line.startswith(f"{key} ="))
        scen.write_text(text.replace("leak_weight = 1e-3", f"leak_weight = 1e-3\n{key} = {value}"))
        with pytest.raises(ScenarioError, match=rf"ilc\.{key}: (a|an) (factor|weight|payload|cut-off|integer) in \["):
            load_ilc(scen)
    scen.write_text(SCENARIO.read_text().replace("leak_weight = 1e-3",
                                                 "leak_weight = 1e-3\nsettling_q_filter_cutoff_hz = 3"))
    assert load_ilc(scen)[1].settling_q_filter_cutoff_hz == 3.0


def _learned_file(tmp_path, n: int):
    from flexarm.parameters import DEFAULT_PARAMETER_FILE
    from flexarm.provenance import sha256_file

    u = 0.05 * np.sin(np.arange(2 * n).reshape(n, 2) * 0.01)
    meta = {"trajectory_file": str(DEFAULT_TRAJECTORY_FILE), "trajectory_sha256": sha256_file(DEFAULT_TRAJECTORY_FILE),
            "parameter_file": str(DEFAULT_PARAMETER_FILE), "parameter_sha256": sha256_file(DEFAULT_PARAMETER_FILE)}
    return u, ilc.write_learned_feedforward(tmp_path / "u", u, 1e-3, meta)


def _carrying(fmu, tmp_path, name, npz=None, json=None):
    """A copy of the controller FMU `fmu` with `npz` and `json` (paths, or None to leave one out) as its learned
    correction in resources/, packed as they are (unchecked: to test what the FMU itself refuses)."""
    from flexarm.ilc import LEARNED_RESOURCE

    out = tmp_path / f"{name}_{fmu.name}"
    shutil.copyfile(fmu, out)
    with zipfile.ZipFile(out, "a") as z:
        for file, suffix in ((npz, ".npz"), (json, ".json")):
            if file is not None:
                z.write(file, f"resources/{Path(LEARNED_RESOURCE).with_suffix(suffix)}")
    return out


def _torques(fmu, n, params):
    from fmu_harness import _controller_inputs
    from native_fmus import run_fmpy

    names, rows = run_fmpy(fmu, n, _controller_inputs, params)
    return np.asarray(rows)[:, [names.index("tau1"), names.index("tau2")]]


def test_controller_fmus_add_the_learned_correction_python_and_native_alike(tmp_path):
    """Both kinds of controller FMU carrying a learned correction in their resources (fmu_build.learned): the Python
    one equals the library law with
    the same correction bit for bit; the native one equals the Python one to 1e-13 N·m (their K·m products sum in
    different orders: the unlearned controllers differ by the same ~1e-14 N·m), a run past the file's end and the
    saturation included; a missing, stale or edited file (its seal broken) is refused by both."""
    from fmu_harness import _controller_inputs, built_fmus
    from native_fmus import native_fmus

    n = 2200  # past the slew (2058 samples) and past the correction's 400 samples
    u, path = _learned_file(tmp_path, 400)
    from fmu_build.learned import with_learned_feedforward

    py, native = built_fmus()["controller"], native_fmus()["controller"]
    py_learned = with_learned_feedforward(py, path, tmp_path / "py_controller.fmu")
    native_learned = with_learned_feedforward(native, path, tmp_path / "native_controller.fmu")
    got = _torques(py_learned, n, {})
    law = TrackingController(DEFAULT_TRAJECTORY_FILE, "gamma0.1", feedforward_correction=u)
    keys = ("q1_m", "q2_m", "qd1_m", "qd2_m", *(f"eps{i}_m" for i in range(1, 7)))
    expect = np.array([law.torque_from_measurements(k, [_controller_inputs(k)[x] for x in keys])
                       for k in range(n + 1)])
    assert np.array_equal(got, expect)
    plain = _torques(py, n, {})
    assert not np.array_equal(plain[:400], got[:400]) and np.array_equal(plain[400:], got[400:])
    native_got, native_plain = _torques(native_learned, n, {}), _torques(native, n, {})
    assert np.abs(native_got - got).max() <= 1e-13 and np.abs(native_plain - plain).max() <= 1e-13
    # the correction itself is applied identically: learned − unlearned agree where nothing saturates
    free = (np.abs(got) < [7.0, 2.25]).all(axis=1) & (np.abs(plain) < [7.0, 2.25]).all(axis=1)
    assert np.abs((native_got - native_plain)[free] - (got - plain)[free]).max() <= 1e-13
    from flexarm.ilc import read_learned_feedforward

    stale = ilc.write_learned_feedforward(tmp_path / "stale", u, 1e-3,
                                          dict(read_learned_feedforward(path).metadata, parameter_sha256="0" * 64))
    # a broken seal of the .json (one digit of it changed; a byte added that JSON does not see): both kinds
    # refuse it, as flexarm.ilc.read_learned_feedforward does
    text = path.with_suffix(".json").read_text()
    seal = text.split('"json_sha256": "')[1][:64]
    broken = []
    for name, edited in (("seal", text.replace(seal, ("1" if seal[0] != "1" else "2") + seal[1:])),
                         ("space", text.replace("{", "{ ", 1))):
        shutil.copyfile(path, tmp_path / f"{name}.npz")
        (tmp_path / f"{name}.json").write_text(edited)
        broken.append(tmp_path / f"{name}.npz")
        with pytest.raises(StaleDataError, match="json_sha256"):
            read_learned_feedforward(broken[-1])
    with pytest.raises(StaleDataError):  # the packing refuses what the FMUs would refuse
        with_learned_feedforward(py, stale, tmp_path / "refused.fmu")
    for fmu in (py, native):
        carrying = [_carrying(fmu, tmp_path, "stale", stale, stale.with_suffix(".json")),
                    _carrying(fmu, tmp_path, "no_json", path),  # one file of the pair missing
                    _carrying(fmu, tmp_path, "no_npz", None, path.with_suffix(".json")),
                    *(_carrying(fmu, tmp_path, b.stem, b, b.with_suffix(".json")) for b in broken)]
        for bad in carrying:
            with pytest.raises(Exception):  # noqa: B017 - fmpy raises its own exception type for fmi2Error
                _torques(bad, 2, {})
        # packed again without a correction: the controller's own torques
        assert np.array_equal(_torques(with_learned_feedforward(carrying[0], None, tmp_path / "stripped.fmu"), 5,
                                       {}), (plain if fmu == py else native_plain)[:6])


def test_ilc_scenario_learns_through_the_fmus_and_resumes(tmp_path):
    """Two trials of a short ILC scenario through the Python FMUs, then a third after a 'restart': the journal
    keeps the first two, the third runs with the correction they produced, and the error falls."""
    from scenarios.config import ScenarioError
    from scenarios.ilc.trials import run_ilc

    text = SCENARIO.read_text().replace("samples = 3058", "samples = 400").replace("trials = 50", "trials = 2")
    text = text.replace('evaluate_cases = ["learn", "payload_0p2", "payload_0p35"]', 'evaluate_cases = ["learn"]')
    scen = tmp_path / "ilc_short.toml"
    scen.write_text(text)
    out = tmp_path / "out"
    first = run_ilc(scen, out, plots=False, progress=lambda s: None)
    assert first["stopped"] is None and [r["trial"] for r in first["trials"]] == [0, 1]
    assert [r["seed"] for r in first["trials"]] == [1, 2]
    journal = (out / "ilc_payload" / "journal.jsonl").read_text().splitlines()
    assert len(journal) == 3  # config + two trials
    second = run_ilc(scen, out, plots=False, progress=lambda s: None, trials=3)
    assert [r["trial"] for r in second["trials"]] == [0, 1, 2]
    assert second["trials"][0] == first["trials"][0]  # not rerun
    rms = [r["metrics"]["slew_rms_position_error"] for r in second["trials"]]
    assert rms[2] < rms[1] < rms[0]
    ev = second["evaluation"]["learn"]
    assert ev["learned"]["metrics"]["slew_rms_position_error"] < ev["unlearned"]["metrics"]["slew_rms_position_error"]
    from scenarios.reports.ilc_report import MARKER, render  # the page renders such a summary (its figures in it)

    page = render(second, [("study", second)], None, second)
    assert page.startswith(MARKER) and f"| 2 | {rms[2]:.4f} |" in page and "Jacobi stepping" in page
    learned = ilc.read_learned_feedforward(out / "ilc_payload" / "learned_feedforward.npz")
    assert learned.metadata["trials_learned_from"] == 3 and learned.correction.shape == (400, 2)
    # the learned controller as one self-contained FMU: the final correction inside it, its SHA-256 recorded
    fmu = out / "ilc_payload" / second["learned_controller"]["file"]
    from flexarm.provenance import sha256_file

    assert sha256_file(fmu) == second["learned_controller"]["sha256"]
    with zipfile.ZipFile(fmu) as z:
        packed = z.read("resources/learned_feedforward.npz")
    assert packed == (out / "ilc_payload" / "learned_feedforward.npz").read_bytes()
    for written in ("evaluation.json", "learned_feedforward.json"):  # no absolute path of this machine
        content = (out / "ilc_payload" / written).read_text()
        assert str(tmp_path) not in content and '"/' not in content, written
    # a number edited in a trial's journal line is refused, naming the line, never reported in trials.csv
    jpath = out / "ilc_payload" / "journal.jsonl"
    lines = jpath.read_text().splitlines()
    rec = json.loads(lines[2])
    rec["metrics"]["slew_rms_position_error"] /= 10
    jpath.write_text("\n".join([*lines[:2], json.dumps(rec), *lines[3:]]) + "\n")
    with pytest.raises(ScenarioError, match=r"line_sha256.*\(line 3\)"):
        run_ilc(scen, out, plots=False, progress=lambda s: None, trials=3)
    jpath.write_text("\n".join(lines) + "\n")
    # another configuration in the same folder is refused, not mixed
    scen.write_text(text.replace("leak_weight = 1e-3", "leak_weight = 2e-3"))
    with pytest.raises(ScenarioError, match="another configuration"):
        run_ilc(scen, out, plots=False, progress=lambda s: None)
    shutil.rmtree(out)


@pytest.mark.parametrize("params", [{"loop_delay_samples": 2, "integral_action": True},
                                    {"estimator": 2, "schedule_period": 0.2}], ids=["kalman-delay2-integral", "bank"])
def test_controller_lqg_adds_the_learned_correction_python_and_native_alike(tmp_path, params):
    """controller_lqg (both kinds) carrying a learned correction in its resources: the Python FMU equals the library
    law with the same correction bit for bit (the filter's input is τ − τ_ff, the correction included); the native one
    equals the Python one to 1e-10 of the peak torque (as without a correction, tests/test_native_lqg.py); the
    correction changes the torques; a stale file is refused by both."""
    from fmu_harness import built_fmus
    from native_fmus import native_fmus, run_fmpy
    from test_native_lqg import MEASURED, lqg_inputs

    from flexarm.lqg import lqg_controller
    from flexarm.lqg_bank import bank_controller

    n = 600
    u, path = _learned_file(tmp_path, 400)
    from fmu_build.learned import with_learned_feedforward

    py, native = built_fmus()["controller_lqg"], native_fmus()["controller_lqg"]

    def torques(fmu, p):
        names, rows = run_fmpy(fmu, n, lqg_inputs, p)
        return np.asarray(rows)[:, [names.index("tau1"), names.index("tau2")]]

    got = torques(with_learned_feedforward(py, path, tmp_path / "py_lqg.fmu"), params)
    plain = torques(py, params)
    delay = params.get("loop_delay_samples", 0)
    integral = params.get("integral_action", False)
    law = (bank_controller("gamma0.1", "200ms", delay, integral, feedforward_correction=u) if "estimator" in params
           else lqg_controller("gamma0.1", "200ms", delay, integral, feedforward_correction=u))
    state, expect = law.initial_state(), []
    for k in range(n + 1):  # the FMU computes sample k from the inputs of sample k - d (lqg_inputs(0) before)
        m = law.design.C @ law.z[0] if k < delay else [lqg_inputs(max(k - 1, 0) if delay else k)[x] for x in MEASURED]
        tau, state = law.step(state, k, m)
        expect.append(tau)
    assert not np.array_equal(got, plain)
    native_got = torques(with_learned_feedforward(native, path, tmp_path / "native_lqg.fmu"), params)
    assert np.abs(native_got - got).max() <= 1e-10 * np.abs(got).max()
    np.testing.assert_array_equal(got, np.array(expect))
    from flexarm.ilc import read_learned_feedforward

    stale = ilc.write_learned_feedforward(tmp_path / "stale", u, 1e-3,
                                          dict(read_learned_feedforward(path).metadata, trajectory_sha256="0" * 64))
    for fmu in (py, native):
        with pytest.raises(Exception):  # noqa: B017 - fmpy raises its own exception type for fmi2Error
            torques(_carrying(fmu, tmp_path, "stale", stale, stale.with_suffix(".json")), params)


def test_an_fmu_error_in_the_middle_of_a_trial_stops_the_campaign(tmp_path, monkeypatch, capsys):
    """The controller returns fmi2Error from fmi2DoStep at t = 0.2 s of trial 1 (as a failing FMU does): the
    campaign stops there (no trial 2, no learned file, no evaluation), the journal keeps the failed trial, and
    ``python -m scenarios run`` says which trial, step and FMU, and exits non-zero; run again, it stays stopped."""
    from scenarios.__main__ import main
    from scenarios.master import units

    text = SCENARIO.read_text().replace("samples = 3058", "samples = 300").replace("trials = 50", "trials = 3")
    text = text.replace('evaluate_cases = ["learn", "payload_0p2", "payload_0p35"]', 'evaluate_cases = ["learn"]')
    scen = tmp_path / "ilc_fail.toml"
    scen.write_text(text)
    raw, runs = units.fmu2_raw_functions, []

    def failing(slave):
        get_real, set_real, do_step = raw(slave)
        if slave.instanceName != "controller":
            return get_real, set_real, do_step

        def step(component, t, h, new_step):
            if t == 0.0:
                runs.append(t)
            return 3 if len(runs) == 2 and t >= 0.2 else do_step(component, t, h, new_step)  # 3: fmi2Error
        return get_real, set_real, step

    monkeypatch.setattr(units, "fmu2_raw_functions", failing)
    out = tmp_path / "out"
    args = ["run", str(scen), "--out", str(out), "--no-plots", "--quiet"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "stopped: trial 1: error" in err and "t = 0.2" in err and "controller" in err, err
    folder = out / "ilc_payload"
    journal = [json.loads(line) for line in (folder / "journal.jsonl").read_text().splitlines()]
    assert [r.get("status") for r in journal[1:]] == ["ok", "error"]
    assert not (folder / "learned_feedforward.npz").exists()
    summary = json.loads((folder / "evaluation.json").read_text())
    assert summary["evaluation"] == {} and len(summary["trials"]) == 2
    assert main(args) == 1 and len((folder / "journal.jsonl").read_text().splitlines()) == 3  # stays stopped


def test_the_ilc_page_is_its_committed_results(capsys):
    """docs/ilc.md's generated parts are what docs/ilc_results.json and docs/ilc_floor.json render to, from the
    scenario and data files as they are (no runs: the runs take 15-20 minutes; their commands regenerate all)."""
    from scenarios.ilc import floor as ilc_floor
    from scenarios.reports import ilc_report

    assert ilc_floor.main(["--check"]) == 0, capsys.readouterr().err
    assert ilc_report.main(["--check"]) == 0, capsys.readouterr().err


def test_the_ilc_report_refuses_to_drop_a_master_silently(tmp_path, capsys, monkeypatch):
    """Without OMSimulator the report refuses (exit 2, naming the tool and the way out) before any run; with
    --without-omsimulator its page says the tool was absent. Before, the column just went missing."""
    from scenarios.reports import ilc_report

    monkeypatch.setattr(ilc_report, "omsimulator", lambda: None)
    assert ilc_report.main(["--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "OMSimulator is not installed" in err and "--without-omsimulator" in err
    assert not (tmp_path / "out").exists()
    record = json.loads(ilc_report.RESULTS.read_text())
    record["masters_absent"] = ["omsimulator"]
    page = ilc_report._render_from(record)
    assert "OMSimulator was not installed on the machine that ran this report" in page
    assert "was not installed" not in ilc_report._render_from({k: v for k, v in record.items()
                                                              if k != "masters_absent"})


def test_run_all_says_it_leaves_the_ilc_scenarios_out(capsys):
    """`run all` runs the single-run scenarios and says, in one line, which ILC scenarios it does not run (here it
    stops at once, refusing an unknown case, before running anything)."""
    from scenarios.__main__ import main

    assert main(["run", "all", "--case", "no_such_case"]) != 0
    lines = [x for x in capsys.readouterr().err.splitlines() if "ILC" in x]
    assert len(lines) == 1 and "ilc_payload" in lines[0] and "ilc_lqg_jacobi" in lines[0], lines


@pytest.mark.parametrize("options, named", [
    (["--controller", "my/MyController.fmu"], "--controller my/MyController.fmu"),
    (["--set", "plant.payload_mass=0.2"], "--set plant.payload_mass=0.2"),
    (["--case", "learn"], "--case learn"),
])
def test_an_ilc_scenario_refuses_the_options_it_would_not_honour(tmp_path, capsys, options, named):
    """`--controller`, `--set` and `--case` on an ILC scenario: exit 2 with a sentence naming the option and why, before
    anything runs or is written; never our controller's figures under the user's name (issue 32 item 6)."""
    from scenarios.__main__ import EXIT_REFUSED, main

    code = main(["run", "ilc_payload", "--out", str(tmp_path / "out"), "--quiet", "--no-plots", *options])
    err = capsys.readouterr().err
    assert code == EXIT_REFUSED == 2 and named in err and "learns the feedforward of its own controller" in err, err
    assert not (tmp_path / "out").exists()


def test_an_ilc_scenario_refuses_a_controller_that_reads_no_learned_feedforward(tmp_path):
    """controller_fb has no feedforward to correct: the ILC run is refused before any trial, naming the FMU and
    the controllers that learn, rather than learning a correction nobody applies."""
    from scenarios.config import ScenarioError
    from scenarios.ilc.trials import run_ilc

    text = SCENARIO.read_text().replace('controller = "controller"', 'controller = "controller_fb"', 1)
    scen = tmp_path / "ilc_fb.toml"
    scen.write_text(text.replace("samples = 3058", "samples = 10"))
    with pytest.raises(ScenarioError, match=r"controller_fb\.fmu does not read a learned feedforward.*"
                                             r"FlexarmControllerLQG"):
        run_ilc(scen, tmp_path / "out", plots=False, progress=lambda s: None)
    assert not (tmp_path / "out" / "ilc_payload" / "journal.jsonl").exists()


def test_the_learned_controller_gives_its_figure_in_other_masters(tmp_path):
    """The learned controller FMU carries the learning into any master (issue 32): a short Jacobi ILC run with the
    native controller_lqg, its evaluation case as an SSP with learned_controller.fmu inside, nothing set, gives the
    run's learned figures in our master, libcosim and Ecos, and `fmpy validate` finds nothing."""
    from native_fmus import native_fmus

    from scenarios.ilc.masters import MASTERS, learned_in_masters, reproduces
    from scenarios.ilc.trials import run_ilc
    from scenarios.reports.ilc_report import _render_masters

    native_fmus()  # built once per test process
    jacobi = SCENARIO.with_name("ilc_lqg_jacobi.toml").read_text()
    text = (jacobi.replace("samples = 3058", "samples = 400")
            .replace("evaluate_samples = 7058", "evaluate_samples = 600")
            .replace('evaluate_cases = ["learn", "payload_0p2", "payload_0p35"]', 'evaluate_cases = ["learn"]'))
    scen = tmp_path / "ilc_lqg_jacobi.toml"
    scen.write_text(text)
    summary = run_ilc(scen, tmp_path / "out", kind="native", plots=False, progress=lambda s: None, trials=2)
    ev = summary["evaluation"]["learn"]
    assert ev["parameters"]["sensors"]["noise_seed"] == 3  # seed_base + trials: the evaluation's own noise
    res = learned_in_masters(scen, summary, tmp_path / "out" / "ilc_lqg_jacobi")
    assert res["fmpy_validate"] == [] and res["within"] == list(MASTERS), res
    row = res["cases"]["learn"]
    unlearned = {f"slew_{k}": ev["unlearned"]["metrics"][f"slew_{k}"]
                 for k in ("rms_position_error", "rms_velocity_error")}
    for master in MASTERS:  # the correction travelled inside the FMU: each master gives the learned run, not the
        assert not reproduces(row[master], unlearned), (master, row[master], unlearned)  # unlearned one
    assert "| ilc_lqg_jacobi | learn |" in "\n".join(_render_masters({"ilc_lqg_jacobi": res}))
    from scenarios.ilc.masters import main

    assert main([str(scen), "--out", str(tmp_path / "out")]) == 0  # the users' command on their run
    assert main(["ilc_lqg_jacobi", "--out", str(tmp_path / "out")]) == 2  # not the file the run was made from
