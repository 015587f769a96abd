"""Sweeps on Dask: cluster table equals the serial one bit for bit, failures are recorded, resume, validation."""

import json
import os
import shutil
import sys
import time
from pathlib import Path

import cloudpickle
import pytest
from distributed import Client, WorkerPlugin

from scenarios.__main__ import main
from scenarios.metrics import METRICS
from scenarios.sweep import SweepError, load_sweep, local_cluster, plan_sweep, read_table, run_sweep

# 2 payloads (random, reproducible) x 2 gain sets x 3 sensor sample periods (1.5 ms is not a whole fraction of
# the 1 ms communication step: the sensors FMU refuses the first step, an error point) = 12 points of 200 steps.
SMALL = """
[sweep]
name = "small"
scenario = "table2"
case = "noise"
samples = 200

[axes]
plant.payload_mass = { uniform = [0.0, 0.5], count = 2, seed = 7 }
controller.gain_set = ["gamma0.1", "gamma1"]
sensors.sample_period = [0.001, 0.0015]
sensors.noise_seed = { range = [1, 2] }
"""
#: Columns that must agree between two runs of the same points (not wall time, worker, dates).
SAME = ["index", "key", "plant.payload_mass", "controller.gain_set", "sensors.sample_period", "sensors.noise_seed",
        "status", *METRICS]


def _write(folder, text, name="small.toml"):
    path = folder / name
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sweep")
    path = _write(folder, SMALL)
    t0 = time.perf_counter()
    res = run_sweep(path, folder / "serial", serial=True, plots=False, progress=False)
    return path, res, time.perf_counter() - t0


def _same(table):
    return [{c: row[c] for c in SAME} for row in read_table(table)]


def test_serial_table_and_provenance(small):
    path, res, _ = small
    rows = read_table(res.tables[0])
    assert len(rows) == 16 and res.ran == 16
    assert {r["status"] for r in rows if r["sensors.sample_period"] == "0.001"} == {"ok"}
    failed = [r for r in rows if r["sensors.sample_period"] == "0.0015"]
    assert len(failed) == 8 and all(r["status"] == "error" and "sensors: fmi2DoStep returned error" in r["message"]
                                    for r in failed)
    assert all(r[m] == "" for r in failed for m in METRICS)
    journal = [json.loads(x) for x in (res.folder / "journal.jsonl").read_text().splitlines()]
    outcome = next(r["outcome"] for r in journal if r["status"] == "error")
    assert outcome["fmu"] == "sensors" and outcome["function"] == "fmi2DoStep" and outcome["fmu_status"] == "error"
    assert "sample_period" in outcome["fmu_message"]  # the FMU's own words, from the status it logged
    # each point that ran carries the loop check of a scenario run (0.2 s: under 3 e-folds even for γ = 1)
    ran = [r for r in journal if r["status"] == "ok"]
    assert {r["loop_stability"]["gain_set"] for r in ran} == {"gamma0.1", "gamma1"}
    assert all(r["warnings"] == [] and 0 < r["loop_stability"]["e_folds_over_run"] < 1 for r in ran)
    assert all(len(r["fmu_sha256.plant"]) == 64 and r["commit"] for r in rows)
    meta = json.loads((res.folder / "sweep.json").read_text())
    # no absolute path of this machine: the sweep file outside the checkout by its name, beside its SHA-256
    assert meta["sweep_sha256"] and meta["points"] == 16 and meta["sweep_file"] == f"…/{path.name}"
    assert meta["scenario_file"] == "scenarios/table2.toml"
    text = (res.folder / "sweep.json").read_text()
    assert str(path.parent) not in text and str(res.folder) not in text and '"/' not in text
    # random samples: reproducible from their seed, inside their range
    payloads = sorted({float(r["plant.payload_mass"]) for r in rows})
    assert payloads == sorted(load_sweep(path).axes[0].values) and all(0 <= p <= 0.5 for p in payloads)


