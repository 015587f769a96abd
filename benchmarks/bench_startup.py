"""Start-up cost of a one-case run: the time Python spends importing, from ``python -X importtime``.

    python benchmarks/bench_startup.py                      # table2 --case none --native --no-plots, best of 3
    python benchmarks/bench_startup.py --repeats 5 -- run table2 --case none --no-plots   # any scenarios command

Runs ``python -X importtime -m scenarios <command>`` in a child process (results into a temporary folder),
parses the importtime lines on its stderr and prints the total import time (the sum of every module's own
time, as importtime measures it: wall time, so a busy machine inflates it), the child's CPU time when the
master takes its first step (start-up, imports, data checks, FMU loading), the top-level imports that cost
most (cumulative) and the child's wall and CPU time. The FMUs must be built and up to date first (a
build would be counted otherwise; the script says so when the command printed a build line). Goal (issue
23): at most 0.5 s of imports, and of CPU before the first step, for the default command.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DEFAULT = ["run", "table2", "--case", "none", "--native", "--no-plots"]
#: ``python -m scenarios ARGS``, printing this process's CPU time when the master takes its first step.
_CHILD = r"""
import sys, time
from scenarios.master import cosim as master

_run = master.Master.run


def run(self, *args, **kwargs):
    print(f"bench-startup: cpu before the first step {time.process_time():.3f} s", file=sys.stderr, flush=True)
    master.Master.run = _run
    return _run(self, *args, **kwargs)


master.Master.run = run
from scenarios.__main__ import main

sys.argv[0] = "python -m scenarios"
sys.exit(main())
"""
_LINE = re.compile(r"^import time:\s+(\d+)\s+\|\s+(\d+)\s+\|(\s*)(\S+)\s*$")


def parse_importtime(stderr: str) -> tuple[float, list[tuple[float, str]]]:
    """(total import time in s: the sum of the modules' own times, [(cumulative s, top-level module)])."""
    total, top = 0, []
    for line in stderr.splitlines():
        m = _LINE.match(line)
        if not m:
            continue
        own, cumulative, indent, name = int(m.group(1)), int(m.group(2)), m.group(3), m.group(4)
        total += own
        if len(indent) == 1:  # imported by the script itself, not by another module
            top.append((cumulative / 1e6, name))
    return total / 1e6, sorted(top, reverse=True)


def measure(command: list[str]) -> dict:
    with tempfile.TemporaryDirectory(prefix="flexarm-bench-startup-") as tmp:
        args = list(command)
        if args[:1] == ["run"] and "--out" not in args:
            args += ["--out", str(Path(tmp) / "results")]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-X", "importtime", "-c", _CHILD, *args], capture_output=True,
                              text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        sys.exit(f"python -m scenarios {' '.join(command)} exited {proc.returncode}:\n{proc.stderr[-2000:]}")
    imports, top = parse_importtime(proc.stderr)
    built = [ln for ln in proc.stderr.splitlines() if ln.startswith("fmu_build: building")]
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    first = re.search(r"^bench-startup: cpu before the first step ([\d.]+) s", proc.stderr, re.M)
    return {"imports_s": imports, "top": top, "wall_s": wall, "cpu_s": cpu, "built": built,
            "cpu_first_step_s": float(first.group(1)) if first else float("nan")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="runs; the best (least import time) is shown")
    ap.add_argument("command", nargs="*", help=f"a scenarios command (default: {' '.join(DEFAULT)})")
    args = ap.parse_args(argv)
    command = args.command or DEFAULT
    runs = [measure(command) for _ in range(max(1, args.repeats))]
    if os.environ.get("PYTHONDONTWRITEBYTECODE"):  # the compiling is counted in every figure below
        print("note: PYTHONDONTWRITEBYTECODE is set here, so every run compiles this project's modules again; a "
              "user's second run reads them compiled (unset it to measure that)")
    if any(r["built"] for r in runs):
        print("note: a run built FMUs (counted in wall and CPU time, not in imports):", *runs[0]["built"], sep="\n  ")
    best = min(runs, key=lambda r: r["imports_s"])
    print(f"python -X importtime -m scenarios {' '.join(command)}  ({len(runs)} runs)")
    each = ", ".join(f"{r['imports_s']:.3f}" for r in runs)
    print(f"imports: {best['imports_s']:.3f} s (best; all runs: {each} s; goal <= 0.5 s)")
    first = min(r["cpu_first_step_s"] for r in runs)
    print(f"CPU before the master's first step (start-up, imports, checks, FMU loading): {first:.3f} s (best; goal "
          "<= 0.5 s)")
    print(f"whole process: wall {best['wall_s']:.2f} s, CPU {best['cpu_s']:.2f} s")
    print("costliest top-level imports (cumulative):")
    for cumulative, name in best["top"][:8]:
        print(f"  {cumulative:7.3f} s  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
