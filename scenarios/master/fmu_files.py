"""FMU files on disk: reading a model description with a clear refusal, and where FMUs are unpacked.

Every process unpacks into its own folder under ``<temp>/flexarm-fmus/`` and holds an ``flock`` on a
file inside it for as long as it lives. The folder is removed when the process exits (``atexit``, and
:meth:`scenarios.master.cosim.Master.close` removes each FMU's files as it frees it); a folder whose lock no
process holds any more was left by a killed run, and the next process that unpacks an FMU removes it.
"""

from __future__ import annotations

import atexit
import fcntl
import os
import shutil
import tempfile
import time
import zipfile
from pathlib import Path

from fmpy import extract, platform, read_model_description

#: Environment variable: the folder under which ``flexarm-fmus/`` is made (default: the system temp folder).
UNPACK_ENV = "FLEXARM_UNPACK_DIR"
_LOCK = ".owner.lock"
_OWN: dict = {}


class NotAnFmuError(ValueError):
    """A file that should be an FMU is missing, not a zip archive, or has no readable modelDescription.xml."""


def read_description(path: str | os.PathLike):
    """fmpy's model description of the FMU at `path`, or :class:`NotAnFmuError` naming the file and why.

    Parsed once per process and file version: a run reads each FMU's description in planning and again when it
    loads the FMU (issue 34: start-up). The cache key is the file's identity and modification (device, inode,
    size, mtime in ns), which change whenever the file is rewritten or replaced; callers must not change the
    returned object.
    """
    path = Path(path)
    if not path.is_file():
        raise NotAnFmuError(f"{path}: no such FMU file")
    st = path.stat()
    key = (str(path.resolve()), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    if key not in _DESCRIPTIONS:
        if len(_DESCRIPTIONS) >= _KEEP_DESCRIPTIONS:  # a long test process reads hundreds of FMU versions
            del _DESCRIPTIONS[next(iter(_DESCRIPTIONS))]
        _DESCRIPTIONS[key] = _parse_description(path)
    return _DESCRIPTIONS[key]


_DESCRIPTIONS: dict = {}
_KEEP_DESCRIPTIONS = 32


def _parse_description(path: Path):
    try:
        with zipfile.ZipFile(path) as archive:
            if "modelDescription.xml" not in archive.namelist():
                raise NotAnFmuError(f"{path}: not an FMU (a zip archive without modelDescription.xml)")
        return read_model_description(str(path))
    except zipfile.BadZipFile as exc:
        raise NotAnFmuError(f"{path}: not an FMU (not a zip archive: {exc})") from exc
    except NotAnFmuError:
        raise
    except Exception as exc:  # noqa: BLE001 - lxml and fmpy raise many kinds for a broken description
        raise NotAnFmuError(f"{path}: not an FMU (modelDescription.xml unreadable: {exc})") from exc


def unpack_root() -> Path:
    """The folder holding every process's unpack folder."""
    return Path(os.environ.get(UNPACK_ENV) or tempfile.gettempdir()) / "flexarm-fmus"


def remove_stale(root: Path | None = None, min_age_s: float = 60.0) -> list[Path]:
    """Remove the unpack folders of processes that are gone (their lock is free); returns them.

    A folder without a lock file is removed only when older than `min_age_s` (it may be being made).
    """
    root = unpack_root() if root is None else Path(root)
    removed = []
    if not root.is_dir():
        return removed
    for folder in root.iterdir():
        if not folder.is_dir() or folder.name.startswith("."):
            continue
        try:
            fd = os.open(folder / _LOCK, os.O_RDWR)
        except PermissionError:
            continue  # another user's: not ours to judge
        except FileNotFoundError:
            try:
                old = time.time() - folder.stat().st_mtime > min_age_s
            except FileNotFoundError:
                continue
            if old:
                shutil.rmtree(folder, ignore_errors=True)
                removed.append(folder)
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            continue  # its process is alive
        finally:
            os.close(fd)  # closing also drops a lock we took
        shutil.rmtree(folder, ignore_errors=True)
        removed.append(folder)
    return removed


def process_folder() -> Path:
    """This process's unpack folder (made, locked and registered for removal on first use)."""
    pid = os.getpid()
    if _OWN.get("pid") == pid and _OWN["folder"].is_dir():
        return _OWN["folder"]
    root = unpack_root()
    root.mkdir(parents=True, exist_ok=True)
    remove_stale(root)
    # made under a dot name (which remove_stale skips), locked, then renamed: never seen unlocked
    new = Path(tempfile.mkdtemp(prefix=f".{pid}-", dir=root))
    fd = os.open(new / _LOCK, os.O_CREAT | os.O_RDWR, 0o600)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    folder = root / new.name[1:]
    os.rename(new, folder)
    _OWN.update(pid=pid, folder=folder, fd=fd)
    atexit.register(_remove_own, pid)
    return folder


def _remove_own(pid: int) -> None:
    if _OWN.get("pid") != pid or os.getpid() != pid:
        return  # a forked child: the folder is its parent's
    shutil.rmtree(_OWN["folder"], ignore_errors=True)
    os.close(_OWN.pop("fd"))
    _OWN.clear()


def needed_at_run_time(member: str) -> bool:
    """Whether an FMU archive's `member` is one a running FMU may read: its model description, its resources
    and this platform's binaries (FMI 2.0.5, 2.4: the layout of the archive). Sources, documentation and other
    platforms' binaries are not unpacked: a native FMU's 110 source and foreign binary files were most of
    the 0.14 s three FMUs took to unpack before every run (issue 34: start-up)."""
    return (member == "modelDescription.xml" or member.startswith("resources/")
            or member.startswith(f"binaries/{platform}/"))


def unpack(path: str | os.PathLike) -> Path:
    """Unpack what a running FMU needs (:func:`needed_at_run_time`) of the FMU at `path` into a new folder
    inside :func:`process_folder`; returns the folder."""
    folder = Path(tempfile.mkdtemp(prefix=f"{Path(path).stem}-", dir=process_folder()))
    try:
        extract(str(path), unzipdir=str(folder), include=needed_at_run_time)
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    return folder
