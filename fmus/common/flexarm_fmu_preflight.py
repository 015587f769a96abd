"""Start-up check of an FMU, run by its C front end before pythonfmu loads the slave (and by the build).

The front end runs this file with :func:`runpy.run_path` (not an import: a copy
cached from another FMU must not answer for this one) and calls
:func:`preflight` with the FMU's resources folder. An empty string means the FMU
can start; anything else is the whole error message, which the front end logs
with status ``fmi2Error`` before ``fmi2Instantiate`` returns NULL. It says what
is missing and how to provide it:

* a bundled data file missing, or different from the SHA-256 recorded in
  ``flexarm_bundle.json`` at build time;
* a data file whose recorded inputs no longer match (the SHA-256 chain: gain
  files record the trajectory and parameter file they were designed for, the
  trajectory records its parameter file), naming both files and the command
  that regenerates the stale one;
* a Python module that does not import (NumPy, SciPy: ``PYTHONPATH``).

:func:`data_chain_problems` is also what ``fmu_build`` runs over the project's
data before it bundles anything. Standard library only.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import os
import sys
import traceback
from pathlib import Path

#: File in the FMU's resources describing the bundled sources (written by fmu_build).
BUNDLE_MANIFEST = "flexarm_bundle.json"
#: Command that regenerates each kind of data file (relative to flexarm/data).
REGENERATE = {
    "trajectory": "python -m flexarm.trajectory",
    "gains": "python -m flexarm.lqr --write",
    "sandia_arm.toml": "python -m flexarm.calibration",
}
REBUILD = "python build_fmus.py --force"


def _regenerate(rel: str) -> str:
    if rel.startswith("gains/"):
        return REGENERATE["gains"]
    if rel.startswith("trajectory."):
        return REGENERATE["trajectory"]
    return REGENERATE.get(rel, "the command named in its provenance")


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def bundle_files(package_dir: Path) -> list[Path]:
    """Files of a package that go into an FMU: no caches, compiled files or hidden files."""
    out = []
    for p in sorted(Path(package_dir).rglob("*")):
        rel = p.relative_to(package_dir).parts
        if p.is_file() and "__pycache__" not in rel and not any(s.startswith(".") for s in rel) \
                and p.suffix not in (".pyc", ".pyo", ".tmp"):
            out.append(p)
    return out


def tree_sha256(package_dir: Path, files: list[str] | None = None) -> str:
    """SHA-256 over :func:`bundle_files` (relative path and content): identifies a copy of a package.

    `files` (relative paths) restricts it to those files, e.g. the ones an FMU bundles; a missing
    one changes the digest.
    """
    package_dir = Path(package_dir)
    rels = [f.relative_to(package_dir).as_posix() for f in bundle_files(package_dir)] if files is None else files
    h = hashlib.sha256()
    for rel in rels:
        f = package_dir / rel
        h.update(rel.encode() + b"\0" + (f.read_bytes() if f.is_file() else b"(missing)") + b"\0")
    return h.hexdigest()


def data_chain_problems(data_dir: Path, files: list[str] | None = None) -> list[str]:
    """Where a data file's recorded SHA-256 of an input file does not match that file.

    Parameters
    ----------
    data_dir : Path
        A ``flexarm/data`` folder.
    files : list of str, optional
        Only the records held by these files (relative paths); default all.

    Returns
    -------
    list of str
        One message per broken link, naming both files and the regenerating command.
    """
    data_dir = Path(data_dir)
    problems = []
    hashes: dict[str, str] = {}

    def digest(rel: str) -> str | None:
        if rel not in hashes:
            p = data_dir / rel
            hashes[rel] = sha256(p) if p.is_file() else None
        return hashes[rel]

    records = []  # (recording file, key, recorded sha, input file)
    for js in sorted(data_dir.glob("gains/*.json")):
        rel = js.relative_to(data_dir).as_posix()
        if files is not None and rel not in files:
            continue
        meta = json.loads(js.read_text())
        if "trajectory_sha256" in meta:
            records.append((rel, "trajectory_sha256", meta["trajectory_sha256"], "trajectory.npz"))
        if "parameter_sha256" in meta:
            records.append((rel, "parameter_sha256", meta["parameter_sha256"],
                            Path(meta.get("parameter_file", "sandia_arm.toml")).name))
    traj_meta = data_dir / "trajectory.json"
    if traj_meta.is_file() and (files is None or "trajectory.json" in files):
        meta = json.loads(traj_meta.read_text())
        if "parameter_sha256" in meta:
            records.append(("trajectory.json", "parameter_sha256", meta["parameter_sha256"],
                            Path(meta.get("parameter_file", "sandia_arm.toml")).name))
    for rel, key, recorded, target in records:
        actual = digest(target)
        if actual is None and files is not None and target not in files:
            continue  # an input this FMU does not carry (checked where it is bundled)
        if actual != recorded:
            problems.append(
                f"flexarm/data/{rel} records {key} {recorded[:12]}... for flexarm/data/{target}, which "
                f"{'is missing' if actual is None else f'has {actual[:12]}...'}: {rel} was made from another "
                f"{target}; regenerate it ({_regenerate(rel)}), then rebuild the FMUs ({REBUILD})")
    return problems


def bundle_problems(resources: Path) -> list[str]:
    """Bundled data files missing or changed since the build, and broken links of their chain."""
    manifest = resources / BUNDLE_MANIFEST
    if not manifest.is_file():
        return [f"{manifest} is missing: this FMU was not built by fmu_build, or its resources were "
                f"altered; rebuild it ({REBUILD})"]
    info = json.loads(manifest.read_text())
    recorded = info.get("data_sha256", {})
    problems = []
    package = info.get("package", "flexarm")  # the bundled flexarm's private name (fmu_build/isolate.py)
    data_dir = resources / package / "data"
    for rel, sha in recorded.items():
        path = data_dir / rel
        if not path.is_file():
            problems.append(f"resources/{package}/data/{rel} is missing (resources/{BUNDLE_MANIFEST} lists it); "
                            f"copy the whole FMU again or rebuild it ({REBUILD})")
        elif sha256(path) != sha:
            problems.append(f"resources/{package}/data/{rel} differs from the file bundled at build time (SHA-256 "
                            f"{sha[:12]}... in resources/{BUNDLE_MANIFEST}); rebuild the FMU ({REBUILD}) after "
                            f"regenerating the data ({_regenerate(rel)})")
    if not problems:
        problems = data_chain_problems(data_dir, list(recorded))
    return problems


def preflight(resources: str) -> str:
    """'' if the FMU in `resources` can start; else the error message (see the module docstring)."""
    try:
        res = Path(resources)
        problems = bundle_problems(res)
        if problems:
            return "a data file of this FMU is missing or does not verify:\n  " + "\n  ".join(problems)
        provided = {e[:-3] if e.endswith(".py") else e for e in os.listdir(resources)
                    if e.endswith(".py") or os.path.isdir(os.path.join(resources, e))}
        for name, module in list(sys.modules.items()):
            file = getattr(module, "__file__", None)
            if name.split(".")[0] in provided and file and not os.path.exists(file):
                del sys.modules[name]  # from an FMU folder that is gone: this FMU's copy replaces it
        try:  # the host's own pythonfmu, if it has one: the FMU's copy (run-time part only) must not shadow it
            importlib.import_module("pythonfmu")
        except ImportError:
            pass
        if resources not in sys.path:
            sys.path.insert(0, resources)
        with open(os.path.join(resources, "slavemodule.txt")) as f:
            importlib.import_module(f.readline().strip())
        return ""
    except ImportError as exc:
        return (f"the FMU's Python code cannot be loaded: {type(exc).__name__}: {exc}. NumPy and SciPy must be "
                "importable by the Python in this process (set PYTHONPATH to a site-packages folder that has "
                f"them):\n{traceback.format_exc(limit=-4)}")
    except BaseException:  # noqa: BLE001 - reported to the host, which gets NULL from fmi2Instantiate
        return f"the FMU's Python code cannot be loaded:\n{traceback.format_exc(limit=-4)}"
