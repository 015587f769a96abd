"""Output folders: one run at a time per folder, checked before any case runs, published whole.

A scenario run writes into ``OUT/.<name>.partial-XXXX/`` and, when every case is done, moves the
previous ``OUT/<name>/`` aside and renames the new folder into its place, so the folder never mixes
files of two runs and an interrupted or failed run leaves the previous results as they were. A sweep
keeps its folder (its journal is what a rerun resumes from) and only removes what it regenerates.

``OUT/.<name>.lock`` is held (``flock``) for the whole run: a second run into the same folder is refused
at once. The lock dies with its process, so a killed run leaves no stale lock; the partial folders and
``.*.tmp`` files a killed run leaves are removed by the next run into the folder.
"""

from __future__ import annotations

import errno
import fcntl
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

#: errno values that mean "this folder cannot take our files" (reported in one line, exit code 3).
WRITE_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOTDIR, errno.EEXIST,
                errno.ENOENT, errno.EISDIR, errno.EFBIG)


class OutputError(RuntimeError):
    """The results folder cannot be used: another run holds it, or it cannot be written."""


class FolderBusy(OutputError):
    """Another run is writing into the same results folder."""


def describe_os_error(exc: OSError) -> str:
    """One line for a filesystem error: what failed and where."""
    where = exc.filename or ""
    return f"{where}: {exc.strerror or exc}" if where else str(exc.strerror or exc)


def check_folder_name(name: str) -> str:
    """`name` if it is one plain path component (the scenario and sweep loaders allow only identifiers; this
    is the last line for any caller): no separator, NUL or leading dot, not ``..``; else OutputError."""
    if (not isinstance(name, str) or not name or name.startswith(".") or "/" in name or "\\" in name
            or any(ord(ch) < 32 for ch in name) or name in (".", "..")):
        raise OutputError(f"output folder name {name!r}: must be one plain name (letters, digits, _, -; no '/', "
                          f"'\\', NUL or leading '.'), so that nothing outside the results folder is written")
    return name


@contextmanager
def folder_lock(out: Path, name: str):
    """Hold ``out/.<name>.lock`` for the block; :class:`FolderBusy` when another process holds it."""
    path = out / f".{check_folder_name(name)}.lock"
    try:
        fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o666)
    except OSError as exc:
        raise OutputError(f"results folder {out}: cannot be written ({describe_os_error(exc)})") from exc
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "another process"
            raise FolderBusy(f"results folder {out / name}: another run (pid {holder}) is writing into it; "
                             "wait for it to finish or choose another --out") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield path
    finally:
        os.close(fd)  # releases the lock


def remove_stale(out: Path, name: str, folder: Path | None = None) -> list[Path]:
    """Partial folders of killed runs (``out/.<name>.partial-*``, ``.old-*``) and ``.*.tmp`` files left by
    interrupted atomic writes in `folder`. Only call while holding :func:`folder_lock`."""
    removed = []
    for p in list(out.glob(f".{name}.partial-*")) + list(out.glob(f".{name}.old-*")):
        shutil.rmtree(p, ignore_errors=True)
        removed.append(p)
    if folder is not None and folder.is_dir():
        for p in folder.glob(".*.tmp"):
            p.unlink(missing_ok=True)
            removed.append(p)
    return removed


def check_writable(folder: Path, need_bytes: int = 0) -> None:
    """Write, fsync and remove a probe file in `folder`, and check `need_bytes` are free: :class:`OutputError`."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".write-probe.", suffix=".tmp")
        try:
            os.write(fd, b"\0" * 4096)
            os.fsync(fd)
        finally:
            os.close(fd)
            os.unlink(probe)
        free = shutil.disk_usage(folder).free
    except OSError as exc:
        raise OutputError(f"results folder {folder}: cannot be written ({describe_os_error(exc)})") from exc
    if free < need_bytes:
        raise OutputError(f"results folder {folder}: {free / 1e6:.1f} MB free, the run needs about "
                          f"{need_bytes / 1e6:.1f} MB")


@contextmanager
def run_folder(out_dir: Path, name: str, need_bytes: int = 0):
    """A fresh, locked, writable staging folder; published as ``out_dir/<name>`` when the block succeeds.

    On any exception (Ctrl-C included) the staging folder is removed and ``out_dir/<name>`` is untouched.
    """
    out = Path(out_dir)
    check_folder_name(name)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"results folder {out}: cannot be created ({describe_os_error(exc)})") from exc
    with folder_lock(out, name):
        remove_stale(out, name)
        check_writable(out, need_bytes)
        staging = Path(tempfile.mkdtemp(prefix=f".{name}.partial-", dir=out))
        try:
            yield staging
            final = out / name
            old = None
            if final.exists():
                old = Path(tempfile.mkdtemp(prefix=f".{name}.old-", dir=out))
                os.rename(final, old / name)
            os.rename(staging, final)
            os.chmod(final, 0o777 & ~_umask())  # mkdtemp makes 0700; results are for sharing
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
