"""Gain schedules along the minimum-time trajectory: design, files, and the data-chain check.

Schedules: ``200ms`` (t = 0, 0.2, ..., the paper's tables), ``20ms`` (every
20 ms) and ``single`` (one set at mid-slew: the operating point nearest, on
average, to every point of the slew; the paper's experiment used one set
without saying where). Gain k is used on [t_k, t_k+1).

Files: ``flexarm/data/gains/<name>_<schedule>.npz`` (arrays) and ``.json``
(provenance: the trajectory and parameter files with their SHA-256, the
commit, the versions). :meth:`GainSchedule.load` refuses a schedule whose
recorded trajectory or parameter SHA-256 no longer matches the files as they
are now, naming both files and :data:`REGENERATE_COMMAND`.
"""

from __future__ import annotations

import datetime as _dt
import importlib.metadata
import os
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy

from .control_law import has_switched
from .gain_sets import DISCRETE_PREFIX, GainError, canonical_name, state_weight
from .lqr_design import DEFAULT_DT, MEASURED_VELOCITY_STATES, R_PAPER, design_gain, reduce_gain
from .model import N_STATE, ArmModel, N
from .parameters import DATA_DIR
from .provenance import (
    SOURCE_ROOT,
    DataFileError,
    git_commit,
    read_sealed_json,
    sha256_file,
    write_atomic,
    write_sealed_json,
)
from .trajectory.io import DEFAULT_TRAJECTORY_FILE, TrajectoryResult, load_trajectory
from .trajectory.io import REGENERATE_COMMAND as CHAIN_COMMAND

#: Directory of the committed gain-schedule files.
DEFAULT_GAIN_DIR = DATA_DIR / "gains"
#: Schedule labels and their spacing in s (None: one set at mid-slew).
SCHEDULES = {"200ms": 0.2, "20ms": 0.02, "single": None}
#: The controller FMUs' ``schedule_period`` (s) of each schedule: its spacing, 0 for one set.
SCHEDULE_PERIOD_PARAMETER = {label: 0.0 if spacing is None else spacing for label, spacing in SCHEDULES.items()}
#: Linearisation forms: the paper's τ̄ = 0 (eq. 11) or about the feedforward torque.
LINEARIZATIONS = ("paper", "feedforward")
FILE_FORMAT = "flexarm-gain-schedule/1"
#: The command that rebuilds every gain file (and the LQG design files) from the data.
REGENERATE_COMMAND = "python -m flexarm.lqr --write"


class StaleDataError(GainError):
    """A design file was made from a trajectory or parameter file that has changed since."""


# -- trajectory access -----------------------------------------------------------------
def load_desired(trajectory) -> tuple[TrajectoryResult, str, str]:
    """The desired trajectory, with the file it came from.

    Parameters
    ----------
    trajectory : TrajectoryResult or path-like
        A trajectory in memory, or a file read (and checked against its parameter
        file) by :func:`flexarm.trajectory.io.load_trajectory`.

    Returns
    -------
    traj : TrajectoryResult
    path, sha256 : str
        The file and its SHA-256 ('' for a trajectory in memory).
    """
    if isinstance(trajectory, TrajectoryResult):
        return trajectory, "", ""
    if isinstance(trajectory, (str, os.PathLike)):
        return load_trajectory(trajectory), str(trajectory), sha256_file(trajectory)
    raise GainError(f"trajectory: a TrajectoryResult or the path of a trajectory file, got {type(trajectory)}")


def as_trajectory(trajectory) -> TrajectoryResult:
    """:func:`load_desired` without the file."""
    return load_desired(trajectory)[0]


def desired_states(traj: TrajectoryResult) -> np.ndarray:
    """Desired states z = (θ, θ̇) at every sample, shape (n, 22)."""
    return np.hstack([traj.theta, traj.omega])


def sample_time(traj: TrajectoryResult) -> float:
    """Sample spacing of a trajectory, s."""
    return float(traj.t[1] - traj.t[0])


