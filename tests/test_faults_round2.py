"""Fault suite, round 2 (issue 26): the inputs a new user or a misbehaving host tried, each with its honest outcome.

Every edited data file refused by name (exit 2); names that would write outside the results folder refused and
nothing outside ``--out`` touched; closed or full standard streams, NUL bytes, deep nesting and huge sizes
without a traceback; an input left unwired refused; saturation said, not hidden; the native plant refusing
fmi2SetReal after a discarded step as the Python plant does. Runs that step FMUs run in both kinds.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave
from fmu_harness import built_fmus
from native_fmus import native_fmus

from scenarios.__main__ import EXIT_STDOUT, main
from scenarios.config import MAX_CASES, MAX_SAMPLES, SCENARIO_DIR, ScenarioError, check_size, load_scenario

ROOT = Path(__file__).resolve().parents[1]
TABLE2 = (SCENARIO_DIR / "table2.toml").read_text()
ONE_CASE = '[[cases]]\nkey = "none"\nlabel = "no tip mass, no noise"\n'
TIMEOUT = 600


def _fmus(kind: str) -> dict[str, Path]:
    return native_fmus() if kind == "native" else built_fmus()


def scenario_text(name="short", samples="20", fmus: dict[str, Path] | None = None, kind="python",
                  connections="", extra="", cases=ONE_CASE, step="0.001") -> str:
    """table2.toml with one case, renamed, shortened; FMUs as paths when given."""
    text = TABLE2.split("[[cases]]")[0]
    text = text.replace('name = "table2"', f"name = {json.dumps(name)}")
    text = text.replace('samples = "trajectory"', f"samples = {samples}").replace('paper_table = "table2"\n', "")
    text = text.replace("step_size_s = 0.001", f"step_size_s = {step}")
    text = text.replace("[scenario]\n", f'[scenario]\nkind = "{kind}"\n', 1)
    if fmus:
        for inst in ("plant", "sensors", "controller"):
            text = text.replace(f'{inst} = "{inst}"\n', f'{inst} = "{fmus[inst].as_posix()}"\n', 1)
    if connections:
        text = text.replace("[connections]\n", f"[connections]\n{connections}\n")
    return text + extra + "\n" + cases


def write(folder: Path, text: str, name="s.toml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


def run(path: Path, out: Path, *extra: str) -> int:
    return main(["run", str(path), "--out", str(out), "--quiet", "--no-plots", *extra])


def err_of(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err


def cli_shell(command: str, cwd: Path, timeout: float = TIMEOUT) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run(["bash", "-c", command], capture_output=True, text=True, timeout=timeout, cwd=cwd, env=env)


def tree_state(root: Path) -> dict[str, str]:
    """Every file and folder under `root`: path -> content hash (files) or 'dir'."""
    out = {}
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root).as_posix()
        out[rel] = "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


# ------------------------------------------------------------------------------------------ data chain
_EDIT_ALL = r'''
import contextlib, io, json, re, sys
from pathlib import Path
from flexarm.data_chain import data_files
from scenarios.__main__ import main

data, out = Path(sys.argv[1]), sys.argv[2]
args = ["run", "table2", "--out", out, "--quiet", "--no-plots"]

def attempt(path, edited):
    original = path.read_bytes()
    path.write_bytes(edited)
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(args)
    finally:
        path.write_bytes(original)
    return code, err.getvalue()

def one_byte(path):
    b = bytearray(path.read_bytes())
    if path.suffix == ".json":  # a value edited by hand: the first digit after the middle, changed
        i = next(i for i in range(len(b) // 2, len(b)) if chr(b[i]).isdigit())
        b[i] = ord("7") if b[i] != ord("7") else ord("3")
    else:  # a flipped byte in the middle of the compressed arrays
        b[len(b) // 2] ^= 0xFF
    return bytes(b)

from scenarios.run.runner import verify_data_chain
results = {"clean": len(verify_data_chain())}  # the unedited copy passes
for f in data_files(data):
    if f.suffix in (".npz", ".json"):
        results[f.relative_to(data).as_posix()] = attempt(f, one_byte(f))
bank = data / "lqg" / "bank_200ms.json"
results["bank sample time"] = attempt(bank, bank.read_bytes().replace(b'"sample_time_s": 0.001',
                                                                      b'"sample_time_s": 0.002'))
print(json.dumps(results))
'''


def test_every_npz_and_json_edited_by_one_byte_is_refused_by_name(tmp_path):
    """In a copy of the code and data: one byte of each .npz and .json changed in turn, then `run table2`: exit 2,
    the message names the file (also for the bank's sample time changed by hand, and a flipped byte of the
    trajectory's compressed arrays: no BadZipFile)."""
    copy = tmp_path / "tree"
    shutil.copytree(ROOT / "flexarm", copy / "flexarm", ignore=shutil.ignore_patterns("__pycache__", "*.png"))
    shutil.copytree(ROOT / "scenarios", copy / "scenarios", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("fmus", "fmu_build"):
        (copy / name).symlink_to(ROOT / name)
    env = {**os.environ, "PYTHONPATH": str(copy)}
    proc = subprocess.run([sys.executable, "-c", _EDIT_ALL, str(copy / "flexarm" / "data"), str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=TIMEOUT, env=env, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = json.loads(proc.stdout.splitlines()[-1])
    assert results.pop("clean") >= 60  # the copy as it was passes the chain (and records every file)
    files = [k for k in results if k != "bank sample time"]
    committed = [p for p in (ROOT / "flexarm" / "data").rglob("*") if p.suffix in (".npz", ".json")]
    assert len(files) == len(committed) >= 50
    assert {"trajectory.npz", "trajectory.json", "lqg/bank_200ms.json", "gains/gamma0.1_200ms.npz"} <= set(files)
    for rel, (code, err) in results.items():
        name = "bank_200ms.json" if rel == "bank sample time" else Path(rel).name
        assert code == 2 and "error: data chain:" in err and name in err, (rel, code, err[-500:])
        assert "Traceback" not in err and "BadZipFile" not in err, (rel, err[-500:])
    assert "differ" in results["trajectory.npz"][1]


# ------------------------------------------------------------------------------------------ names and paths
@pytest.mark.parametrize("field, value", [
    ("scenario", "./../../../victim"), ("scenario", "../x"), ("scenario", "a/b"), ("scenario", "a\u0000b"),
    ("scenario", "sweeps"), ("scenario", "Sweeps"), ("scenario", ".hidden"), ("scenario", ""),
    ("case", "../x"), ("case", "a/b"), ("case", "sweeps/x"),
])
def test_names_that_leave_the_results_folder_are_refused_and_nothing_outside_is_touched(tmp_path, capsys, field,
                                                                                         value):
    world = tmp_path / "world"
    (world / "victim").mkdir(parents=True)
    (world / "victim" / "precious.txt").write_text("keep me")
    (world / "results" / "sweeps" / "robustness").mkdir(parents=True)
    (world / "results" / "sweeps" / "robustness" / "journal.jsonl").write_text("{}\n")
    out = world / "a" / "b" / "results"
    if field == "scenario":
        text = scenario_text(name=value)
    else:
        text = scenario_text(cases=f'[[cases]]\nkey = {json.dumps(value)}\nlabel = "x"\n')
    path = write(tmp_path, text)
    before = tree_state(world)
    assert run(path, out) == 2
    err = err_of(capsys)
    where = "scenario.name" if field == "scenario" else "cases[0].key"
    assert where in err and ("plain identifier" in err or "control character" in err or "results tree" in err), err
    assert tree_state(world) == before  # nothing written, moved or removed anywhere (--out included)


def test_sweep_names_are_plain_identifiers(tmp_path):
    from scenarios.sweep import load_sweep

    for name in ("../x", "a/b", "é"):
        path = write(tmp_path, f"[sweep]\nname = {json.dumps(name)}\nscenario = 'table2'\n[axes]\n"
                               "plant.payload_mass = [0.0]\n", "sw.toml")
        with pytest.raises(ScenarioError, match="sweep.name: a plain identifier"):
            load_sweep(path)


# ------------------------------------------------------------------------------------------ odd inputs
def test_nul_bytes_anywhere_in_a_scenario_are_refused(tmp_path, capsys):
    for text in (scenario_text().replace("payload_mass = 0.0", '"pay\\u0000load" = 0.1'),
                 scenario_text().replace('sensors = "sensors"', 'sensors = "sens\\u0000ors"'),
                 scenario_text(cases='[[cases]]\nkey = "none"\nlabel = "a\\u0000b"\n')):
        assert run(write(tmp_path, text), tmp_path / "out") == 2
        assert "control character" in err_of(capsys)


@pytest.mark.parametrize("kind", ["scenario", "sweep"])
def test_an_array_nested_5000_deep_is_refused(tmp_path, capsys, kind):
    deep = "x = " + "[" * 5000 + "]" * 5000 + "\n"
    if kind == "scenario":
        assert run(write(tmp_path, deep + scenario_text()), tmp_path / "out") == 2
    else:
        path = write(tmp_path, deep + "[sweep]\nname = 'deep'\nscenario = 'table2'\n", "deep.toml")
        assert main(["sweep", str(path), "--out", str(tmp_path / "out"), "--serial", "--quiet"]) == 2
    assert "nested too deeply" in err_of(capsys)


def test_huge_runs_are_capped_with_a_flag_to_go_past(tmp_path, capsys):
    assert run(write(tmp_path, scenario_text(samples="1e7")), tmp_path / "out") == 2  # a float: not a count
    assert "scenario.samples" in err_of(capsys)
    assert run(write(tmp_path, scenario_text(samples=str(MAX_SAMPLES + 1))), tmp_path / "out") == 2
    err = err_of(capsys)
    assert f"{MAX_SAMPLES + 1} communication steps" in err and "--allow-large" in err
    tiny_step = scenario_text(samples='"trajectory"', step="0.000001", fmus=built_fmus())
    assert run(write(tmp_path, tiny_step), tmp_path / "out_step") == 2
    assert "--allow-large" in err_of(capsys)  # a tiny step makes a long run too (refused before any case ran)
    assert not (tmp_path / "out_step" / "short").exists()
    many = "".join(f'[[cases]]\nkey = "c{i}"\n' for i in range(10_000))
    assert run(write(tmp_path, scenario_text(cases=many)), tmp_path / "out") == 2
    err = err_of(capsys)
    assert "10000 cases" in err and f"the {MAX_CASES}" in err and "--allow-large" in err
    assert not (tmp_path / "out").exists()
    sc = load_scenario(write(tmp_path, scenario_text(cases=many)))
    sc.allow_large = True  # what --allow-large sets
    check_size(sc, 10 * MAX_SAMPLES)


# ------------------------------------------------------------------------------------------ runs, both kinds
@pytest.mark.parametrize("kind", ["python", "native"])
def test_closed_standard_streams_still_give_results(tmp_path, kind):
    path = write(tmp_path, scenario_text(fmus=_fmus(kind), kind=kind))
    for redirect in ("2>&-", ">&-", ">&- 2>&-", "<&- >&- 2>&-"):
        out = tmp_path / f"out{len(redirect)}"
        proc = cli_shell(f"{sys.executable} -m scenarios run {path} --out {out} --no-plots {redirect}; echo rc=$?",
                         tmp_path)
        assert proc.stdout.strip().endswith("rc=0"), (redirect, proc.stdout, proc.stderr)
        assert json.loads((out / "short" / "none.json").read_text())["status"] == "ok", redirect


@pytest.mark.parametrize("kind", ["python", "native"])
def test_stdout_to_dev_full_says_the_results_were_written(tmp_path, kind):
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full on this system")
    path = write(tmp_path, scenario_text(fmus=_fmus(kind), kind=kind))
    proc = cli_shell(f"{sys.executable} -m scenarios run {path} --out {tmp_path / 'out'} --quiet --no-plots "
                     f">/dev/full", tmp_path)
    assert proc.returncode == EXIT_STDOUT, proc.stderr
    assert "standard output: cannot print the table" in proc.stderr and "the results were written" in proc.stderr
    assert str(tmp_path / "out" / "short") in proc.stderr and "Traceback" not in proc.stderr
    assert json.loads((tmp_path / "out" / "short" / "none.json").read_text())["status"] == "ok"


@pytest.mark.parametrize("kind", ["python", "native"])
def test_explicit_wiring_that_leaves_an_input_open_is_refused(tmp_path, capsys, kind):
    fmus = _fmus(kind)
    md = {inst: read_model_description(str(fmus[inst])) for inst in ("plant", "sensors", "controller")}
    pairs = []
    for dst in ("plant", "sensors", "controller"):
        outputs = {v.name: src for src in md for v in md[src].modelVariables
                   if v.causality == "output" and src != dst}
        pairs += [[f"{outputs[v.name]}.{v.name}", f"{dst}.{v.name}"] for v in md[dst].modelVariables
                  if v.causality == "input" and v.name in outputs and v.name != "tau2"]
    wiring = "explicit = " + json.dumps(pairs)
    path = write(tmp_path, scenario_text(fmus=fmus, kind=kind, connections=wiring))
    assert run(path, tmp_path / "out") == 2
    err = err_of(capsys)
    assert "input plant.tau2 is not connected" in err and '"plant.tau2"]' in err
    assert not (tmp_path / "out" / "short").exists()
    full = "explicit = " + json.dumps([*pairs, ["controller.tau2", "plant.tau2"]])
    assert run(write(tmp_path, scenario_text(fmus=fmus, kind=kind, connections=full), "full.toml"),
               tmp_path / "out") == 0, err_of(capsys)


@pytest.mark.parametrize("kind", ["python", "native"])
def test_saturation_is_said_in_the_table_and_the_json(tmp_path, capsys, kind):
    """lqg_jacobi stepped every 4 ms with loop_delay_samples = 2 (it needs 8): the torques sit at the motors'
    limits most of the run. Table 2's no-payload case at 1 ms does not warn."""
    fmus = _fmus(kind)
    text = (SCENARIO_DIR / "lqg_jacobi.toml").read_text().split("[[cases]]")[0]
    text = text.replace("step_size_s = 0.001", "step_size_s = 0.004").replace('name = "lqg_jacobi"',
                                                                              'name = "jacobi_4ms"')
    text = text.replace("[scenario]\n", f'[scenario]\nkind = "{kind}"\n', 1)
    text = text.replace("[parameters.controller]\n", "[parameters.controller]\nloop_delay_samples = 2\n", 1)
    for inst, fmu in (("plant", "plant"), ("sensors", "sensors"), ("controller", "controller_lqg")):
        text = text.replace(f'{inst} = "{fmu}"\n', f'{inst} = "{fmus[fmu].as_posix()}"\n', 1)
    path = write(tmp_path, text + ONE_CASE)
    main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet", "--no-plots"])
    printed = capsys.readouterr().out
    warnings = json.loads((tmp_path / "out" / "jacobi_4ms" / "none.json").read_text())["warnings"]
    tau2 = [w for w in warnings if w.startswith("torque saturation: tau2")]
    assert len(tau2) == 1 and float(tau2[0].split("samples (")[1].split(" %")[0]) > 50.0, warnings
    assert f"none: warning: {warnings[0]}" in printed
    calm = write(tmp_path, scenario_text(name="calm", samples='"trajectory"', fmus=fmus, kind=kind), "calm.toml")
    assert run(calm, tmp_path / "out") == 0
    assert json.loads((tmp_path / "out" / "calm" / "none.json").read_text())["warnings"] == []
    assert "warning" not in capsys.readouterr().out


@pytest.mark.parametrize("kind", ["python", "native"])
def test_the_plant_refuses_set_real_after_a_discarded_step(tmp_path, kind):
    """A torque that drives the state non-finite: fmi2DoStep returns fmi2Discard; then fmi2SetReal is refused
    (the FMU is in stepFailed) until a state is restored, in both kinds."""
    fmu = _fmus(kind)["plant"]
    md = read_model_description(str(fmu))
    var = {v.name: v for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu), unzipdir=str(tmp_path / "u")),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="p")
    slave.instantiate()
    try:
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        state = slave.getFMUstate()
        slave.setReal([var["tau1"].valueReference], [1e300])
        with pytest.raises(FMICallException) as step:
            slave.doStep(0.0, 1e-3)
        assert step.value.status == 2  # fmi2Discard
        with pytest.raises(FMICallException) as refused:
            slave.setReal([var["tau1"].valueReference], [0.0])
        assert refused.value.status == 3  # fmi2Error
        slave.setFMUstate(state)  # restoring a state leaves stepFailed
        slave.setReal([var["tau1"].valueReference], [0.0])
        slave.doStep(0.0, 1e-3)
        slave.freeFMUstate(state)
    finally:
        slave.freeInstance()
