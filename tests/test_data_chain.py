"""The data chain: a trajectory refuses to load against a parameter file it was not made from."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from flexarm.parameters import DEFAULT_PARAMETER_FILE
from flexarm.provenance import sha256_file
from flexarm.trajectory import (
    DEFAULT_TRAJECTORY_FILE,
    REGENERATE_COMMAND,
    StaleTrajectoryError,
    load_trajectory,
    save_trajectory,
)


@pytest.fixture()
def copied_chain(tmp_path):
    """The committed parameter file and trajectory (npz and its sealed JSON) copied side by side into a temporary
    folder."""
    params = tmp_path / DEFAULT_PARAMETER_FILE.name
    shutil.copyfile(DEFAULT_PARAMETER_FILE, params)
    traj = tmp_path / DEFAULT_TRAJECTORY_FILE.name
    shutil.copyfile(DEFAULT_TRAJECTORY_FILE, traj)
    shutil.copyfile(DEFAULT_TRAJECTORY_FILE.with_suffix(".json"), traj.with_suffix(".json"))
    return params, traj


def test_committed_trajectory_matches_committed_parameters():
    result = load_trajectory()
    assert result.metadata["parameter_sha256"] == sha256_file(DEFAULT_PARAMETER_FILE)


def test_trajectory_from_a_changed_parameter_file_is_refused(copied_chain):
    params, traj = copied_chain
    assert load_trajectory(traj).n_samples > 1000  # the copy next to it matches
    params.write_text(params.read_text().replace("\n", "\n# edited\n", 1))
    with pytest.raises(StaleTrajectoryError) as err:
        load_trajectory(traj)
    msg = str(err.value)
    assert str(traj) in msg and str(params) in msg and REGENERATE_COMMAND in msg


def test_explicit_parameter_file_is_checked(copied_chain, tmp_path):
    params, traj = copied_chain
    other = tmp_path / "other.toml"
    other.write_text(params.read_text() + "\n")
    with pytest.raises(StaleTrajectoryError, match="other.toml"):
        load_trajectory(traj, parameter_file=other)
    assert load_trajectory(traj, parameter_file=params).t_f == pytest.approx(load_trajectory().t_f)


def test_trajectory_without_a_recorded_checksum_is_refused(copied_chain, tmp_path):
    _, traj = copied_chain
    result = load_trajectory(traj)
    result.metadata.pop("parameter_sha256")
    bare = tmp_path / "bare.npz"
    save_trajectory(result, bare)
    with pytest.raises(StaleTrajectoryError, match="records no parameter SHA-256"):
        load_trajectory(bare)
    # an inspecting tool may opt out explicitly, and then reads the same samples
    assert np.array_equal(load_trajectory(bare, parameter_file=False).tau, result.tau)


def test_regenerate_runs_the_chain_in_order_and_stops_at_a_failure(monkeypatch, capsys):
    """parameters -> trajectory -> gains -> FMUs, each its documented command; a failing stage stops the chain."""
    import subprocess

    from flexarm import regenerate

    ran = []

    class Done:
        def __init__(self, rc):
            self.returncode = rc

    def fake_run(cmd, cwd):
        ran.append(cmd)
        return Done(1 if "flexarm.lqr" in cmd else 0)

    monkeypatch.setattr(subprocess, "run", fake_run)
    assert regenerate.main([]) == 1
    assert [c[2] if c[1] == "-m" else c[1] for c in ran] == ["flexarm.calibration", "flexarm.trajectory",
                                                               "flexarm.lqr"]  # FMUs not built after a failure
    assert "--write" in ran[-1]
    err = capsys.readouterr().err
    assert "stage 'gains' failed" in err and "--from gains" in err
    ran.clear()
    assert regenerate.main(["--from", "fmus"]) == 0
    assert ran == [[ran[0][0], "build_fmus.py", "--force"], [ran[0][0], "-m", "scenarios", "results-page"]]


def test_the_chain_hashes_each_file_once_and_nothing_is_remembered_after_it(tmp_path, monkeypatch):
    """Every design record names the trajectory and the parameter file: one verification hashes each file once
    (it hashed the trajectory 30 times); the memo lives only inside the verification, so a file rewritten with the
    same size and time stamp afterwards is hashed again, never taken from an old digest."""
    import os

    from flexarm import data_chain, provenance

    hashed = []
    plain = provenance._sha256_of
    monkeypatch.setattr(provenance, "_sha256_of", lambda p: hashed.append(os.fspath(p)) or plain(p))
    digests = data_chain.verify_data_files()
    assert len(hashed) == len(set(hashed)) and len(digests) <= len(hashed)
    assert all(digests[k] == plain(data_chain.DATA_DIR.parent.parent / k) for k in digests)
    f = tmp_path / "same_size.bin"
    f.write_bytes(b"a" * 64)
    stamp = os.stat(f).st_mtime_ns
    first = provenance.sha256_file(f)
    f.write_bytes(b"b" * 64)
    os.utime(f, ns=(stamp, stamp))
    assert provenance.sha256_file(f) != first
