"""Which FMU files a run uses: names resolved by kind (Python or native) and built, paths checked, model
descriptions read.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from scenarios.config import KINDS, Scenario, ScenarioError
from scenarios.master.fmu_files import NotAnFmuError, read_description

#: Where FMUs are built and found: $FLEXARM_FMU_DIR, else ./build/fmus (relative to the current directory, as
#: fmu_build's default), made absolute once so that scenario and sweep files in other folders find the same.
DEFAULT_FMU_DIR = Path(os.environ.get("FLEXARM_FMU_DIR", Path("build") / "fmus")).resolve()
#: Where the native (plain C) FMUs are built and found: $FLEXARM_NATIVE_FMU_DIR, else ./build/fmus-native (as
#: fmu_build.native's default), made absolute once.
DEFAULT_NATIVE_FMU_DIR = Path(os.environ.get("FLEXARM_NATIVE_FMU_DIR", Path("build") / "fmus-native")).resolve()


def _build_tool():
    """The packaged build tooling (:mod:`fmu_build`), or None where it is not installed."""
    try:
        import fmu_build
    except ImportError:
        return None
    return fmu_build


def known_fmu_names() -> list[str]:
    """The FMU names this project builds (``build_fmus.FMUS``); [] when the build tooling is not importable."""
    tool = _build_tool()
    return sorted(tool.FMUS) if tool is not None else []


def native_fmu_names() -> list[str] | None:
    """The FMU names that have a native build (``fmu_build.native_build.NATIVE_FMUS``); None if unknown here."""
    try:
        from fmu_build.native_build import NATIVE_FMUS
    except ImportError:
        return None
    return list(NATIVE_FMUS)


#: generationTool of a native FMU's model description (fmu_build/native_build.py) starts with this.
NATIVE_GENERATION_TOOL = "flexarm-fmi native build"


def fmu_kind(description) -> str:
    """The kind of an FMU from its description: "native" (our plain C), "python" (pythonfmu) or "other"."""
    tool = description.generationTool or ""
    if tool.startswith(NATIVE_GENERATION_TOOL):
        return "native"
    return "python" if tool.startswith("PythonFMU") else "other"


def refuse_without_native(names: dict[str, str], kind: str) -> None:
    """With kind "native": :class:`ScenarioError` naming an instance whose FMU name has no native build."""
    native = native_fmu_names() if kind == "native" else None
    if native is None:
        return
    for inst, name in names.items():
        if not name.endswith(".fmu") and name not in native:
            raise ScenarioError(f"fmus.{inst}: {name} has no native build (the native FMUs are "
                                f"{', '.join(native)}): run it with the Python FMUs (--python, or "
                                f"kind = \"python\" in [scenario]) or give a path to a .fmu")


def check_kind(scenario: Scenario, kind: str | None = None, controller: str | None = None) -> str:
    """The kind a run of `scenario` uses (`kind`, else the scenario's), after refusing a name of any case
    that has no FMU of that kind; nothing is built (the CLI checks every scenario before the first runs)."""
    kind = kind or scenario.kind
    if kind not in KINDS:
        raise ScenarioError(f"kind: one of {list(KINDS)}, got {kind!r}")
    for case in scenario.cases:
        names = dict(case.fmus or scenario.fmus)
        if controller is not None:
            names["controller"] = controller
        refuse_without_native(names, kind)
    return kind


def resolve_fmus(scenario: Scenario, fmu_dir: Path, controller: str | None = None, build: bool = True,
                 names: dict[str, str] | None = None, kind: str | None = None,
                 native_fmu_dir: Path = DEFAULT_NATIVE_FMU_DIR) -> dict[str, Path]:
    """FMU instance -> .fmu path; names are built (rebuilt when older than their sources).

    `names` (instance -> FMU name or path) defaults to the scenario's ``[fmus]``;
    `controller` replaces the ``controller`` instance's FMU. `kind` (default the scenario's
    ``kind``) says which FMUs a name means: "python" (built into `fmu_dir`) or "native" (built into
    `native_fmu_dir`, with their Python twins in `fmu_dir`, whose interface they copy). An unknown name,
    or with kind "native" a name that has no native build, is refused listing the known ones; a path that
    is no FMU is refused naming the file (all :class:`ScenarioError`). A path to a .fmu is used as it is,
    whatever the kind. Without the build tooling (a non-editable install) names are taken from the
    folder as they are.
    """
    kind = kind or scenario.kind
    if kind not in KINDS:
        raise ScenarioError(f"kind: one of {list(KINDS)}, got {kind!r}")
    names = dict(scenario.fmus if names is None else names)
    if controller is not None:
        names["controller"] = controller
    to_build = sorted({n for n in names.values() if not n.endswith(".fmu")})
    tool = _build_tool() if to_build else None
    known = sorted(tool.FMUS) if tool is not None else []
    for inst, name in names.items():
        if not name.endswith(".fmu") and known and name not in known:
            raise ScenarioError(f"fmus.{inst}: an FMU name of this project {known} or a path to a .fmu file, "
                                f"got {name!r}")
    refuse_without_native(names, kind)
    folder = Path(native_fmu_dir if kind == "native" else fmu_dir)
    given = {inst: _given_path(scenario, name) for inst, name in names.items() if name.endswith(".fmu")}
    for inst, p in given.items():  # a file given by path is checked before minutes of building ours
        if not p.is_file():
            raise ScenarioError(f"fmus.{inst}: no FMU at {p}")
    read_descriptions(given)
    built = {}
    if to_build and build and tool is not None:
        try:
            built = tool.build_all(fmu_dir, only=to_build)
            if kind == "native":
                from fmu_build.native import build_native_all

                built = build_native_all(built, folder, only=to_build)
        except Exception as exc:  # noqa: BLE001 - one line naming what failed, not a traceback
            raise ScenarioError(f"building the {kind} FMUs {to_build} into {folder} failed: {type(exc).__name__}: "
                                f"{exc}") from exc
    paths = {}
    for inst, name in names.items():
        if name.endswith(".fmu"):
            p = given[inst]
        else:
            p = built.get(name, folder / f"{name}.fmu")
        if not p.is_file():
            hint = "" if tool is not None or name.endswith(".fmu") else (
                " (the build tooling build_fmus.py is not installed here: build the FMUs in a checkout and pass "
                "--fmu-dir" + (" / --native-fmu-dir" if kind == "native" else "") + ")")
            what = "FMU" if name.endswith(".fmu") else f"{kind} FMU"
            raise ScenarioError(f"fmus.{inst}: no {what} at {p}{hint}")
        paths[inst] = p
    return paths


def _given_path(scenario: Scenario, name: str) -> Path:
    """A .fmu given by path: as it is when absolute, else relative to the scenario file's folder."""
    return Path(name) if Path(name).is_absolute() else (scenario.path.parent / name)


