"""Regenerate the whole data chain with one command: parameters -> trajectory -> gains -> FMUs -> tables.

``python -m flexarm.regenerate`` runs, in order and each as its own process
(so each stage is exactly its documented command):

1. ``python -m flexarm.calibration`` -> ``flexarm/data/sandia_arm.toml`` (records the design file's SHA-256);
2. ``python -m flexarm.trajectory`` -> ``flexarm/data/trajectory.npz/.json/.png`` (records the parameter file's);
3. ``python -m flexarm.lqr --write`` -> ``flexarm/data/gains/*`` (record the trajectory's and parameters');
4. ``python build_fmus.py --force`` -> ``build/fmus/*.fmu`` (built from the files above; not committed);
5. ``python -m scenarios results-page`` -> ``docs/results.md`` and the README's table (from fresh runs).

It stops at the first stage that fails, naming it; the files of the stages
before it are complete (every file is written atomically). ``--from STAGE``
resumes at a stage, ``--only STAGE`` runs one.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from .provenance import refuse_outside_checkout

REPO = Path(__file__).resolve().parent.parent
DATA = Path(__file__).resolve().parent / "data"


def stages(sensitivity: bool) -> list[tuple[str, list[str]]]:
    """(name, command) of every stage, in order."""
    py = sys.executable
    # Paths relative to the repository (the stages run there): they are recorded in the files' metadata.
    plot = DATA / "trajectory.png"
    plot = plot.relative_to(REPO) if plot.is_relative_to(REPO) else plot
    trajectory = [py, "-m", "flexarm.trajectory", "--quiet", "--plot", str(plot)]
    if sensitivity:
        trajectory.append("--sensitivity")
    return [
        ("parameters", [py, "-m", "flexarm.calibration"]),
        ("trajectory", trajectory),
        ("gains", [py, "-m", "flexarm.lqr", "--write"]),
        ("fmus", [py, "build_fmus.py", "--force"]),
        ("tables", [py, "-m", "scenarios", "results-page"]),
    ]


def main(argv=None) -> int:
    names = [n for n, _ in stages(False)]
    ap = argparse.ArgumentParser(prog="python -m flexarm.regenerate", description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="start", choices=names, default=names[0], help="first stage to run")
    ap.add_argument("--only", choices=names, default=None, help="run this stage only")
    ap.add_argument("--sensitivity", action="store_true",
                    help="the trajectory stage also solves the ±20 %% parameter cases (about a minute more)")
    args = ap.parse_args(argv)
    if refuse_outside_checkout("python -m flexarm.regenerate", "the data files, FMUs and documents", REPO):
        return 2
    chosen = stages(args.sensitivity)
    first = names.index(args.only or args.start)
    chosen = chosen[first:first + 1] if args.only else chosen[first:]
    t_all = time.perf_counter()
    for name, cmd in chosen:
        print(f"== {name}: {' '.join(cmd)}", flush=True)
        t0 = time.perf_counter()
        try:
            rc = subprocess.run(cmd, cwd=REPO).returncode
        except KeyboardInterrupt:
            print(f"interrupted in stage '{name}'; rerun with --from {name}", file=sys.stderr)
            return 130
        if rc != 0:
            print(f"error: stage '{name}' failed (exit code {rc}); later stages not run. "
                  f"Fix it and rerun with --from {name}", file=sys.stderr)
            return 1
        print(f"== {name}: done in {time.perf_counter() - t0:.0f} s", flush=True)
    print(f"regenerated {', '.join(n for n, _ in chosen)} in {time.perf_counter() - t_all:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