def trajectory_from_states(t, tau, z) -> TrajectoryResult:
    """A trajectory in memory from arrays (for tests and studies; files come from :mod:`flexarm.trajectory`).

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times from 0, uniform spacing, s.
    tau : array_like, shape (n, 2)
        Feedforward torque held over [t_k, t_k+1), N·m.
    z : array_like, shape (n, 22)
        Desired states (rad, rad/s).
    """
    t, tau, z = (np.asarray(a, dtype=float) for a in (t, tau, z))
    n = len(t)
    if t.ndim != 1 or n < 2:
        raise GainError(f"trajectory t: expected a 1-D array of >= 2 times, got shape {t.shape}")
    if tau.shape != (n, 2):
        raise GainError(f"trajectory tau: expected shape ({n}, 2), got {tau.shape}")
    if z.shape != (n, N_STATE):
        raise GainError(f"trajectory z: expected shape ({n}, {N_STATE}), got {z.shape}")
    steps = np.diff(t)
    if abs(t[0]) > 1e-12 or np.ptp(steps) > 1e-9 or steps[0] <= 0:
        raise GainError("trajectory t: must start at 0 with a uniform positive spacing")
    if not (np.isfinite(t).all() and np.isfinite(tau).all() and np.isfinite(z).all()):
        raise GainError("trajectory: contains non-finite values")
    return TrajectoryResult(t=t, tau=tau, theta=z[:, :N].copy(), omega=z[:, N:].copy(), tip=np.zeros((n, 2)),
                            metadata={})


def default_trajectory_path() -> Path:
    """The committed minimum-time trajectory, ``flexarm/data/trajectory.npz``."""
    return DEFAULT_TRAJECTORY_FILE


# -- schedules -----------------------------------------------------------------------------
def schedule_index(times, t: float) -> int:
    """Index of the schedule point in force at time t (s): point k covers [t_k, t_k+1); the first before t_0.

    `times` ascending; the rule is :func:`flexarm.control_law.has_switched` (the native FMUs' C is generated from
    it), counted over the points after the first.
    """
    return int(np.count_nonzero(has_switched(np.asarray(times, dtype=float)[1:], t)))


def operating_times(duration: float, schedule: str, dt: float = DEFAULT_DT) -> np.ndarray:
    """Operating times of a schedule, s, on the ``dt`` sample grid.

    ``200ms``/``20ms``: 0, spacing, ... up to the slew time; ``single``: the
    sample nearest mid-slew.
    """
    if schedule not in SCHEDULES:
        raise GainError(f"schedule: {schedule!r} is not one of {tuple(SCHEDULES)}")
    spacing = SCHEDULES[schedule]
    if spacing is None:
        return np.array([round(duration / 2 / dt) * dt])
    n = int(np.floor(duration / spacing + 1e-9)) + 1
    return np.round(np.arange(n) * spacing / dt) * dt


