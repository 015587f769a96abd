"""Fault suite, continued (issue 16): what a run reads and writes. A broken or stale data file, a locked,
unwritable or full results folder, stale files of an earlier run, unpacked FMUs of a killed run, an unknown or
garbage FMU file and sweep journals: each refused or cleaned up with an honest message, never a wrong result
with exit 0 (the outcomes, steps and values of a run are in tests/test_faults.py, whose helpers this file uses).
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from test_faults import TIMEOUT, cli, prepare_table2, scenario_file, stderr_line

from flexarm.provenance import sha256_bytes
from scenarios.__main__ import main
from scenarios.master import fmu_files
from scenarios.run import setup as run_setup
from scenarios.run import write as run_write
from scenarios.run.setup import verify_data_chain
from scenarios.sweep import Journal, run_sweep


@pytest.fixture(scope="module")
def table2_setup():
    return prepare_table2()


# ---------------------------------------------------------------------------------------- 4. data chain


def test_a_broken_trajectory_is_refused_through_the_loader(tmp_path, capsys, monkeypatch):
    from flexarm.provenance import sha256_file, write_sealed_json
    from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE, load_trajectory

    with np.load(DEFAULT_TRAJECTORY_FILE) as d:
        arrays = {k: d[k] for k in d.files}
    arrays["tau1"], arrays["tau2"] = arrays["tau1"][:-100], arrays["tau2"][:-100]  # torques cut short
    bad = tmp_path / "trajectory.npz"
    np.savez(bad, **arrays)
    meta = json.loads(DEFAULT_TRAJECTORY_FILE.with_suffix(".json").read_text())  # its side file records it
    write_sealed_json(bad.with_suffix(".json"), {**meta, "npz_sha256": sha256_file(bad)})
    monkeypatch.setattr(run_setup, "desired_trajectory", lambda: load_trajectory(bad))
    assert main(["run", "table2", "--out", str(tmp_path / "out"), "--quiet", "--no-plots"]) == 2
    err = stderr_line(capsys)
    assert err.startswith("error: data chain:") and str(bad) in err and "arrays of different lengths" in err
    assert not (tmp_path / "out").exists()


def _has(module: str, name: str) -> bool:
    import importlib

    try:
        return hasattr(importlib.import_module(module), name)
    except ImportError:
        return False


@pytest.mark.skipif(not _has("flexarm.trajectory", "StaleTrajectoryError"),
                    reason="needs the verifying trajectory loader (helper C, issue 16 item 4)")
def test_a_trajectory_made_from_other_parameters_is_refused(tmp_path, capsys, monkeypatch):
    import shutil

    import flexarm.trajectory.io
    from flexarm.parameters import DEFAULT_PARAMETER_FILE
    from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE, load_trajectory

    params, traj = tmp_path / DEFAULT_PARAMETER_FILE.name, tmp_path / DEFAULT_TRAJECTORY_FILE.name
    shutil.copyfile(DEFAULT_PARAMETER_FILE, params)
    shutil.copyfile(DEFAULT_TRAJECTORY_FILE, traj)
    shutil.copyfile(DEFAULT_TRAJECTORY_FILE.with_suffix(".json"), traj.with_suffix(".json"))
    params.write_text(params.read_text().replace("\n", "\n# edited\n", 1))
    monkeypatch.setattr(run_setup, "desired_trajectory", lambda: load_trajectory(traj))
    monkeypatch.setattr(flexarm.trajectory.io, "DEFAULT_TRAJECTORY_FILE", traj)
    assert main(["run", "table2", "--out", str(tmp_path / "out"), "--quiet", "--no-plots"]) == 2
    err = stderr_line(capsys)
    assert err.startswith("error: data chain:") and str(traj) in err and str(params) in err


@pytest.mark.skipif(not _has("flexarm.lqr", "StaleDataError"),
                    reason="needs the verifying gain loader (helper D, issue 16 item 4)")
def test_gains_made_from_another_trajectory_are_refused(tmp_path, capsys, monkeypatch):
    import shutil

    import flexarm.lqr
    from flexarm.provenance import write_sealed_json

    gains = tmp_path / "gains"
    shutil.copytree(flexarm.lqr.DEFAULT_GAIN_DIR, gains)
    meta = json.loads((gains / "gamma0.1_200ms.json").read_text())
    meta["trajectory_sha256"] = "0" * 64  # as if the trajectory had changed since the design
    write_sealed_json(gains / "gamma0.1_200ms.json", meta)  # sealed anew: only the recorded input is stale
    monkeypatch.setattr(flexarm.lqr, "DEFAULT_GAIN_DIR", gains)
    assert main(["run", "table2", "--out", str(tmp_path / "out"), "--quiet", "--no-plots"]) == 2
    err = stderr_line(capsys)
    assert err.startswith("error: data chain:") and "gamma0.1_200ms" in err and "trajectory" in err


def test_the_data_chain_is_recorded(tmp_path):
    chain = verify_data_chain()
    assert {"flexarm/data/sandia_arm.toml", "flexarm/data/trajectory.npz"} <= set(chain)
    assert sum(k.startswith("flexarm/data/gains/") for k in chain) >= 12 and all(len(v) == 64 for v in chain.values())


# ---------------------------------------------------------------------------------------- 5. output folders


def test_a_second_run_into_a_locked_folder_is_refused(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    fd = os.open(out / ".table2.lock", os.O_CREAT | os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        os.write(fd, b"4242")
        assert main(["run", "table2", "--out", str(out), "--quiet", "--no-plots"]) == 3
    finally:
        os.close(fd)
    err = stderr_line(capsys)
    assert "another run (pid 4242) is writing into it" in err and err.count("\n") == 0


def test_a_second_sweep_into_a_locked_folder_is_refused(tmp_path):
    from scenarios.run.outdir import FolderBusy

    sweep = tmp_path / "busy.toml"
    sweep.write_text("[sweep]\nname='busy'\nscenario='table2'\nsamples=20\n[axes]\nplant.payload_mass=[0.0]\n")
    (tmp_path / "out").mkdir()
    fd = os.open(tmp_path / "out" / ".busy.lock", os.O_CREAT | os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        with pytest.raises(FolderBusy, match="another run"):
            run_sweep(sweep, tmp_path / "out", serial=True, plots=False, progress=False)
    finally:
        os.close(fd)
    assert not (tmp_path / "out" / "busy" / "journal.jsonl").exists()


def test_an_unwritable_folder_is_refused_before_any_case_runs(tmp_path, capsys):
    (tmp_path / "a_file").write_text("")
    t0 = time.perf_counter()
    assert main(["run", "table2", "--out", str(tmp_path / "a_file" / "out"), "--quiet", "--no-plots"]) == 3
    err = stderr_line(capsys)
    assert err.count("\n") == 0 and "cannot be created" in err and "Not a directory" in err
    assert time.perf_counter() - t0 < 60  # refused up front, not after computing the cases


def test_disk_full_while_writing_gives_one_line_and_publishes_nothing(tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    (out / "table2").mkdir(parents=True)
    (out / "table2" / "none.csv").write_text("earlier run\n")

    def full(path, columns):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(run_write, "write_csv", full)  # the write stage (scenarios/run/write.py)
    sc = scenario_file(tmp_path, "table2")
    assert main(["run", str(sc), "--out", str(out), "--quiet", "--no-plots"]) == 3
    err = stderr_line(capsys)
    assert err.count("\n") == 0 and "No space left on device" in err
    assert (out / "table2" / "none.csv").read_text() == "earlier run\n"
    assert not list(out.glob(".table2.partial-*"))


def test_stale_files_of_an_earlier_run_are_gone(tmp_path):
    out = tmp_path / "out"
    folder = out / "stale"
    folder.mkdir(parents=True)
    (folder / "old_case.csv").write_text("from an earlier run\n")
    (out / ".stale.partial-killed").mkdir()  # a killed run's staging folder
    path = scenario_file(tmp_path, "stale", samples="20")
    assert main(["run", str(path), "--out", str(out), "--quiet", "--no-plots"]) == 0
    assert sorted(p.name for p in folder.iterdir()) == ["none.csv", "none.json"]
    assert sorted(p.name for p in out.iterdir()) == [".stale.lock", "stale"]


def test_sweep_disk_full_closes_the_cluster_and_does_not_hang(tmp_path):
    """The journal cannot write (and cannot close either): exit 3 in one line, the cluster is closed."""
    sweep = tmp_path / "full.toml"
    sweep.write_text("[sweep]\nname='full'\nscenario='table2'\nsamples=20\n[axes]\nplant.payload_mass=[0.0, 0.1]\n")
    code = (
        "import errno, os, sys\n"
        "from scenarios.sweep import Journal\n"
        "from scenarios.__main__ import main\n"
        "def full(*a, **k): raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), 'journal.jsonl')\n"
        "Journal.append = full\n"
        "Journal.close = full\n"
        f"sys.exit(main(['sweep', {str(sweep)!r}, '--workers', '1', '--quiet', '--no-plots', '--out', "
        f"{str(tmp_path / 'out')!r}]))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 3, proc.stderr
    assert "error: cannot write results: journal.jsonl: No space left on device" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_cancellation_in_dask_shutdown_is_not_logged_but_a_real_error_is():
    """What the disk-full sweep printed under load in CI: a nanny's unregister, cancelled by our closing."""
    import asyncio
    import io
    import logging

    from scenarios.sweep import worker

    stream = io.StringIO()
    handler = logging.StreamHandler(stream)  # where Dask's records go: its own handler, or the host's root one
    dask_log = logging.getLogger("distributed")
    dask_log.addHandler(handler)
    try:
        worker._quiet_cancellations()
        log = logging.getLogger("distributed.nanny")
        for exc in (asyncio.CancelledError(), RuntimeError("worker lost")):
            try:
                raise exc
            except BaseException:  # noqa: BLE001 - logged as Dask's log_errors does
                log.exception("in _on_worker_exit")
    finally:
        dask_log.removeHandler(handler)
    text = stream.getvalue()
    assert text.count("Traceback") == 1 and "RuntimeError: worker lost" in text and "CancelledError" not in text


