"""Build this project's FMUs into ``build/fmus/<name>.fmu``.

Usage::

    python build_fmus.py                 # build every FMU whose sources changed
    python build_fmus.py --only plant    # one FMU
    python build_fmus.py --out DIR       # another output folder
    python build_fmus.py --force         # rebuild even if up to date

Each FMU is built with pythonfmu's builder and bundles, in its ``resources``:

* its slave script (module name unique per FMU, e.g. ``flexarm_plant_fmu``),
* the shared glue ``fmus/common/*.py``,
* the ``flexarm`` package with its data files (no ``__pycache__``), and
* ``flexarm_bundle.json``: SHA-256 of the bundled sources, read by the glue
  to detect FMUs of different builds loaded into one interpreter.

so that the FMU runs when copied alone to another machine with only NumPy
and SciPy installed (Numba optional). Every FMU is checked with
``fmpy.validation.validate_fmu`` before it replaces the previous file (build
to a temporary file, then rename). Add an FMU with one entry in :data:`FMUS`.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent
#: Default output folder (documented in README and docs/fmu-interface.md).
DEFAULT_OUT_DIR = ROOT / "build" / "fmus"
COMMON_DIR = ROOT / "fmus" / "common"
FLEXARM_DIR = ROOT / "flexarm"
DOC_FILE = ROOT / "docs" / "fmu-interface.md"
_IGNORE = shutil.ignore_patterns("__pycache__", "*.pyc", "*.pyo", "*.tmp", ".*")



def _load_glue():
    # Under a private name: the FMUs import the glue as 'flexarm_fmu_base', and a
    # copy cached here from the project tree would shadow the bundled one.
    name = "_flexarm_fmu_base_for_build"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, COMMON_DIR / "flexarm_fmu_base.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # dataclasses look their module up here
        spec.loader.exec_module(module)
    return sys.modules[name]


_glue = _load_glue()
BUNDLE_MANIFEST, bundle_files, tree_sha256 = _glue.BUNDLE_MANIFEST, _glue.bundle_files, _glue.tree_sha256


@dataclass(frozen=True)
class FmuSpec:
    """One FMU of the project.

    Attributes
    ----------
    name : str
        Output file stem: ``<out_dir>/<name>.fmu``.
    script : Path
        Slave script; its stem is the Python module name inside the FMU and
        must be unique among all FMUs (they may share one interpreter).
    extra_files : tuple of Path
        Further files or folders bundled into this FMU's resources.
    """

    name: str
    script: Path
    extra_files: tuple[Path, ...] = field(default=())


#: Direct-feedthrough sampling glue shared by the sensors and controller FMUs.
FEEDTHROUGH = ROOT / "fmus" / "sensors" / "flexarm_feedthrough.py"
#: The controller FMUs: one slave module each, sharing flexarm_controller_base.py.
CONTROLLER_DIR = ROOT / "fmus" / "controller"

#: Every FMU of the project; sensors and controller add one entry each.
FMUS: dict[str, FmuSpec] = {
    spec.name: spec for spec in (
        FmuSpec("plant", ROOT / "fmus" / "plant" / "flexarm_plant_fmu.py"),
        FmuSpec("sensors", ROOT / "fmus" / "sensors" / "flexarm_sensors_fmu.py", (FEEDTHROUGH,)),
        *(FmuSpec(f"controller{suffix}", CONTROLLER_DIR / f"flexarm_controller{suffix}_fmu.py",
                  (FEEDTHROUGH, CONTROLLER_DIR / "flexarm_controller_base.py"))
          for suffix in ("", "_ff", "_fb", "_dlqr")),
    )
}

#: Capabilities written into <CoSimulation> (pythonfmu option names).
FMU_OPTIONS = {
    "canHandleVariableCommunicationStepSize": True,
    "canGetAndSetFMUstate": True,
    "canSerializeFMUstate": True,
}


class BuildError(RuntimeError):
    """An FMU could not be built or failed validation."""


def _files(path: Path) -> list[Path]:
    return [path] if path.is_file() else bundle_files(path)


def _sources(spec: FmuSpec) -> list[Path]:
    """Every file the FMU is made from (for the up-to-date check)."""
    out = [spec.script, *[f for e in spec.extra_files for f in _files(e)]]
    return out + sorted(COMMON_DIR.glob("*.py")) + bundle_files(FLEXARM_DIR)


def is_up_to_date(spec: FmuSpec, fmu: Path) -> bool:
    """True if `fmu` exists and is newer than every source (and this build script)."""
    if not fmu.is_file():
        return False
    newest = max(p.stat().st_mtime for p in [*_sources(spec), Path(__file__)] + ([DOC_FILE] * DOC_FILE.is_file()))
    return fmu.stat().st_mtime >= newest


@contextlib.contextmanager
def _import_sandbox(paths: list[Path]):
    """Let pythonfmu import the slave script, then undo sys.path and sys.modules changes.

    Without this, a later in-process load of the built FMU would find the
    project's copy of the slave module already in ``sys.modules`` instead
    of the one bundled in the FMU.
    """
    saved_path = list(sys.path)
    saved_modules = set(sys.modules)
    sys.path[:0] = [str(p) for p in paths]
    try:
        yield
    finally:
        sys.path[:] = saved_path
        drop = (str(ROOT / "fmus"), tempfile.gettempdir())
        for name in set(sys.modules) - saved_modules:
            file = getattr(sys.modules[name], "__file__", None) or ""
            if file.startswith(drop):
                del sys.modules[name]


def build_fmu(spec: FmuSpec, out_dir: Path) -> Path:
    """Build one FMU into ``out_dir/<spec.name>.fmu`` (temporary file, validate, rename)."""
    from fmpy.validation import validate_fmu
    from pythonfmu.builder import FmuBuilder

    out_dir.mkdir(parents=True, exist_ok=True)
    final = out_dir / f"{spec.name}.fmu"
    with tempfile.TemporaryDirectory(prefix=f"build_{spec.name}_") as tmp:
        stage = Path(tmp)
        shutil.copytree(FLEXARM_DIR, stage / "flexarm", ignore=_IGNORE)
        for f in COMMON_DIR.glob("*.py"):
            shutil.copy2(f, stage / f.name)
        manifest = stage / BUNDLE_MANIFEST
        manifest.write_text(json.dumps({
            "fmu": spec.name, "slave_module": spec.script.stem, "flexarm_sha256": tree_sha256(stage / "flexarm"),
            "flexarm_files": [f.relative_to(stage / "flexarm").as_posix() for f in bundle_files(stage / "flexarm")],
        }, indent=1))
        project_files = [stage / "flexarm", manifest, *[stage / f.name for f in COMMON_DIR.glob("*.py")],
                         *spec.extra_files]
        doc_dir = None
        if DOC_FILE.is_file():
            doc_dir = stage / "documentation"
            doc_dir.mkdir()
            shutil.copy2(DOC_FILE, doc_dir / DOC_FILE.name)
        fd, tmp_name = tempfile.mkstemp(dir=out_dir, prefix=f".{spec.name}-", suffix=".fmu")
        os.close(fd)
        tmp_fmu = Path(tmp_name)
        try:
            # Folders of extra modules too: the builder imports the script, which may import them.
            extra_dirs = [e.parent for e in spec.extra_files if e.suffix == ".py"]
            with _import_sandbox([COMMON_DIR, spec.script.parent, *extra_dirs]):
                FmuBuilder.build_FMU(spec.script, dest=tmp_fmu, project_files=project_files,
                                     documentation_folder=doc_dir, **FMU_OPTIONS)
            problems = validate_fmu(str(tmp_fmu))
            if problems:
                raise BuildError(f"{spec.name}: fmpy.validate_fmu found {len(problems)} problem(s):\n  "
                                 + "\n  ".join(problems))
            os.replace(tmp_fmu, final)
        finally:
            tmp_fmu.unlink(missing_ok=True)
    return final


def build_all(out_dir: str | os.PathLike | None = None, only=None, force: bool = False) -> dict[str, Path]:
    """Build the project's FMUs; return {name: path of the .fmu}.

    Parameters
    ----------
    out_dir : path-like, optional
        Output folder (default ``build/fmus``).
    only : str or iterable of str, optional
        Names from :data:`FMUS` to build (default: all).
    force : bool
        Rebuild even if the FMU is newer than all its sources.
    """
    out_dir = Path(out_dir) if out_dir is not None else DEFAULT_OUT_DIR
    names = list(FMUS) if only is None else ([only] if isinstance(only, str) else list(only))
    unknown = [n for n in names if n not in FMUS]
    if unknown:
        raise BuildError(f"unknown FMU name(s) {unknown}; choose from {sorted(FMUS)}")
    result = {}
    for name in names:
        spec = FMUS[name]
        target = out_dir / f"{name}.fmu"
        result[name] = target if not force and is_up_to_date(spec, target) else build_fmu(spec, out_dir)
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", action="append", choices=sorted(FMUS), help="build only this FMU (repeatable)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT_DIR, help=f"output folder (default {DEFAULT_OUT_DIR})")
    parser.add_argument("--force", action="store_true", help="rebuild even if up to date")
    args = parser.parse_args(argv)
    try:
        before = {n: (args.out / f"{n}.fmu").stat().st_mtime if (args.out / f"{n}.fmu").exists() else None
                  for n in (args.only or FMUS)}
        built = build_all(args.out, args.only, args.force)
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for name, path in built.items():
        state = "up to date" if before[name] == path.stat().st_mtime else "built"
        print(f"{name}: {path} ({state})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
