"""Provenance and safe file writing: one place for the commit, checksums and atomic writes.

Every file the project writes (parameter files, trajectories, gain schedules, results, sweep journals)
goes through :func:`write_atomic`, so a reader never sees half a file, and records :func:`git_commit`
and the :func:`sha256_file` of what it was made from.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import json
import os
import re
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import numpy as np

SOURCE_ROOT = Path(__file__).resolve().parent.parent


#: Written by setup.py into a built (non-editable) package: the commit it was built from.
BUILD_COMMIT_FILE = Path(__file__).with_name("_build_commit.txt")


def checkout_refusal(command: str, writes: str, root: str | Path = SOURCE_ROOT) -> str | None:
    """The refusal of a command that rewrites committed files when `root` is no checkout, else None.

    A checkout has ``build_fmus.py`` beside the packages; an installed package (``pip install .``) has not,
    and a command that rewrote ``docs/`` or ``flexarm/data`` there would write into site-packages.

    Parameters
    ----------
    command : str
        The command as the user typed it (``python -m flexarm.lqr --write``).
    writes : str
        What it rewrites (``the gain files in flexarm/data/gains``).
    """
    if (Path(root) / "build_fmus.py").is_file():
        return None
    return (f"{command} rewrites {writes} of a checkout of flexarm-fmi, and {root} is none (an installed "
            "package): run it in a clone of the repository")


def refuse_outside_checkout(command: str, writes: str, root: str | Path = SOURCE_ROOT) -> bool:
    """Print :func:`checkout_refusal`'s message to stderr and return True when `root` is no checkout (the
    command then exits 2); False in a checkout."""
    refusal = checkout_refusal(command, writes, root)
    if refusal:
        print(f"error: {refusal}", file=sys.stderr)
    return refusal is not None


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


#: Inside :func:`sha256_memo`: (path, device, inode, size, mtime_ns) -> digest; None outside.
_SHA256_MEMO: contextvars.ContextVar[dict | None] = contextvars.ContextVar("flexarm_sha256_memo", default=None)


def sha256_file(path: str | Path) -> str:
    """Hex SHA-256 of the file at ``path``, read in 1 MiB chunks (once per file inside :func:`sha256_memo`)."""
    memo = _SHA256_MEMO.get()
    if memo is not None:
        st = os.stat(path)
        key = (os.fspath(path), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
        if key not in memo:
            memo[key] = _sha256_of(path)
        return memo[key]
    return _sha256_of(path)


def _sha256_of(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


@contextlib.contextmanager
def sha256_memo():
    """Within the block, :func:`sha256_file` hashes each file once (a file replaced meanwhile, by its stat: again).

    For one verification that meets the same inputs many times: every design file's record names the trajectory
    and the parameter file it was made from, so checking the data chain hashed them once per record (24 MB for
    6 MB of data, :func:`flexarm.data_chain.verify_data_files`). Scoped, never process-wide: a file rewritten
    with the same size within the file system's timestamp granularity could otherwise keep an old digest.
    """
    token = _SHA256_MEMO.set({})
    try:
        yield
    finally:
        _SHA256_MEMO.reset(token)


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


# -- sealed JSON: a provenance file that carries the SHA-256 of its own bytes ------------------------------------
#: The key of the seal; always the last one of the file.
SEAL_KEY = "json_sha256"
_SEAL_PLACEHOLDER = "0" * 64
_SEAL_RE = re.compile(rb'"json_sha256": "([0-9a-f]{64})"')


class DataFileError(ValueError):
    """A data file is corrupt, edited by hand or unreadable (the message names it and what to do)."""


def sealed_json_text(obj: dict) -> str:
    """``obj`` as indented JSON whose last key, :data:`SEAL_KEY`, is the SHA-256 of the file's own bytes.

    The digest is taken over the text with the digest written as 64 zeros, so any change of any byte of the file
    (a value edited by hand, a flipped bit) is found by :func:`read_sealed_json`.
    """
    body = {k: v for k, v in obj.items() if k != SEAL_KEY}
    text = json.dumps({**body, SEAL_KEY: _SEAL_PLACEHOLDER}, indent=2, default=jsonable) + "\n"
    return text.replace(f'"{SEAL_KEY}": "{_SEAL_PLACEHOLDER}"', f'"{SEAL_KEY}": "{sha256_bytes(text.encode())}"')


def write_sealed_json(path: str | Path, obj: dict) -> Path:
    """Write ``obj`` with its seal (:func:`sealed_json_text`), atomically."""
    return write_atomic(path, sealed_json_text(obj))


def read_sealed_json(path: str | Path, regenerate: str) -> dict:
    """Read a JSON provenance file written by :func:`write_sealed_json` and check its seal.

    Parameters
    ----------
    path : path-like
    regenerate : str
        The command that rewrites the file, for the message.

    Returns
    -------
    dict
        The content, without the seal.

    Raises
    ------
    DataFileError
        The file is missing, unreadable, not JSON, has no seal or its bytes differ from the sealed ones.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataFileError(f"{path}: cannot be read ({exc.strerror or exc}); regenerate it with "
                            f"`{regenerate}`") from exc
    seals = _SEAL_RE.findall(raw)
    if len(seals) != 1:
        raise DataFileError(f"{path}: carries no seal ({SEAL_KEY}, the SHA-256 of its own bytes), so an edit "
                            f"cannot be told from the file as written; regenerate it with `{regenerate}`")
    seal = seals[0].decode()
    unsealed = raw.replace(f'"{SEAL_KEY}": "{seal}"'.encode(), f'"{SEAL_KEY}": "{_SEAL_PLACEHOLDER}"'.encode())
    if sha256_bytes(unsealed) != seal:
        raise DataFileError(f"{path}: its bytes differ from the ones it was written with ({SEAL_KEY} "
                            f"{seal[:12]}... does not match): edited or corrupt; regenerate it with "
                            f"`{regenerate}` (or restore it from git)")
    try:
        obj = json.loads(raw)
    except ValueError as exc:  # unreachable for a sealed file, kept for a clear message
        raise DataFileError(f"{path}: not JSON ({exc}); regenerate it with `{regenerate}`") from exc
    if not isinstance(obj, dict):
        raise DataFileError(f"{path}: not a JSON object; regenerate it with `{regenerate}`")
    obj.pop(SEAL_KEY, None)
    return obj