def test_unpacked_fmus_of_a_killed_run_are_removed_by_the_next_one(tmp_path, table2_setup):
    env = {**os.environ, fmu_files.UNPACK_ENV: str(tmp_path),
           "FLEXARM_FMU_DIR": str(table2_setup.paths["plant"].parent)}
    code = ("import sys, time\nfrom scenarios.run.runner import prepare\nfrom scenarios.config import load_scenario\n"
            "m = prepare(load_scenario('table2'), build=False).open_master()\nprint('loaded', flush=True)\n"
            "time.sleep(600)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline().strip() == "loaded"
        root = tmp_path / "flexarm-fmus"
        (alive,) = list(root.iterdir())
        assert len(list(alive.iterdir())) == 4  # the lock and three unpacked FMUs
        assert fmu_files.remove_stale(root) == []  # its process is alive: kept
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        proc.kill()
    assert fmu_files.remove_stale(root) == [alive] and not alive.exists()


def test_a_normal_run_leaves_no_unpacked_fmus(tmp_path):
    path = scenario_file(tmp_path, "clean", samples="20")
    proc = cli(["run", str(path), "--out", str(tmp_path / "out"), "--quiet", "--no-plots"],
               env={fmu_files.UNPACK_ENV: str(tmp_path / "unpack")})
    assert proc.returncode == 0, proc.stderr
    assert list((tmp_path / "unpack" / "flexarm-fmus").iterdir()) == []


def test_an_fmu_replaced_in_place_is_read_anew_not_from_the_description_cache(tmp_path):
    """read_description parses each FMU version once per process (issue 34, start-up): a file replaced under
    the same name, as a rebuild or a user's copy does, is read again; a removed one is refused by name."""
    from fmu_harness import built_fmus

    fmus = built_fmus()
    path = tmp_path / "my.fmu"
    path.write_bytes(fmus["plant"].read_bytes())
    first = fmu_files.read_description(path)
    assert fmu_files.read_description(path) is first  # the same version: parsed once
    path.write_bytes(fmus["sensors"].read_bytes())
    again = fmu_files.read_description(path)
    assert again is not first and again.modelName != first.modelName
    path.unlink()
    with pytest.raises(fmu_files.NotAnFmuError, match="my.fmu: no such FMU file"):
        fmu_files.read_description(path)


def test_an_fmu_is_unpacked_with_what_runs_it_and_not_its_sources_or_other_platforms(tmp_path, monkeypatch):
    """unpack extracts the model description, the resources and this platform's binaries (issue 34, start-up):
    a native FMU's sources and its other platforms' binaries stay in the archive, and the FMU still runs."""
    import zipfile

    import fmpy
    from native_fmus import native_fmus

    monkeypatch.setenv(fmu_files.UNPACK_ENV, str(tmp_path))
    fmu = native_fmus()["plant"]
    with zipfile.ZipFile(fmu) as zf:
        members = zf.namelist()
    assert any(m.startswith("sources/") for m in members) and any(m.startswith("binaries/win64/") for m in members)
    folder = fmu_files.unpack(fmu)
    got = sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())
    want = sorted(m for m in members if not m.endswith("/") and fmu_files.needed_at_run_time(m))
    assert got == want and "modelDescription.xml" in got
    assert any(g.startswith(f"binaries/{fmpy.platform}/") for g in got)
    assert not any(g.startswith(("sources/", "binaries/win64/", "binaries/darwin64/")) for g in got)
    md = fmu_files.read_description(fmu)
    slave = fmpy.fmi2.FMU2Slave(guid=md.guid, unzipDirectory=str(folder),
                                modelIdentifier=md.coSimulation.modelIdentifier, instanceName="plant")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    slave.doStep(currentCommunicationPoint=0.0, communicationStepSize=1e-3)  # fmpy raises on a failed step
    theta1 = next(v.valueReference for v in md.modelVariables if v.name == "theta1")
    assert np.isfinite(slave.getReal([theta1])[0])
    slave.terminate()
    slave.freeInstance()


