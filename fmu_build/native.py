"""The native (plain C) kind of the FMUs, built beside the Python kind with up-to-date checks.

The native build itself is :mod:`fmu_build.native_build` (CasADi code generation, Zig's C
cross-compiler); this module decides what needs building: a native FMU is rebuilt when it is
older than its Python twin (whose interface it copies) or than any source of the native build
(``fmus/native/**``, the ``flexarm`` package and its data, this module and the build modules
beside it). The native FMUs have the file names of the Python ones, in their own folder (default
``build/fmus-native``).
"""

from __future__ import annotations

import os
from pathlib import Path

from .compile import BuildError
from .progress import say
from .registry import FLEXARM_DIR, SOURCES

#: Environment variable naming the default output folder of the native kind.
NATIVE_OUT_DIR_ENV = "FLEXARM_NATIVE_FMU_DIR"
#: The two kinds of FMU this project builds.
KINDS = ("python", "native")
#: The native build's sources (C, generators, build script).
NATIVE_SOURCES = SOURCES / "native"


def default_native_out_dir() -> Path:
    """Where native FMUs are built by default: ``$FLEXARM_NATIVE_FMU_DIR``, else ``build/fmus-native`` here."""
    return Path(os.environ.get(NATIVE_OUT_DIR_ENV) or Path.cwd() / "build" / "fmus-native")


def _build_module():
    """:mod:`fmu_build.native_build`, or BuildError saying what to install."""
    try:
        from . import native_build as build_native
    except ImportError as exc:  # fmpy or casadi missing: the message names the module
        raise BuildError(f"the native build cannot be imported: {exc}") from exc
    return build_native


def native_names() -> list[str]:
    """Names of the FMUs that have a native build (a subset of :data:`fmu_build.registry.FMUS`)."""
    return list(_build_module().NATIVE_FMUS)


def check_native_toolchain() -> None:
    """BuildError (saying what to install) unless Zig's C compiler, from the ``ziglang`` package, is there."""
    build_native = _build_module()
    try:
        build_native.zig_command()
    except build_native.NativeBuildError as exc:
        raise BuildError(f"the native FMUs need Zig's C compiler: {exc} (or build only the Python kind: "
                         "python build_fmus.py --kind python)") from None


def _newest_source() -> float:
    files = [p for p in NATIVE_SOURCES.rglob("*") if p.is_file() and "__pycache__" not in p.parts]
    files += [p for p in FLEXARM_DIR.rglob("*") if p.is_file() and "__pycache__" not in p.parts]
    here = Path(__file__).parent  # this module and the build, code generation and resource writers beside it
    files += [here / f for f in ("native.py", "native_build.py", "native_codegen.py", "law_codegen.py",
                                  "native_description.py", "native_resources.py")]
    return max(p.stat().st_mtime for p in files)


def native_is_up_to_date(fmu: Path, python_fmu: Path) -> bool:
    """True if `fmu` exists and is newer than its Python twin and every source of the native build."""
    if not fmu.is_file():
        return False
    return fmu.stat().st_mtime >= max(python_fmu.stat().st_mtime, _newest_source())


def _zig_first_time() -> str:
    """What a build adds when Zig's C libraries are not cached yet (its global cache is empty)."""
    cache = Path(os.environ.get("ZIG_GLOBAL_CACHE_DIR") or Path(os.environ.get("XDG_CACHE_HOME") or
                                                                 Path.home() / ".cache") / "zig")
    if cache.is_dir() and any(cache.iterdir()):
        return ""
    return f", plus about 2.5 minutes once to build Zig's C libraries for the three targets (cached in {cache})"


def build_native_all(python_fmus: dict[str, Path], out_dir: str | os.PathLike | None = None, only=None,
                     force: bool = False) -> dict[str, Path]:
    """Build the native twins of `python_fmus` into `out_dir`; return {name: path of the .fmu}.

    Parameters
    ----------
    python_fmus : dict
        Name -> built Python FMU (:func:`fmu_build.build_all`); each native FMU copies its twin's interface.
    out_dir : path-like, optional
        Output folder (default :func:`default_native_out_dir`).
    only : str or iterable of str, optional
        Names to build (default: every name of `python_fmus` that has a native build). A name without
        a native build is refused (BuildError naming it and those that have one).
    force : bool
        Rebuild even if up to date.

    Raises
    ------
    BuildError
        A name without a native build, no Zig compiler (``pip install ziglang``), or a failed build.
    """
    build_native = _build_module()
    out_dir = Path(out_dir) if out_dir is not None else default_native_out_dir()
    have = native_names()
    names = ([n for n in python_fmus if n in have] if only is None
             else ([only] if isinstance(only, str) else list(only)))
    missing = [n for n in names if n not in have]
    if missing:
        raise BuildError(f"no native build of {', '.join(missing)} (the native FMUs are {', '.join(have)}); "
                         "use the Python kind for it")
    absent = [n for n in names if n not in python_fmus]
    if absent:
        raise BuildError(f"native build of {', '.join(absent)}: its Python twin was not built (its interface "
                         "is copied from it)")
    stale = [n for n in names if force or not native_is_up_to_date(out_dir / f"{n}.fmu", Path(python_fmus[n]))]
    result = {n: out_dir / f"{n}.fmu" for n in names}
    if not stale:
        return result
    check_native_toolchain()
    say(f"building native {', '.join(f'{n}.fmu' for n in stale)} into {out_dir} with Zig for linux64, win64 and "
        f"darwin64: about 2-5 s each{_zig_first_time()}")
    try:
        result.update(build_native.build_native_fmus(out_dir, {n: Path(python_fmus[n]) for n in stale}, only=stale))
    except build_native.NativeBuildError as exc:
        raise BuildError(f"native build: {exc}") from exc
    except ImportError as exc:  # the generators' CasADi (imported only for a build) missing: name the module
        raise BuildError(f"the native build cannot import what it needs: {exc}") from exc
    return result