@dataclass
class GainSchedule:
    """Piecewise-constant gains along the trajectory.

    Attributes
    ----------
    name : str
        Gain-set name (e.g. ``gamma0.1``, ``dlqr-gamma0.1``).
    schedule : str
        ``200ms``, ``20ms`` or ``single``.
    times : ndarray, shape (n_sets,)
        Operating times t_k, s; gain k is used on [t_k, t_k+1), the last one
        from t_n-1 on (including the hold after the slew).
    gains : ndarray, shape (n_sets, 2, 22)
        Full-state gains K_k.
    operating_points : ndarray, shape (n_sets, 22)
        Linearisation states z̄_k.
    Q, R : ndarray
        Weights, shapes (22, 22) and (2, 2).
    residuals, rho_full, rho_reduced, rho_implemented, max_real_full, max_real_reduced : ndarray, shape (n_sets,)
        Per-set diagnostics (see :class:`GainDesign`).
    metadata : dict
        Provenance (written to the JSON side file).
    """

    name: str
    schedule: str
    times: np.ndarray
    gains: np.ndarray
    operating_points: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    residuals: np.ndarray
    rho_full: np.ndarray
    rho_reduced: np.ndarray
    rho_implemented: np.ndarray
    max_real_full: np.ndarray
    max_real_reduced: np.ndarray
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        self.times = np.atleast_1d(np.asarray(self.times, dtype=float))
        self.gains = np.asarray(self.gains, dtype=float).reshape(-1, 2, N_STATE)
        if len(self.gains) != len(self.times) or len(self.times) == 0:
            raise GainError(f"gains: expected {len(self.times)} sets of shape (2, 22), got {self.gains.shape}")
        if np.any(np.diff(self.times) <= 0):
            raise GainError("times: operating times must be strictly increasing")
        if not np.all(np.isfinite(self.gains)):
            raise GainError("gains: contain non-finite values")

    @property
    def discrete(self) -> bool:
        """True for a discrete-time (dlqr) design."""
        return self.name.startswith(DISCRETE_PREFIX)

    def index_at(self, t: float) -> int:
        """Index of the set in force at time t (s); the first set before t_0."""
        return schedule_index(self.times, t)

    def gain_at(self, t: float, reduced: bool = True) -> np.ndarray:
        """Gain in force at time t (s), shape (2, 22); ``reduced`` zeros the unmeasured velocity columns."""
        K = self.gains[self.index_at(t)]
        return reduce_gain(K) if reduced else K.copy()

    def reduced_gains(self) -> np.ndarray:
        """All sets with the nine unmeasured velocity columns zeroed, shape (n_sets, 2, 22)."""
        return reduce_gain(self.gains)

    # -- files ---------------------------------------------------------------------
    def save(self, directory=None) -> Path:
        """Write ``<name>_<schedule>.npz`` and ``.json`` atomically; returns the npz path."""
        directory = Path(directory) if directory is not None else DEFAULT_GAIN_DIR
        directory.mkdir(parents=True, exist_ok=True)
        stem = directory / f"{self.name}_{self.schedule}"  # names contain dots: no with_suffix
        arrays = dict(times=self.times, gains=self.gains, operating_points=self.operating_points, Q=self.Q,
                      R=self.R, residuals=self.residuals, rho_full=self.rho_full, rho_reduced=self.rho_reduced,
                      rho_implemented=self.rho_implemented, max_real_full=self.max_real_full,
                      max_real_reduced=self.max_real_reduced)
        return write_design_files(stem, arrays, dict(self.metadata, format=FILE_FORMAT, name=self.name,
                                                     schedule=self.schedule), compressed=False)

    @classmethod
    def load(cls, name: str, schedule: str = "200ms", directory=None) -> GainSchedule:
        """Load a committed (or written) gain schedule.

        Parameters
        ----------
        name : str
            Gain-set name (``gamma1``, ``gamma0.1``, ``gamma0``, ``eq32``,
            ``dlqr-*``, alias ``dlqr``).
        schedule : str
            ``200ms``, ``20ms`` or ``single``.
        directory : path-like, optional
            Default ``flexarm/data/gains``.
        """
        name = canonical_name(name)
        if schedule not in SCHEDULES:
            raise GainError(f"schedule: {schedule!r} is not one of {tuple(SCHEDULES)}")
        directory = Path(directory) if directory is not None else DEFAULT_GAIN_DIR
        # a folder's gains belong to the data folder around it (its trajectory.npz, when it holds the recorded one)
        meta, arrays = read_design_files(directory / f"{name}_{schedule}", "gain file", data_dir=directory.parent)
        return cls(name=name, schedule=schedule, metadata=meta, **arrays)


def design_schedule(model: ArmModel, trajectory, name: str, schedule: str = "200ms", R=R_PAPER,
                    linearization: str = "paper") -> GainSchedule:
    """Design a gain schedule along a trajectory.

    Parameters
    ----------
    model : ArmModel
        The controller's model (no payload: the payload is the model error).
    trajectory : TrajectoryResult or path-like
        See :func:`load_desired`.
    name : str
        Gain-set name (see :func:`state_weight`).
    schedule : str
        ``200ms``, ``20ms`` or ``single``.
    R : array_like, shape (2, 2)
    linearization : str
        ``paper`` (τ̄ = 0, eq. 11) or ``feedforward`` (τ̄ = τ_ff(t_k)).

    Returns
    -------
    GainSchedule
    """
    name = canonical_name(name)
    if linearization not in LINEARIZATIONS:
        raise GainError(f"linearization: {linearization!r} is not one of {LINEARIZATIONS}")
    traj, traj_path, traj_sha = load_desired(trajectory)
    z, dt = desired_states(traj), sample_time(traj)
    Q = state_weight(name)
    R = np.asarray(R, dtype=float)
    times = operating_times(traj.t_f, schedule, dt)
    idx = np.round(times / dt).astype(int)
    designs = []
    for k in idx:
        tau_bar = traj.tau[k] if linearization == "feedforward" else (0.0, 0.0)
        designs.append(design_gain(model, z[k], Q, R, tau_bar, discrete=name.startswith(DISCRETE_PREFIX), dt=dt))
    col = lambda a: np.array([getattr(d, a) for d in designs])  # noqa: E731
    meta = {
        "description": "LQR gains K (tau = tau_ff - K (x - x_d)), eqs. 17-20/32 of the paper",
        "design": "discrete-time dlqr on the ZOH model" if name.startswith(DISCRETE_PREFIX) else "continuous-time lqr",
        "solver": "control.dlqr/lqr(method='scipy') in modal frequency-scaled coordinates (flexarm.lqr)",
        "residual_definition": ("||A'P+PA-PGP+Q||_F / (||Q||_F + 2||A'P||_F + ||PGP||_F), G = B R^-1 B', "
                                "original coordinates" if not name.startswith(DISCRETE_PREFIX) else
                                "||F'PF-P-W+Q||_F/(||F'PF||_F+||P||_F+||W||_F+||Q||_F), "
                                "W = F'PG(R+G'PG)^-1 G'PF, original coordinates"),
        "linearization": ("paper: A = df/dz at z_d(t_k), tau_bar = 0 (eqs. 11-14)" if linearization == "paper"
                          else "feedforward: A = d(f+g tau_ff)/dz at (z_d(t_k), tau_ff(t_k))"),
        "sample_time_s": dt,
        "operating_times_s": times.tolist(),
        "Q_diagonal": np.diag(Q).tolist(),
        "R": R.tolist(),
        "measured_velocity_states": list(MEASURED_VELOCITY_STATES),
        "trajectory_file": relative_path(traj_path),
        "trajectory_sha256": traj_sha,
        "parameter_file": relative_path(model.params.source),
        "parameter_sha256": model.params.sha256,
        "payload_mass_kg": float(model.params.payload_mass),
        "commit": git_commit(),
        "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "versions": {"python-control": importlib.metadata.version("control"), "scipy": scipy.__version__,
                     "numpy": np.__version__},
        "max_residual": float(col("residual").max()),
        "max_abs_gain": float(np.abs(col("K")).max()),
    }
    return GainSchedule(name=name, schedule=schedule, times=times, gains=col("K"),
                        operating_points=z[idx], Q=Q, R=R, residuals=col("residual"),
                        rho_full=col("rho_full"), rho_reduced=col("rho_reduced"),
                        rho_implemented=col("rho_implemented"),
                        max_real_full=col("max_real_full"), max_real_reduced=col("max_real_reduced"),
                        metadata=meta)


