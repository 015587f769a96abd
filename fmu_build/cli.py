"""``python build_fmus.py`` / ``python -m fmu_build``: build the FMUs (or regenerate the interface document)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .compile import BuildError
from .registry import FMUS, OUT_DIR_ENV, default_out_dir

USAGE = f"""Build this project's FMUs into <out>/<name>.fmu.

    python build_fmus.py                 # build every FMU whose sources changed
    python build_fmus.py --only plant    # one FMU
    python build_fmus.py --out DIR       # another output folder
    python build_fmus.py --force         # rebuild even if up to date
    python build_fmus.py --write-doc     # regenerate the tables of docs/fmu-interface.md

The default output folder is ${OUT_DIR_ENV}, else build/fmus under the current directory."""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="build_fmus.py", description=USAGE,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", action="append", choices=sorted(FMUS), help="build only this FMU (repeatable)")
    parser.add_argument("--out", type=Path, default=None, help=f"output folder (default {default_out_dir()})")
    parser.add_argument("--force", action="store_true", help="rebuild even if up to date")
    parser.add_argument("--write-doc", action="store_true",
                        help="regenerate the generated tables of docs/fmu-interface.md from the signal catalogue "
                             "and the FMUs' variable tables, and build nothing")
    args = parser.parse_args(argv)
    try:
        if args.write_doc:
            from .interface_doc import write_interface_doc

            print(f"{write_interface_doc()}: regenerated")
            return 0
        from .package import build_all

        out = args.out or default_out_dir()
        before = {n: (out / f"{n}.fmu").stat().st_mtime if (out / f"{n}.fmu").exists() else None
                  for n in (args.only or FMUS)}
        built = build_all(out, args.only, args.force)
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for name, path in built.items():
        state = "up to date" if before[name] == path.stat().st_mtime else "built"
        print(f"{name}: {path} ({state}, {path.stat().st_size / 1e3:.0f} kB)")
    return 0
