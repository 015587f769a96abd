"""Result files: time series as CSV (provenance and atomic writes: :mod:`flexarm.provenance`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from flexarm.provenance import write_atomic


def write_csv(path: str | Path, columns: dict[str, np.ndarray]) -> None:
    """Time series as CSV (one column per signal, full float precision), written atomically."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    lines = [",".join(names)]
    lines += [",".join(repr(float(x)) for x in row) for row in data]
    write_atomic(path, "\n".join(lines) + "\n")
