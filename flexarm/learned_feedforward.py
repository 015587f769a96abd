"""Learned feedforward files (:mod:`flexarm.ilc`): write, read and check them, without the learning.

Kept apart from :mod:`flexarm.ilc` so that a controller FMU, which only reads such a file, does not import the
learning's SciPy modules (``scipy.signal`` alone costs about half a second of CPU at start-up, issue 34).
:mod:`flexarm.ilc` re-exports every name here.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .gain_schedule import read_design_files, relative_path, write_design_files
from .gain_sets import GainError
from .provenance import git_commit

FILE_FORMAT = "flexarm-learned-feedforward/1"
#: A learned correction inside a controller FMU: ``resources/<this>`` and its ``.json`` beside it (both kinds read
#: it at every initialisation; none without the file).
LEARNED_RESOURCE = "learned_feedforward.npz"
#: How a learned-feedforward file is written anew (named when one is stale or unreadable).
RELEARN_COMMAND = "python -m scenarios run ilc_payload (or the ILC scenario its .json names under 'scenario')"


class IlcError(ValueError):
    """An ILC setting, measurement or learned-feedforward file is invalid."""


@dataclass
class LearnedFeedforward:
    """A learned feedforward correction with its provenance.

    Attributes
    ----------
    correction : ndarray, shape (n, 2)
        Added to the feedforward torque of samples 0..n−1 (N·m); zero after.
    dt : float
        Sample time, s.
    metadata : dict
        Provenance (trajectory, parameters, gains, ILC weights, trials).
    """

    correction: np.ndarray
    dt: float
    metadata: dict = field(default_factory=dict)


def write_learned_feedforward(stem, correction, dt: float, metadata: dict) -> Path:
    """Write ``<stem>.npz`` (``correction`` (n, 2) N·m, ``dt`` s) and ``<stem>.json`` (provenance) atomically.

    `metadata` should carry ``trajectory_file``/``trajectory_sha256`` and ``parameter_file``/``parameter_sha256``
    (checked when read), the gain set, the ILC weights and the trials; the format, commit and time are added.
    """
    u = np.asarray(correction, dtype=float)
    if u.ndim != 2 or u.shape[1] != 2 or len(u) < 1 or not np.isfinite(u).all():
        raise IlcError(f"correction: expected finite values of shape (n, 2) N·m, got shape {u.shape}")
    meta = dict(metadata, format=FILE_FORMAT, samples=len(u), sample_time_s=float(dt),
                description="feedforward correction learned by norm-optimal ILC (flexarm.ilc); added to the "
                            "trajectory's feedforward torque of sample k (N.m) for k < samples",
                commit=metadata.get("commit") or git_commit(),
                created_utc=_dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"))
    for key in ("trajectory_file", "parameter_file"):
        if meta.get(key):
            meta[key] = relative_path(meta[key])
    return write_design_files(stem, {"correction": u, "dt": np.array(float(dt))}, meta, compressed=False)


def read_learned_feedforward(path, data_dir=None) -> LearnedFeedforward:
    """Read a learned-feedforward file (``.npz`` path, or its stem), checking its data chain.

    `data_dir`: the data folder of the slew it was learnt on, when that is not the package's (a slew re-planned
    for a payload, :mod:`flexarm.payload_data`; see :func:`flexarm.gain_schedule.read_design_metadata`).

    Raises
    ------
    IlcError
        Not a learned-feedforward file, or malformed.
    flexarm.gain_schedule.StaleDataError
        The file, or the trajectory or parameter file it was learned on, changed since.
    """
    p = Path(path)
    stem = p.with_suffix("") if p.suffix == ".npz" else p
    try:
        meta, arrays = read_design_files(stem, "learned-feedforward file", RELEARN_COMMAND, data_dir)
    except GainError:
        raise
    except (OSError, ValueError, KeyError) as exc:
        raise IlcError(f"learned-feedforward file {p}: cannot be read: {type(exc).__name__}: {exc}") from exc
    if meta.get("format") != FILE_FORMAT or "correction" not in arrays:
        raise IlcError(f"learned-feedforward file {p}: format {meta.get('format')!r}, expected {FILE_FORMAT!r} "
                       "with an array 'correction'")
    u = np.asarray(arrays["correction"], dtype=float)
    if u.ndim != 2 or u.shape[1] != 2 or not np.isfinite(u).all():
        raise IlcError(f"learned-feedforward file {p}: correction must be finite, shape (n, 2); got {u.shape}")
    return LearnedFeedforward(correction=u, dt=float(arrays["dt"]), metadata=meta)
