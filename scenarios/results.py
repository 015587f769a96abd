"""Result files: time series as CSV; provenance and atomic writes come from :mod:`flexarm.provenance`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from flexarm.provenance import git_commit, sha256_file, write_atomic, write_json

__all__ = ["git_commit", "sha256_file", "write_atomic", "write_json", "write_csv"]

REPO = Path(__file__).resolve().parent.parent


def write_csv(path: str | Path, columns: dict[str, np.ndarray]) -> None:
    """Time series as CSV (one column per signal, full float precision)."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    lines = [",".join(names)]
    lines += [",".join(repr(float(x)) for x in row) for row in data]
    write_atomic(path, "\n".join(lines) + "\n")
