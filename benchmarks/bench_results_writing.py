"""What a one-case run spends on simulating, judging and writing its results, by CPU time.

    python benchmarks/bench_results_writing.py                   # table2 --case none --native, best of 3
    python benchmarks/bench_results_writing.py --repeats 5 -- run lqg --case none --no-plots

Runs ``python -m scenarios <command>`` in this process (results into a temporary folder) with the run stage
(:func:`scenarios.run.runner.simulate`: the master stepping the FMUs), the judge stage
(:func:`scenarios.run.verdict.judge_case`) and the write stage (:func:`scenarios.run.write.write_case`: the
case's CSV and JSON) timed by this thread's CPU time, and prints each beside the goal of issue 34: writing
the results costs no more than the simulation they record. Then formats the written CSV's numbers both
ways, ``repr`` (what :func:`scenarios.results.write_csv` used before) and orjson
(:func:`scenarios.results.csv_rows`), and checks that both read back as the same doubles. The FMUs must be
built and up to date first. CPU time, not wall time: the machine may be shared.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DEFAULT = ["run", "table2", "--case", "none", "--native", "--no-plots"]


def _timed(module, name: str, totals: dict[str, float], label: str):
    inner = getattr(module, name)

    def wrapper(*args, **kwargs):
        t0 = time.thread_time()
        try:
            return inner(*args, **kwargs)
        finally:
            totals[label] = totals.get(label, 0.0) + time.thread_time() - t0

    setattr(module, name, wrapper)
    return inner


def one_run(command: list[str]) -> tuple[dict[str, float], Path]:
    """CPU seconds per stage of one ``python -m scenarios`` command, and its results folder."""
    from scenarios.__main__ import main
    from scenarios.run import runner

    totals: dict[str, float] = {}
    originals = {n: _timed(runner, n, totals, label)
                 for n, label in (("simulate", "run (stepping)"), ("judge_case", "judge"), ("write_case", "write"))}
    out = Path(tempfile.mkdtemp(prefix="bench-results-"))
    t0 = time.thread_time()
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            status = main([*command, "--out", str(out)])
    finally:
        for n, f in originals.items():
            setattr(runner, n, f)
    totals["whole command"] = time.thread_time() - t0
    if status:
        raise SystemExit(f"python -m scenarios {' '.join(command)} exited {status}")
    return totals, out


def formatting(csv: Path, repeats: int) -> tuple[float, float, int]:
    """CPU seconds to format the numbers of `csv` with ``repr`` and with :func:`scenarios.results.csv_rows`
    (best of `repeats`), and how many numbers; exits 1 when the two do not read back as the same doubles."""
    from scenarios.results import csv_rows

    data = np.loadtxt(csv, delimiter=",", skiprows=2, ndmin=2)
    best = {"repr": np.inf, "orjson": np.inf}
    for _ in range(repeats):
        t0 = time.thread_time()
        by_repr = [",".join(repr(float(x)) for x in row) for row in data]
        best["repr"] = min(best["repr"], time.thread_time() - t0)
        t0 = time.thread_time()
        rows = csv_rows(data)
        best["orjson"] = min(best["orjson"], time.thread_time() - t0)
    back = np.array([[float(x) for x in r.split(",")] for r in rows])
    if not np.array_equal(back, np.array([[float(x) for x in r.split(",")] for r in by_repr]), equal_nan=True):
        raise SystemExit("the two formats do not read back as the same doubles")
    return best["repr"], best["orjson"], data.size


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("command", nargs="*", help="after --: a python -m scenarios command (default: %(default)s)")
    args = ap.parse_args(argv)
    command = args.command or DEFAULT
    runs = [one_run(command) for _ in range(max(args.repeats, 1))]
    best = {k: min(t[k] for t, _ in runs) for k in runs[0][0]}
    print(f"python -m scenarios {' '.join(command)}  (in this process, best of {len(runs)}, thread CPU time)")
    for label in ("run (stepping)", "judge", "write", "whole command"):
        print(f"  {label:15s} {best.get(label, float('nan')):7.3f} s")
    ratio = best["write"] / best["run (stepping)"]
    print(f"writing / simulating: {ratio:.2f} (goal <= 1: {'met' if ratio <= 1 else 'missed'})")
    csv = sorted(runs[-1][1].rglob("*.csv"))[0]
    t_repr, t_orjson, n = formatting(csv, args.repeats)
    print(f"formatting {csv.name}'s {n} numbers: repr {t_repr:.3f} s, orjson {t_orjson:.3f} s "
          f"({t_repr / t_orjson:.0f}x), both read back as the same doubles")
    return 0


if __name__ == "__main__":
    sys.exit(main())