def read_descriptions(paths: dict[str, Path]) -> dict:
    """Instance -> model description; a file that is no FMU is refused naming the instance and the file."""
    out = {}
    for inst, p in paths.items():
        try:
            out[inst] = read_description(p)
        except NotAnFmuError as exc:
            raise ScenarioError(f"fmus.{inst}: {exc}") from exc
    return out


def numba_compiles(fmu: Path | None = None) -> bool:
    """Whether a Python plant FMU will compile Numba kernels when it steps.

    Numba must be importable and not switched off. Each Python FMU runs its own private copy of ``flexarm``
    (fmu_build.isolate), whose kernels Numba caches once per FMU build in the user's cache folder
    (:mod:`flexarm._numba_cache`); given the FMU file, this is also False when that cache holds its build.
    """
    import importlib.util

    if os.environ.get("FLEXARM_NO_NUMBA") or importlib.util.find_spec("numba") is None:
        return False
    if fmu is None:
        return True
    import zipfile

    from flexarm._numba_cache import cache_root

    try:
        with zipfile.ZipFile(fmu) as z:
            bundled = {n.split("/")[1] for n in z.namelist() if n.startswith("resources/_") and n.count("/") >= 2}
    except (OSError, zipfile.BadZipFile):
        return True
    return bool(bundled) and not any(next((cache_root() / b).glob("*.nbi"), None) for b in bundled)


def _say_numba_compile(fmu: Path | None = None) -> bool:
    """Say so when the Python plant FMU `fmu` will compile its Numba kernels on its first step; whether it will."""
    if not numba_compiles(fmu):
        return False
    try:
        print("the Python plant FMU compiles its Numba kernels on its first step (about 20 s, once per FMU "
              "build: then cached; FLEXARM_NO_NUMBA=1 runs NumPy instead)", file=sys.stderr, flush=True)
    except (OSError, ValueError):  # standard error unwritable: no reason to stop a run
        pass
    return True
