"""``python build_fmus.py`` / ``python -m fmu_build``: build the FMUs (or regenerate the interface document)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .compile import BuildError
from .native import KINDS, NATIVE_OUT_DIR_ENV, default_native_out_dir
from .registry import FMUS, OUT_DIR_ENV, default_out_dir

USAGE = f"""Build this project's FMUs, both kinds: the Python ones into <out>/<name>.fmu and the native
(plain C, Python-free) ones into <native-out>/<name>.fmu.

    python build_fmus.py                 # build every FMU, both kinds, whose sources changed
    python build_fmus.py --kind python   # only the Python FMUs
    python build_fmus.py --kind native   # only the native FMUs (their Python twins are brought up to date too:
                                         #   the native ones copy their interface)
    python build_fmus.py --only plant    # one FMU (both kinds)
    python build_fmus.py --out DIR --native-out DIR2   # other output folders
    python build_fmus.py --force         # rebuild even if up to date
    python build_fmus.py --write-doc     # regenerate the tables of docs/fmu-interface.md

The default output folders are ${OUT_DIR_ENV}, else build/fmus, and ${NATIVE_OUT_DIR_ENV}, else
build/fmus-native, under the current directory. The native kind needs Zig's C compiler
(pip install ziglang); an FMU without a native build is built as Python only (and said so)."""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="build_fmus.py", description=USAGE,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", action="append", choices=sorted(FMUS), help="build only this FMU (repeatable)")
    parser.add_argument("--kind", choices=(*KINDS, "both"), default="both",
                        help="which kind to build (default: both)")
    parser.add_argument("--out", type=Path, default=None, help=f"Python FMUs' folder (default {default_out_dir()})")
    parser.add_argument("--native-out", type=Path, default=None,
                        help=f"native FMUs' folder (default {default_native_out_dir()})")
    parser.add_argument("--force", action="store_true", help="rebuild even if up to date")
    parser.add_argument("--write-doc", action="store_true",
                        help="regenerate the generated tables of docs/fmu-interface.md from the signal catalogue "
                             "and the FMUs' variable tables, and build nothing")
    args = parser.parse_args(argv)
    try:
        if args.write_doc:
            from flexarm.provenance import refuse_outside_checkout

            from .interface_doc import write_interface_doc
            from .registry import SOURCES

            # an installed package carries no docs/: exit 2 with the reason, as every command that needs a checkout
            if refuse_outside_checkout("flexarm-build-fmus --write-doc", "docs/fmu-interface.md", SOURCES.parent):
                return 2
            print(f"{write_interface_doc()}: regenerated")
            return 0
        return _build(args)
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


def _mtimes(folder: Path, names) -> dict[str, float | None]:
    return {n: (folder / f"{n}.fmu").stat().st_mtime if (folder / f"{n}.fmu").exists() else None for n in names}


def _report(label: str, built: dict[str, Path], before: dict[str, float | None]) -> None:
    for name, path in built.items():
        state = "up to date" if before.get(name) == path.stat().st_mtime else "built"
        print(f"{label}{name}: {path} ({state}, {path.stat().st_size / 1e3:.0f} kB)")


def _build(args) -> int:
    from .native import build_native_all, check_native_toolchain, native_names
    from .package import build_all

    out = args.out or default_out_dir()
    names = args.only or list(FMUS)
    native = [n for n in names if n in native_names()] if args.kind in ("native", "both") else []
    if args.kind == "native":
        without = [n for n in names if n not in native]
        if args.only and without:
            raise BuildError(f"no native build of {', '.join(without)} (the native FMUs are "
                             f"{', '.join(native_names())})")
    if native:
        check_native_toolchain()  # before anything is built: say so now, not after the Python kind
    python_names = names if args.kind in ("python", "both") else native
    before = _mtimes(out, python_names)
    built = build_all(out, python_names, args.force)
    if args.kind != "native":
        _report("", built, before)
    if native:
        native_out = args.native_out or default_native_out_dir()
        before = _mtimes(native_out, native)
        _report("native ", build_native_all(built, native_out, native, args.force), before)
        if args.kind == "both":
            for name in names:
                if name not in native:
                    print(f"native {name}: none (no native build of this FMU; the Python one serves)")
    return 0