def relative_path(path) -> str:
    """``path`` relative to the source root (the folder holding ``flexarm/``), absolute outside it; '' for ''."""
    if not path:
        return ""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(SOURCE_ROOT))
    except ValueError:
        return str(p)


def _resolve(recorded: str, data_dir=None, sha256: str = "") -> Path:
    """A recorded path (:func:`relative_path`) as a file: ``flexarm/...`` is this package's own folder, whatever
    the package is called (inside an FMU it is bundled under a private name, see fmu_build/isolate.py).

    `data_dir`: the data folder the design belongs to (a data set written elsewhere, e.g. a slew re-planned for a
    payload with its gains, :mod:`flexarm.payload_data`). ``flexarm/data/X`` is then that folder's X when it has
    one whose SHA-256 is the recorded `sha256`, else the package's: the checksum decides which file a design was
    made from, never the folder alone.
    """
    p = Path(recorded)
    if p.is_absolute():
        return p
    if p.parts[:1] == ("flexarm",):
        own = Path(__file__).resolve().parent.joinpath(*p.parts[1:])
        if data_dir is not None and p.parts[1:2] == ("data",):
            local = Path(data_dir).joinpath(*p.parts[2:])
            if local.exists() and (not sha256 or sha256_file(local) == sha256 or not own.exists()
                                   or sha256_file(own) != sha256):
                return local
        return own
    return SOURCE_ROOT / p


def write_design_files(stem, arrays: dict, metadata: dict, compressed: bool = True) -> Path:
    """Write a design file pair atomically: ``<stem>.npz`` (the arrays), then ``<stem>.json`` (the metadata
    plus the npz's name and SHA-256, which :func:`read_design_metadata` checks); returns the npz path.

    Parameters
    ----------
    stem : path-like
        The files' path without suffix (names may contain dots).
    arrays : dict of str to ndarray
    metadata : dict
        JSON-serialisable.
    compressed : bool
        ``np.savez_compressed`` or ``np.savez``.
    """
    npz_path = Path(f"{stem}.npz")
    save = np.savez_compressed if compressed else np.savez
    write_atomic(npz_path, lambda f: save(f, **arrays))
    meta = dict(metadata, npz_file=npz_path.name, npz_sha256=sha256_file(npz_path))
    write_sealed_json(Path(f"{stem}.json"), meta)  # sealed: an edit of the JSON itself is found too
    return npz_path


