"""The trajectory file: the 1 ms data type, reading and writing. No CasADi here.

A trajectory is two files written together by :func:`save_trajectory`:
``trajectory.npz`` (1 ms samples: ``t``, ``tau1``, ``tau2``, ``theta1..11``,
``omega1..11``, ``tip_x``, ``tip_y`` and the metadata as a JSON string) and
its ``.json`` sidecar (the same metadata, for people and ``git diff``).

The metadata record where the trajectory came from: the parameter file's
name and SHA-256, the commit and the command. :func:`load_trajectory` checks
that SHA-256 against the parameter file as it is now and refuses a stale
trajectory (see :func:`check_parameter_chain`).
"""

from __future__ import annotations

import json
import os
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..parameters import DATA_DIR, DEFAULT_PARAMETER_FILE, N_ELEMENTS
from ..provenance import DataFileError, jsonable, read_sealed_json, sha256_file, write_atomic, write_sealed_json

DEFAULT_TRAJECTORY_FILE = DATA_DIR / "trajectory.npz"
DEFAULT_PLOT_FILE = DATA_DIR / "trajectory.png"
#: Minimum time reported by the paper for its slew, s (compared with, never copied into outputs).
PAPER_TF = 2.058
#: Sample time of the file (and of the controller), s.
SAMPLE_TIME = 1e-3
#: The command that regenerates parameters, trajectory, gains and FMUs (named in refusals).
REGENERATE_COMMAND = "python -m flexarm.regenerate"


class TrajectoryError(RuntimeError):
    """The optimiser failed (infeasible, iteration limit, ...) or a file is invalid."""


class StaleTrajectoryError(TrajectoryError):
    """The trajectory was made from a parameter file that has changed since."""


@dataclass
class TrajectoryResult:
    """The optimal slew sampled every 1 ms.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Sample times 0, 1 ms, ..., t_f, s (n = t_f / 1 ms + 1).
    tau : ndarray, shape (n, 2)
        Torque held from t[k] to t[k+1], N·m (zero at t_f: the arm is left at rest).
    theta, omega : ndarray, shape (n, 11)
        Desired element angles (rad) and rates (rad/s).
    tip : ndarray, shape (n, 2)
        Tip position of the desired angles, m.
    metadata : dict
        t_f, solver statistics, discretisation, parameter file hash, line, commit, command.
    solution : CollocationSolution or None
        The optimiser's raw result (None when loaded from a file).
    """

    t: np.ndarray
    tau: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    tip: np.ndarray
    metadata: dict
    solution: object | None = None  # a flexarm.trajectory.problem.CollocationSolution (not imported: CasADi)

    @property
    def t_f(self) -> float:
        """Slew time of the file, s (a whole number of milliseconds)."""
        return float(self.t[-1])

    @property
    def n_samples(self) -> int:
        """Number of 1 ms torque steps, t_f / 1 ms."""
        return len(self.t) - 1

    def state(self, k: int) -> np.ndarray:
        """Desired state z = (θ, θ̇) at sample k, shape (22,)."""
        return np.concatenate([self.theta[k], self.omega[k]])


def _npz_arrays(result: TrajectoryResult) -> dict:
    out = {"t": result.t, "tau1": result.tau[:, 0], "tau2": result.tau[:, 1]}
    for i in range(N_ELEMENTS):
        out[f"theta{i + 1}"] = result.theta[:, i]
    for i in range(N_ELEMENTS):
        out[f"omega{i + 1}"] = result.omega[:, i]
    out["tip_x"], out["tip_y"] = result.tip[:, 0], result.tip[:, 1]
    return out


def save_trajectory(result: TrajectoryResult, path: str | os.PathLike = DEFAULT_TRAJECTORY_FILE) -> Path:
    """Write ``path`` (.npz, 1 ms samples + metadata) and its ``.json`` sidecar atomically.

    Returns
    -------
    Path
        The JSON metadata file.
    """
    path = Path(path)
    text = json.dumps(result.metadata, indent=2, sort_keys=False, default=jsonable) + "\n"
    arrays = _npz_arrays(result)
    arrays["metadata"] = np.array(text)
    write_atomic(path, lambda fh: np.savez_compressed(fh, **arrays))
    json_path = path.with_suffix(".json")
    write_sealed_json(json_path, {**result.metadata, "npz_file": path.name, "npz_sha256": sha256_file(path)})
    return json_path