def test_stale_tmp_files_in_a_sweep_folder_are_removed(tmp_path):
    sweep = tmp_path / "tmpfiles.toml"
    sweep.write_text("[sweep]\nname='tmpfiles'\nscenario='table2'\nsamples=20\n[axes]\nplant.payload_mass=[0.0]\n")
    folder = tmp_path / "out" / "tmpfiles"
    folder.mkdir(parents=True)
    (folder / ".tmpfiles.csv.abc123.tmp").write_text("half a table")
    run_sweep(sweep, tmp_path / "out", serial=True, plots=False, progress=False)
    assert not list(folder.glob(".*.tmp"))


# ---------------------------------------------------------------------------------------- FMU files, sweep keys


def test_an_unknown_fmu_name_is_refused_listing_the_known_ones(tmp_path, capsys):
    code = main(["run", "table2", "--controller", "controller_xyz", "--out", str(tmp_path), "--quiet"])
    err = stderr_line(capsys)
    assert code == 2 and "fmus.controller: an FMU name of this project [" in err and "'controller_ff'" in err


def test_a_garbage_fmu_is_refused(tmp_path, capsys):
    junk = tmp_path / "junk.fmu"
    junk.write_bytes(b"this is no zip archive" * 10)
    code = main(["run", "table2", "--controller", str(junk), "--out", str(tmp_path / "out"), "--quiet"])
    err = stderr_line(capsys)
    assert code == 2 and f"fmus.controller: {junk}: not an FMU (not a zip archive" in err