def read_design_files(stem, what: str, regenerate: str | None = None, data_dir=None) -> tuple[dict, dict]:
    """Read a design file pair written by :func:`write_design_files`: (metadata, arrays by name).

    Parameters
    ----------
    stem : path-like
        The files' path without suffix.
    what : str
        What the file is, for the message (``gain file``, ``LQG design file``, ...).

    regenerate : str, optional
        The command that writes this file, named in the errors (default :data:`REGENERATE_COMMAND`, the gains').
    data_dir : path-like, optional
        The data folder the design belongs to (see :func:`read_design_metadata`).

    Raises
    ------
    GainError
        If ``<stem>.npz`` does not exist (naming :data:`REGENERATE_COMMAND`).
    StaleDataError
        As :func:`read_design_metadata`.
    """
    npz_path = Path(f"{stem}.npz")
    if not npz_path.exists():
        raise GainError(f"{what} {npz_path} does not exist; run `{regenerate or REGENERATE_COMMAND}`")
    meta = read_design_metadata(Path(f"{stem}.json"), npz_path, regenerate, data_dir)
    try:
        with np.load(npz_path, allow_pickle=False) as d:
            return meta, {k: d[k] for k in d.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise StaleDataError(f"{what} {npz_path}: cannot be read ({type(exc).__name__}: {exc}); regenerate it "
                             f"with `{regenerate or REGENERATE_COMMAND}`") from exc


def read_design_metadata(json_path, data_path, regenerate: str | None = None, data_dir=None) -> dict:
    """Read a design file's JSON side file and verify the data chain behind it.

    Checks, against the files as they are now: the SHA-256 of ``data_path``
    (the arrays the JSON describes) and of the trajectory and parameter files the
    design was made from (``trajectory_file``/``trajectory_sha256``,
    ``parameter_file``/``parameter_sha256``; a design made from in-memory data
    records no file and is not checked for it).

    Parameters
    ----------
    json_path, data_path : path-like
        The ``.json`` side file and the ``.npz`` it describes.
    regenerate : str, optional
        The command that writes this file (default :data:`REGENERATE_COMMAND`, the gains', with the whole chain's
        :data:`CHAIN_COMMAND` for a changed parameter file).
    data_dir : path-like, optional
        The data folder the design belongs to: a recorded ``flexarm/data/X`` is that folder's X when its SHA-256 is
        the recorded one (a data set outside the package, :mod:`flexarm.payload_data`), else the package's.

    Returns
    -------
    dict
        The metadata.

    Raises
    ------
    StaleDataError
        Naming the design file, the trajectory and parameter files and
        :data:`REGENERATE_COMMAND`, when a recorded SHA-256 does not match (or
        the side file or a recorded input is missing).
    """
    json_path, data_path = Path(json_path), Path(data_path)
    command = regenerate or REGENERATE_COMMAND
    if not json_path.exists():
        raise StaleDataError(f"design file {data_path}: its provenance file {json_path} is missing; "
                             f"regenerate with `{command}`")
    try:
        meta = read_sealed_json(json_path, command)
    except DataFileError as exc:
        raise StaleDataError(f"design file {data_path}: its provenance file {exc}") from exc
    problems = []
    if not meta.get("npz_sha256"):
        problems.append(f"{json_path.name} records no SHA-256 of {data_path.name}")
    elif sha256_file(data_path) != meta["npz_sha256"]:
        problems.append(f"{data_path.name} differs from the SHA-256 recorded in {json_path.name}")
    for kind in ("trajectory", "parameter"):
        recorded, sha = meta.get(f"{kind}_file", ""), meta.get(f"{kind}_sha256", "")
        if not recorded or not sha:
            continue
        path = _resolve(recorded, data_dir, sha)
        if not path.exists():
            problems.append(f"the {kind} file {path} it was made from does not exist")
        elif sha256_file(path) != sha:
            problems.append(f"the {kind} file {path} has changed since (SHA-256 {sha256_file(path)[:12]}..., "
                            f"recorded {sha[:12]}...)")
    if problems:
        traj = (_resolve(meta["trajectory_file"], data_dir, meta.get("trajectory_sha256", ""))
                if meta.get("trajectory_file") else "(in memory)")
        par = (_resolve(meta["parameter_file"], data_dir, meta.get("parameter_sha256", ""))
               if meta.get("parameter_file") else "(in memory)")
        raise StaleDataError(f"design file {data_path} is stale: " + "; ".join(problems)
                             + f". It was made from trajectory file {traj} and parameter file {par}; "
                             f"regenerate it with `{command}`"
                             + ("" if regenerate else f" (if the parameter file changed, the whole chain: "
                                                      f"`{CHAIN_COMMAND}`)"))
    return meta