def check_parameter_chain(metadata: dict, trajectory_path: str | os.PathLike,
                          parameter_file: str | os.PathLike | None = None) -> Path:
    """Refuse a trajectory whose recorded parameter SHA-256 differs from the parameter file's now.

    Parameters
    ----------
    metadata : dict
        The trajectory's metadata (``parameter_file``, ``parameter_sha256``).
    trajectory_path : path
        The trajectory file (named in the message).
    parameter_file : path, optional
        The parameter file to compare with. Default: the file named in the
        metadata, looked up next to the trajectory, then in ``flexarm/data``.

    Returns
    -------
    Path
        The parameter file that matched.

    Raises
    ------
    StaleTrajectoryError
        The checksums differ, the metadata do not record one, or the parameter file is missing;
        the message names both files and the regenerating command.
    """
    trajectory_path = Path(trajectory_path)
    recorded = metadata.get("parameter_sha256", "")
    if parameter_file is None:
        name = metadata.get("parameter_file") or DEFAULT_PARAMETER_FILE.name
        candidates = [trajectory_path.parent / name, DATA_DIR / name]
        parameter_file = next((c for c in candidates if c.exists()), candidates[-1])
    parameter_file = Path(parameter_file)
    if not parameter_file.exists():
        raise StaleTrajectoryError(f"{trajectory_path}: its parameter file {parameter_file} does not exist; "
                                   f"regenerate the chain with `{REGENERATE_COMMAND}`")
    if not recorded:
        raise StaleTrajectoryError(f"{trajectory_path} records no parameter SHA-256, so it cannot be checked "
                                   f"against {parameter_file}; regenerate the chain with `{REGENERATE_COMMAND}`")
    actual = sha256_file(parameter_file)
    if actual != recorded:
        raise StaleTrajectoryError(
            f"{trajectory_path} was made from a different version of {parameter_file} (recorded SHA-256 "
            f"{recorded[:12]}..., file now {actual[:12]}...); regenerate the chain with `{REGENERATE_COMMAND}`")
    return parameter_file


def check_npz_against_sidecar(path: str | os.PathLike, sidecar: str | os.PathLike) -> dict:
    """Check a trajectory ``.npz`` against the SHA-256 its sealed ``.json`` side file records; return the JSON.

    Raises
    ------
    StaleTrajectoryError
        The side file is missing, edited or corrupt (its seal), records no SHA-256 of the npz, or the npz's bytes
        differ from it; the message names the file and the regenerating command.
    """
    path, sidecar = Path(path), Path(sidecar)
    try:
        meta = read_sealed_json(sidecar, REGENERATE_COMMAND)
    except DataFileError as exc:
        raise StaleTrajectoryError(f"trajectory {path}: its provenance file {exc}") from exc
    recorded = meta.get("npz_sha256", "")
    actual = sha256_file(path) if path.exists() else "(missing)"
    if actual != recorded:
        raise StaleTrajectoryError(
            f"trajectory {path}: its bytes differ from the SHA-256 recorded in {sidecar.name} (file "
            f"{actual[:12]}..., recorded {recorded[:12] or '(none)'}...): edited or corrupt; regenerate it with "
            f"`{REGENERATE_COMMAND}` (or restore it from git)")
    return meta


def load_trajectory(path: str | os.PathLike = DEFAULT_TRAJECTORY_FILE,
                    parameter_file: str | os.PathLike | None | bool = None) -> TrajectoryResult:
    """Read a file written by :func:`save_trajectory` and check it against its parameter file.

    Parameters
    ----------
    path : path
        The ``.npz`` file.
    parameter_file : path, None or False
        Parameter file the trajectory must have been made from (see
        :func:`check_parameter_chain`); None: the one named in the file;
        False: skip the check (for tools that inspect old files).

    Raises
    ------
    TrajectoryError
        A key is missing or the arrays are inconsistent.
    StaleTrajectoryError
        The parameter file changed since the trajectory was made.
    """
    path = Path(path)
    sidecar = path.with_suffix(".json")
    if parameter_file is not False or sidecar.exists():
        check_npz_against_sidecar(path, sidecar)
    try:
        with np.load(path, allow_pickle=False) as data:
            try:
                t = data["t"]
                tau = np.stack([data["tau1"], data["tau2"]], axis=1)
                theta = np.stack([data[f"theta{i + 1}"] for i in range(N_ELEMENTS)], axis=1)
                omega = np.stack([data[f"omega{i + 1}"] for i in range(N_ELEMENTS)], axis=1)
                tip = np.stack([data["tip_x"], data["tip_y"]], axis=1)
                meta = json.loads(str(data["metadata"])) if "metadata" in data else {}
            except KeyError as exc:
                raise TrajectoryError(f"{path}: missing array {exc}") from exc
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise TrajectoryError(f"{path}: cannot be read ({type(exc).__name__}: {exc}); regenerate it with "
                              f"`{REGENERATE_COMMAND}`") from exc
    n = len(t)
    if any(len(a) != n for a in (tau, theta, omega, tip)) or n < 2:
        raise TrajectoryError(f"{path}: arrays of different lengths")
    if not np.allclose(np.diff(t), SAMPLE_TIME, atol=1e-12, rtol=0):
        raise TrajectoryError(f"{path}: samples are not {SAMPLE_TIME} s apart")
    if parameter_file is not False:
        check_parameter_chain(meta, path, parameter_file)
    return TrajectoryResult(t=t, tau=tau, theta=theta, omega=omega, tip=tip, metadata=meta)
