"""Data chain (issue 16 item 4): a gain schedule refuses to load when the files it was made from changed."""

import shutil

import numpy as np
import pytest

from flexarm import ArmModel, rigid_configuration
from flexarm.gain_schedule import (
    DEFAULT_GAIN_DIR,
    REGENERATE_COMMAND,
    GainSchedule,
    StaleDataError,
    design_schedule,
    trajectory_from_states,
)
from flexarm.gain_sets import GAIN_SET_NAMES
from flexarm.model import N
from flexarm.parameters import DEFAULT_PARAMETER_FILE, load_parameters
from flexarm.provenance import sha256_file
from flexarm.trajectory.io import load_trajectory, save_trajectory


@pytest.fixture()
def chain(tmp_path):
    """A parameter file and a trajectory file in tmp_path, and a single-set schedule designed from them."""
    par = tmp_path / "arm.toml"
    shutil.copy(DEFAULT_PARAMETER_FILE, par)
    model = ArmModel(load_parameters(par))
    n = 401
    t = np.arange(n) * 1e-3
    z = np.tile(np.r_[rigid_configuration(-0.9, 1.0), np.zeros(N)], (n, 1))
    traj = tmp_path / "traj.npz"
    result = trajectory_from_states(t, np.zeros((n, 2)), z)
    result.metadata.update(parameter_file=par.name, parameter_sha256=sha256_file(par))
    save_trajectory(result, traj)
    gains = tmp_path / "gains"
    design_schedule(model, traj, "gamma0.1", "single").save(gains)
    return par, traj, gains


def test_fresh_schedule_loads(chain):
    par, traj, gains = chain
    s = GainSchedule.load("gamma0.1", "single", gains)
    assert s.metadata["trajectory_file"].endswith("traj.npz")
    assert s.metadata["parameter_file"].endswith("arm.toml")


@pytest.mark.parametrize("changed", ["trajectory", "parameter"])
def test_changed_input_is_refused_naming_both_files_and_the_command(chain, changed):
    par, traj, gains = chain
    if changed == "trajectory":
        result = load_trajectory(traj)
        result.tau[10, 0] = 0.5
        save_trajectory(result, traj)
    else:
        par.write_text(par.read_text() + "\n# recalibrated\n")
    with pytest.raises(StaleDataError) as err:
        GainSchedule.load("gamma0.1", "single", gains)
    msg = str(err.value)
    assert f"the {changed} file" in msg
    assert str(traj) in msg and str(par) in msg and REGENERATE_COMMAND in msg


def test_tampered_gain_arrays_and_missing_provenance_are_refused(chain):
    par, traj, gains = chain
    npz = gains / "gamma0.1_single.npz"
    with np.load(npz) as d:
        arrays = {k: d[k] for k in d.files}
    arrays["gains"] = arrays["gains"] * 1.01
    np.savez(npz, **arrays)
    with pytest.raises(StaleDataError, match="differs from the SHA-256"):
        GainSchedule.load("gamma0.1", "single", gains)
    (gains / "gamma0.1_single.json").unlink()
    with pytest.raises(StaleDataError, match="provenance file"):
        GainSchedule.load("gamma0.1", "single", gains)


@pytest.mark.parametrize("name", GAIN_SET_NAMES)
def test_committed_schedules_match_the_committed_data(name):
    """The committed gain files were made from the committed trajectory and parameter file."""
    if not (DEFAULT_GAIN_DIR / f"{name}_200ms.npz").exists():
        pytest.skip("gain files not generated")
    s = GainSchedule.load(name, "200ms")
    assert s.metadata["trajectory_sha256"] and s.metadata["parameter_sha256"]