def test_a_comment_in_the_sweep_file_reruns_nothing(tmp_path, capsys):
    sweep = tmp_path / "c.toml"
    sweep.write_text("[sweep]\nname='c'\nscenario='table2'\nsamples=20\n[axes]\nplant.payload_mass=[0.0, 0.1]\n")
    first = run_sweep(sweep, tmp_path / "out", serial=True, plots=False, progress=False)
    sweep.write_text("# a comment\n" + sweep.read_text().replace("[0.0, 0.1]", "[0.0, 0.1, 0.2]  # one more"))
    second = run_sweep(sweep, tmp_path / "out", serial=True, plots=False, progress=False)
    assert first.ran == 2 and second.ran == 1 and second.skipped == 2  # only the new value runs
    assert "match no point" not in capsys.readouterr().err
    sweep.write_text(sweep.read_text().replace("samples=20", "samples=21"))  # every point is another run now
    third = run_sweep(sweep, tmp_path / "out", serial=True, plots=False, progress=False)
    assert third.ran == 3 and "c: 3 journal record(s) match no point of this sweep" in capsys.readouterr().err


def test_journal_close_is_idempotent_after_a_failure(tmp_path):
    j = Journal(tmp_path / "j.jsonl")
    j.append({"key": "a", "status": "ok"})

    class Broken:
        def close(self):
            raise OSError(errno.ENOSPC, "No space left on device")

    j._f.close()
    j._f = Broken()
    with pytest.raises(OSError):
        j.close()
    j.close()  # the handle was dropped: a second close (e.g. in a finally) does nothing


