"""Provenance and safe file writing: one place for the commit, checksums and atomic writes.

Every file the project writes (parameter files, trajectories, gain schedules, results, sweep journals)
goes through :func:`write_atomic`, so a reader never sees half a file, and records :func:`git_commit`
and the :func:`sha256_file` of what it was made from.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import numpy as np

SOURCE_ROOT = Path(__file__).resolve().parent.parent


#: Written by setup.py into a built (non-editable) package: the commit it was built from.
BUILD_COMMIT_FILE = Path(__file__).with_name("_build_commit.txt")


def git_commit(root: str | Path = SOURCE_ROOT) -> str:
    """The commit of this code: HEAD of its checkout, with '+dirty' when tracked files differ.

    Asked of git only when `root` is the top of a git checkout (not a folder inside another repository,
    e.g. a venv in a user's project). An installed package answers with the commit baked in at build time
    (:data:`BUILD_COMMIT_FILE`, by setup.py); 'unknown' when neither is there.
    """
    root = Path(root).resolve()
    try:
        top = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=root, capture_output=True, text=True,
                             check=True, timeout=10).stdout.strip()
        if Path(top).resolve() != root:
            raise subprocess.SubprocessError(f"{root} is inside the checkout {top}, not its top")
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                              check=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, check=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        if root == SOURCE_ROOT.resolve() and BUILD_COMMIT_FILE.is_file():
            return BUILD_COMMIT_FILE.read_text().strip() or "unknown"
        return "unknown"
    return head + ("+dirty" if dirty else "")


def package_version() -> str:
    """The installed distribution's version (flexarm-fmi), else the source's ``flexarm.__version__``."""
    import importlib.metadata

    try:
        return importlib.metadata.version("flexarm-fmi")
    except importlib.metadata.PackageNotFoundError:
        from . import __version__

        return __version__


def sha256_bytes(data: bytes) -> str:
    """Hex SHA-256 of ``data``."""
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | Path) -> str:
    """Hex SHA-256 of the file at ``path``, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def write_atomic(path: str | Path, data: bytes | str | Callable[[BinaryIO], object]) -> Path:
    """Write ``path`` through a temporary file in the same folder, fsync, then rename over it.

    Parameters
    ----------
    path : str or Path
        Destination; its folder is created if missing.
    data : bytes, str or callable
        The content (str is written as UTF-8), or a function that writes into the open binary file.

    Returns
    -------
    Path
        ``path``. The file is readable by everyone (mode 0666 less the umask), as results are for sharing.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            if callable(data):
                data(f)
            else:
                f.write(data if isinstance(data, bytes) else data.encode())
            f.flush()
            os.fsync(f.fileno())  # the data is on disk before the name points at it
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def jsonable(x):
    """``json.dumps(default=...)`` hook: NumPy scalars and arrays, paths."""
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON serialisable: {type(x)}")


def write_json(path: str | Path, obj) -> Path:
    """Write ``obj`` as indented JSON, atomically (see :func:`write_atomic`)."""
    return write_atomic(path, json.dumps(obj, indent=2, default=jsonable) + "\n")
