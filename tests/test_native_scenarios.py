"""Table 2's four cases with the native FMUs against the Python FMUs, in our master (closed loop) and the CLI."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from fmu_harness import built_fmus
from native_fmus import native_fmus

from flexarm.provenance import sha256_file
from scenarios.config import SCENARIO_DIR, ScenarioError, load_scenario
from scenarios.metrics import METRICS
from scenarios.run.runner import CaseResult, format_table, simulate_case
from scenarios.run.setup import prepare


def _run_table2(fmus: dict, tmp_path, label: str):
    folder = tmp_path / label
    folder.mkdir()
    for name in ("plant", "sensors", "controller"):
        (folder / f"{name}.fmu").write_bytes(fmus[name].read_bytes())
    sc = load_scenario("table2")
    results, signals = [], {}
    for case in sc.cases:
        setup = prepare(sc, folder, names=case.fmus or None, build=False)
        with setup.open_master("gauss-seidel") as m:
            out, metrics = simulate_case(setup, m, case.parameters)
            assert out["status"] == "ok", out.get("message")
        signals[case.key] = out["signals"]
        results.append(CaseResult(case.key, case.label, "ok", "", metrics, 0.0, {}))
    return results, signals


def test_table2_native_equals_python(tmp_path):
    """Every recorded signal of the four cases (noise included: the sensors draw NumPy's numbers) agrees to
    1e-10 of its peak, and the printed tables are identical."""
    python, native = built_fmus(), native_fmus()
    res_py, sig_py = _run_table2(python, tmp_path, "python")
    res_nat, sig_nat = _run_table2(native, tmp_path, "native")
    for key in sig_py:
        assert set(sig_py[key]) == set(sig_nat[key])
        for name, ref in sig_py[key].items():
            got = np.asarray(sig_nat[key][name])
            ref = np.asarray(ref)
            # The accelerometers (recorded as what the controller saw, not used by its law) come from a linear
            # solve per sample: native and Python differ by about 5e-9 of their peak there (measured).
            rel = 1e-7 if name.startswith("sensors.acc") else 1e-10
            assert np.abs(got - ref).max() <= max(rel * np.abs(ref).max(), 1e-12), (key, name)
    assert format_table(res_nat, None) == format_table(res_py, None)
    for r_py, r_nat in zip(res_py, res_nat):
        for m in METRICS:
            assert abs(r_nat.metrics[m] - r_py.metrics[m]) <= 1e-9 * abs(r_py.metrics[m]) + 1e-12, (r_py.key, m)


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "scenarios", *args], capture_output=True, text=True, timeout=900)


def _table(stdout: str) -> str:
    """The printed table of the (one) scenario: its lines after the "== name" header, up to the wall times (the
    per-case warnings left out: table2's undamped loop is unstable, scenarios/analysis/stability.py)."""
    lines = stdout.split("\n== ", 1)[1].splitlines()[1:]
    return "\n".join(ln for ln in lines if ln.strip() and not ln.lstrip().startswith(("wall time", "results:"))
                     and ": warning: " not in ln)


def test_cli_runs_table2_native_with_the_python_sets_table(tmp_path):
    """``python -m scenarios run table2 --native`` prints the table the Python set prints; the results record
    the kind and the native files' SHA-256; a scenario's ``kind = "native"`` chooses the same, --python
    overrides it."""
    python, native = built_fmus(), native_fmus()
    dirs = ["--fmu-dir", str(python["plant"].parent), "--native-fmu-dir", str(native["plant"].parent)]
    runs = {}
    for kind in ("native", "python"):
        proc = _cli("run", "table2", f"--{kind}", *dirs, "--out", str(tmp_path / kind), "--quiet", "--no-plots")
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert f"[{kind} FMUs]" in proc.stdout
        runs[kind] = _table(proc.stdout)
    assert runs["native"] == runs["python"]
    assert "peak torque (1st joint)" in runs["native"] and len(runs["native"].splitlines()) == 8
    record = json.loads((tmp_path / "native" / "table2" / "none.json").read_text())
    assert record["fmu_kind"] == "native"
    assert record["fmu_kinds"] == {"plant": "native", "sensors": "native", "controller": "native"}
    assert record["fmu_sha256"] == {i: sha256_file(native[i]) for i in ("plant", "sensors", "controller")}
    assert json.loads((tmp_path / "python" / "table2" / "none.json").read_text())["fmu_kind"] == "python"

    text = (SCENARIO_DIR / "table2.toml").read_text()
    assert '\n[scenario]\n' in text
    chosen = tmp_path / "table2_native.toml"
    chosen.write_text(text.replace("\n[scenario]\n", '\n[scenario]\nkind = "native"\n', 1))
    for flag, kind in (((), "native"), (("--python",), "python")):
        out = tmp_path / f"file-{kind}"
        proc = _cli("run", str(chosen), *flag, *dirs, "--out", str(out), "--quiet", "--no-plots")
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert json.loads((out / "table2" / "none.json").read_text())["fmu_kind"] == kind



def test_cli_refuses_a_name_without_a_native_build_before_anything_runs(tmp_path, monkeypatch, capsys):
    """As if controller_ff had no native build: ``run table2 compare_ff_fb --native`` exits 2 naming it, before
    table2 (which has every native FMU) runs."""
    from fmu_build import native_build as build_native
    from scenarios.__main__ import main

    monkeypatch.setattr(build_native, "NATIVE_FMUS", {k: v for k, v in build_native.NATIVE_FMUS.items()
                                                      if k != "controller_ff"})
    out = tmp_path / "refused"
    assert main(["run", "table2", "compare_ff_fb", "--native", "--out", str(out), "--quiet", "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "fmus.controller: controller_ff has no native build" in err and "--python" in err
    assert not (out / "table2").exists()


def test_a_scenario_kind_outside_the_choices_is_refused(tmp_path):
    bad = tmp_path / "bad.toml"
    text = (SCENARIO_DIR / "table2.toml").read_text()
    bad.write_text(text.replace("\n[scenario]\n", '\n[scenario]\nkind = "c"\n', 1))
    with pytest.raises(ScenarioError, match=r"scenario.kind: one of \['python', 'native'\]"):
        load_scenario(bad)


def test_build_fmus_both_kinds_up_to_date_and_refusals(tmp_path, monkeypatch, capsys):
    """build_fmus.py's native kind: a second build of up-to-date FMUs rebuilds nothing; an FMU without a native
    build is refused naming it; without ziglang it says so and builds nothing."""
    from fmu_build.cli import main
    from fmu_build.compile import BuildError
    from fmu_build.native import build_native_all, native_is_up_to_date

    python, native = built_fmus(), native_fmus()
    stamps = {n: p.stat().st_mtime_ns for n, p in native.items()}
    again = build_native_all(python, next(iter(native.values())).parent)
    assert again == native and {n: p.stat().st_mtime_ns for n, p in again.items()} == stamps
    assert all(native_is_up_to_date(native[n], python[n]) for n in native)
    stale = tmp_path / "plant.fmu"
    stale.write_bytes(native["plant"].read_bytes())
    os.utime(stale, ns=(python["plant"].stat().st_mtime_ns - 10**9,) * 2)  # older than its Python twin
    assert not native_is_up_to_date(stale, python["plant"])
    from fmu_build import native_build as build_native

    with monkeypatch.context() as m:  # as if controller_ff had no native build
        m.setattr(build_native, "NATIVE_FMUS", {k: v for k, v in build_native.NATIVE_FMUS.items()
                                                if k != "controller_ff"})
        with pytest.raises(BuildError, match="no native build of controller_ff"):
            build_native_all(python, tmp_path, only=["controller_ff"])

    monkeypatch.setitem(sys.modules, "ziglang", None)  # as if not installed: import ziglang raises
    out, native_out = tmp_path / "py", tmp_path / "nat"
    assert main(["--out", str(out), "--native-out", str(native_out), "--only", "sensors"]) == 1
    err = capsys.readouterr().err
    assert "pip install ziglang" in err and "--kind python" in err
    assert not out.exists() and not native_out.exists()  # said before anything was built


def test_a_native_sweep_runs_the_native_files_and_never_reuses_python_points(tmp_path):
    """run_sweep(kind="native"): every point on the native FMU files (their SHA-256 in sweep.json), with the
    Python set's metrics; the Python kind into the same folder reuses none of the native points."""
    from scenarios.sweep import run_sweep

    python, native = built_fmus(), native_fmus()
    sweep = tmp_path / "two_schedules.toml"
    sweep.write_text('[sweep]\nname = "two"\ndescription = "two schedules"\nscenario = "table2"\ncase = "none"\n'
                     "\n[axes]\ncontroller.schedule_period = [0.2, 0.0]\n")
    dirs = {"fmu_dir": python["plant"].parent, "native_fmu_dir": native["plant"].parent}
    runs = {}
    for kind in ("native", "python"):
        runs[kind] = run_sweep(sweep, tmp_path / "out", serial=True, plots=False, progress=False, build=False,
                               kind=kind, **dirs)
        meta = json.loads((tmp_path / "out" / "two" / "sweep.json").read_text())
        assert meta["fmu_kind"] == kind
        files = native if kind == "native" else python
        assert meta["fmu_sets"][0]["fmu_sha256"] == {i: sha256_file(files[i]) for i in ("plant", "sensors",
                                                                                         "controller")}
        assert runs[kind].ran == 2 and runs[kind].skipped == 0  # the Python run reused no native point
    for r_nat, r_py in zip(runs["native"].rows, runs["python"].rows):
        assert r_nat["status"] == r_py["status"] == "ok"
        for m in METRICS:
            assert abs(float(r_nat[m]) - float(r_py[m])) <= 1e-9 * abs(float(r_py[m])) + 1e-12, m