def test_stale_tmp_files_in_the_sweep_fmu_cache_are_removed(tmp_path, monkeypatch):
    from scenarios.sweep import store_fmus

    monkeypatch.setenv("FLEXARM_SWEEP_FMU_CACHE", str(tmp_path))
    data = b"fmu bytes"
    folder = tmp_path / sha256_bytes(data)[:32]
    folder.mkdir()
    old, fresh = folder / ".plant.fmu.dead.tmp", folder / ".plant.fmu.busy.tmp"
    old.write_bytes(b"half")
    fresh.write_bytes(b"being written")
    os.utime(old, (time.time() - 3600, time.time() - 3600))
    store_fmus({"plant": "plant"}, {"plant": data})
    assert (folder / "plant.fmu").read_bytes() == data
    assert not old.exists() and fresh.exists()  # a concurrent writer's file is left alone


def test_a_closed_standard_output_is_reported_as_such_not_as_a_results_error():
    """`python -m scenarios list | head` : the reader leaving is a broken pipe (exit 141), not a results error."""
    r, w = os.pipe()
    os.close(r)  # the reader is gone before anything is written
    try:
        proc = subprocess.run([sys.executable, "-m", "scenarios", "list"], stdout=w, stderr=subprocess.PIPE,
                              text=True, timeout=TIMEOUT)
    finally:
        os.close(w)
    assert proc.returncode == 141, proc.stderr
    assert "broken pipe" in proc.stderr and "cannot write results" not in proc.stderr
    assert "Traceback" not in proc.stderr and "Exception ignored" not in proc.stderr


def test_a_heartbeat_cut_by_the_workers_own_close_is_not_logged_but_a_lost_scheduler_is():
    """What a SIGTERM sweep printed under load in CI (exit 143 as it should, and a Dask traceback): Dask's
    Worker.close cuts a heartbeat already on the wire, and the worker logs that as an ERROR."""
    import io
    import logging

    from distributed.comm.core import CommClosedError
    from distributed.core import Status

    from scenarios.sweep import worker

    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    dask_log = logging.getLogger("distributed")
    dask_log.addHandler(handler)
    class FakeWorker:  # weak-referenceable, as a Worker is
        status = Status.running

    fake = FakeWorker()
    try:
        worker.QuietClose().setup(fake)
        log = logging.getLogger("distributed.worker")
        for status in (Status.running, Status.closing, Status.closed):
            fake.status = status
            try:
                raise CommClosedError(f"heartbeat while {status.name}")
            except OSError:
                log.exception("Failed to communicate with scheduler during heartbeat.")
        try:
            raise RuntimeError("unexpected while closing")
        except RuntimeError:
            log.exception("Unexpected exception during heartbeat. Closing worker.")
    finally:
        dask_log.removeHandler(handler)
    text = stream.getvalue()
    assert text.count("Traceback") == 2, text
    assert "heartbeat while running" in text and "unexpected while closing" in text
    assert "heartbeat while closing" not in text and "heartbeat while closed" not in text