def test_local_cluster_equals_serial_bit_for_bit(small, tmp_path):
    """... and the cluster shuts down cleanly: no worker killed by its nanny, no warning."""
    import logging

    path, serial, _ = small
    warnings = []
    handler = logging.Handler(logging.WARNING)
    handler.emit = lambda record: warnings.append(f"{record.name}: {record.getMessage()}")
    logger = logging.getLogger("distributed")  # Dask's loggers do not propagate to the root logger
    logger.addHandler(handler)
    try:
        res = run_sweep(path, tmp_path, workers=2, progress=False)
    finally:
        logger.removeHandler(handler)
    assert not warnings, warnings
    assert res.ran == 16
    assert _same(res.tables[0]) == _same(serial.tables[0])
    assert {p.name for p in res.plots} == {"metrics_vs_payload_mass.png", "rms_spread_over_seeds.png"}
    assert all(p.stat().st_size > 10_000 for p in res.plots)


class KillOnPoint(WorkerPlugin):
    """Test fixture: the worker that starts executing the named point exits at once (as a crash would)."""

    def __init__(self, point_key):
        self.point_key = point_key

    def transition(self, key, start, finish, **kwargs):
        if finish == "executing" and self.point_key in str(key):
            os._exit(13)


def test_worker_death_is_recorded_and_the_sweep_completes(small, tmp_path):
    path, serial, _ = small
    victim = plan_sweep(load_sweep(path)).points[1]  # ok in the serial run
    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers cannot import this test module
    cluster = local_cluster(2, allowed_failures=0)
    try:
        with Client(cluster) as client:
            client.register_plugin(KillOnPoint(victim.key), name="kill-on-point")
            res = run_sweep(path, tmp_path, scheduler=cluster.scheduler_address, progress=False, plots=False)
    finally:
        cluster.close()
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    rows = _same(res.tables[0])
    assert len(rows) == 16
    dead = rows[victim.index]
    assert dead["status"] == "error" and all(dead[m] == "" for m in METRICS)
    assert "KilledWorker" in read_table(res.tables[0])[victim.index]["message"]
    others = [r for r in rows if r["index"] != str(victim.index)]
    assert others == [r for r in _same(serial.tables[0]) if r["index"] != str(victim.index)]


def test_resume_skips_done_points(small, tmp_path, capsys):
    path, serial, _ = small
    folder = tmp_path / "small"
    shutil.copytree(serial.folder, folder)
    # a rerun (through the CLI) skips the 8 done points and retries the 8 error ones (exit code 1: errors)
    assert main(["sweep", str(path), "--serial", "--quiet", "--no-plots", "--out", str(tmp_path)]) == 1
    assert "(8 run now, 8 from the journal)" in capsys.readouterr().out
    # a crash lost the last two records, the one before was cut mid-line: those three run again
    journal = folder / "journal.jsonl"
    lines = journal.read_text().splitlines()
    keep = [json.loads(x) for x in lines]
    ok = [i for i, r in enumerate(keep) if r["status"] == "ok"]
    cut = ok[-3:]
    text = "\n".join(x for i, x in enumerate(lines) if i not in cut) + "\n" + lines[cut[0]][:40]
    journal.write_text(text)
    res = run_sweep(path, tmp_path, serial=True, plots=False, progress=False)
    assert res.ran == 3 + 8 and res.skipped == 5
    assert _same(res.tables[0]) == _same(serial.tables[0])
    assert journal.read_text().endswith("\n")  # the cut line was closed before appending


def test_an_edited_journal_number_is_never_reported(small, tmp_path, capsys):
    """A metric edited by hand in a finished sweep's journal breaks that line's seal: the rerun names the line,
    runs its point again and the table holds the computed value, not the edited one; so does a line without a
    seal (written by hand or by an older version)."""
    path, serial, _ = small
    folder = tmp_path / "small"
    shutil.copytree(serial.folder, folder)
    journal = folder / "journal.jsonl"
    lines = journal.read_text().splitlines()
    recs = [json.loads(x) for x in lines]
    edited, unsealed = [i for i, r in enumerate(recs) if r["status"] == "ok"][:2]
    recs[edited]["metrics"]["rms_velocity_error"] *= 7.13  # the edit: mean rms 0.006452 -> 0.04601
    del recs[unsealed]["line_sha256"]
    journal.write_text("".join(json.dumps(r) + "\n" if i in (edited, unsealed) else lines[i] + "\n"
                               for i, r in enumerate(recs)))
    res = run_sweep(path, tmp_path, serial=True, plots=False, progress=False)
    err = capsys.readouterr().err
    assert f"line {edited + 1}, {unsealed + 1}" in err and "run again" in err
    assert res.ran == 2 + 8 and res.skipped == 6  # the two lines and the 8 error points
    assert _same(res.tables[0]) == _same(serial.tables[0])


def test_fmu_swap_axis(tmp_path):
    path = _write(tmp_path, "[sweep]\nname='swap'\nscenario='table2'\ncase='tip'\nsamples=100\n[axes]\n"
                            "fmus.controller = ['controller', 'controller_ff']\n")
    res = run_sweep(path, tmp_path, serial=True, plots=False, progress=False)
    fb, ff = read_table(res.tables[0])
    assert fb["status"] == ff["status"] == "ok" and fb["fmu_sha256.controller"] != ff["fmu_sha256.controller"]
    assert fb["fmu_sha256.plant"] == ff["fmu_sha256.plant"] and fb["peak_tau2"] != ff["peak_tau2"]


@pytest.mark.parametrize("text, field, allowed", [
    ("[sweep]\nname='a'\nscenario='table2'\n[axes]\nplant.payload_mass=[0.0]\n[other]\n", "small.toml",
     "top-level tables allowed"),
    ("[sweep]\nname='a'\nscenario='table2'\ncase='nope'\n[axes]\nplant.payload_mass=[0.0]\n", "sweep.case",
     "one of the scenario's cases ['none', 'noise', 'tip', 'tip_noise']"),
    ("[sweep]\nname='a'\nscenario='no_such'\n[axes]\nplant.payload_mass=[0.0]\n", "sweep.scenario",
     "known scenarios"),
    ("[sweep]\nname='a'\nscenario='table2'\nsamples=0\n[axes]\nplant.payload_mass=[0.0]\n", "sweep.samples",
     "an integer in [1, 200000]"),
    ("[sweep]\nname='a'\nscenario='table2'\n[axes]\nrobot.payload_mass=[0.0]\n", "axes.robot",
     "an FMU instance of the scenario ['controller', 'plant', 'sensors']"),
    ("[sweep]\nname='a'\nscenario='table2'\n[axes]\nsensors.noise_seed={range=[5, 1]}\n",
     "axes.sensors.noise_seed.range", "first <= last"),
    ("[sweep]\nname='a'\nscenario='table2'\n[axes]\nplant.payload_mass={uniform=[0, 0.5], count=4}\n",
     "axes.plant.payload_mass.seed", "required for reproducibility"),
    ("[sweep]\nname='a'\nscenario='table2'\n[axes]\nplant.payload_mass={grid=[0, 0.5]}\n",
     "axes.plant.payload_mass", "{ uniform = [low, high], count = N, seed = S }"),
    ("[sweep]\nname='a'\nscenario='table2'\n[axes]\nplant.payload_mass=[0.1, 0.1]\n",
     "axes.plant.payload_mass", "unique values"),
])
def test_sweep_file_errors_name_the_field(tmp_path, text, field, allowed):
    with pytest.raises(SweepError) as err:
        load_sweep(_write(tmp_path, text))
    assert field in str(err.value) and allowed in str(err.value)


@pytest.mark.parametrize("axis, field, allowed", [
    ("plant.payload_mass = [0.0, -1.0]", "axes.plant.payload_mass", "a value in the FMU's range [0, 10] kg"),
    ("plant.payload_mas = [0.0]", "axes.plant.payload_mas", "a parameter of FMU plant.fmu ("),
    ("sensors.noise_seed = [1, 1.5]", "axes.sensors.noise_seed", "an integer (noise_seed is Integer), got 1.5"),
    ("sensors.noise_enabled = { range = [0, 1] }", "axes.sensors.noise_enabled", "true or false"),
    ("fmus.controller = ['controller', 'controller_xyz']", "axes.fmus.controller", "controller_dlqr"),
])
def test_axes_checked_against_the_fmus(tmp_path, axis, field, allowed):
    path = _write(tmp_path, f"[sweep]\nname='a'\nscenario='table2'\n[axes]\n{axis}\n")
    with pytest.raises(SweepError) as err:
        plan_sweep(load_sweep(path))
    assert field in str(err.value) and allowed in str(err.value)


def test_shipped_sweeps_load():
    rob, sched = load_sweep("robustness"), load_sweep("schedule")
    assert rob.n_points == 360 and sched.n_points == 12
    assert [a.field for a in rob.axes] == ["plant.payload_mass", "controller.gain_set", "sensors.noise_seed"]


def test_sweep_points_step_as_their_scenario(monkeypatch):
    """A sweep point's master steps with the scenario's algorithm (lqg_jacobi: Jacobi), not always
    Gauss-Seidel: the worker and the base-point probe open it through Setup.open_master."""
    from scenarios.config import load_scenario
    from scenarios.run import runner
    from scenarios.run.setup import Setup

    opened = []
    monkeypatch.setattr(runner.master, "Master", lambda *args: opened.append(args[3]) or args[3])
    for name, algorithm in (("lqg_jacobi", "jacobi"), ("table2", "gauss-seidel")):
        setup = Setup(load_scenario(name), {}, [], "plant", "controller", [], 0, {}, {},
                      isolate=[], step_timeout=60.0)  # in this process, as our FMUs named by name
        assert setup.open_master() == algorithm
        assert setup.open_master("gauss-seidel") == "gauss-seidel"  # an explicit choice wins
    assert opened == ["jacobi", "gauss-seidel", "gauss-seidel", "gauss-seidel"]


def test_sweep_caps_are_refused_and_allow_large_passes_them(tmp_path):
    """Issue 26 item 6: a cap has a clear message, with an explicit flag to go past it."""
    from scenarios.config import MAX_SAMPLES
    from scenarios.sweep.spec import MAX_POINTS

    long_points = _write(tmp_path, f"[sweep]\nname='a'\nscenario='table2'\nsamples={MAX_SAMPLES + 1}\n[axes]\n"
                                   "plant.payload_mass=[0.0]\n")
    with pytest.raises(SweepError) as err:
        load_sweep(long_points)
    assert "sweep.samples" in str(err.value) and "--allow-large" in str(err.value)
    assert load_sweep(long_points, allow_large=True).scenario.samples == MAX_SAMPLES + 1
    many = tmp_path / "many"
    many.mkdir()
    n = int(MAX_POINTS ** 0.5) + 1  # two axes of n values: n² > MAX_POINTS points
    many_points = _write(many, "[sweep]\nname='b'\nscenario='table2'\n[axes]\n"
                               f"sensors.noise_seed={{range=[1, {n}]}}\nsensors.other_seed={{range=[1, {n}]}}\n")
    with pytest.raises(SweepError) as err:
        load_sweep(many_points)
    assert "[axes]" in str(err.value) and "--allow-large" in str(err.value)
    assert load_sweep(many_points, allow_large=True).n_points == n * n


def test_the_sweep_caps_in_the_docs_are_the_code_s():
    from scenarios.config import MAX_SAMPLES
    from scenarios.sweep.spec import MAX_POINTS

    text = (Path(__file__).resolve().parents[1] / "docs" / "sweeps.md").read_text()
    assert f"more than {MAX_SAMPLES} samples per point or {MAX_POINTS} points need `--allow-large`" in text
