"""Issue 34's run-speed goals, measured together: start-up, real-time factor, writing against stepping.

    python benchmarks/bench_run_speed.py [--repeats 3]            # print
    python benchmarks/bench_run_speed.py --write                  # also docs/run-speed.json and its table

For each command (table2's no-payload case with the native and with the Python FMUs, Gauss-Seidel, and
lqg_jacobi's with the native FMUs, Jacobi): the CPU time before the master's first step in a fresh process
(:func:`bench_startup.measure`, best of the repeats), then in this process the CPU time of the run's stepping,
judging and writing (:func:`bench_results_writing.one_run`, best of the repeats), the real-time factor (the
simulated time over the stepping's CPU time) and writing over stepping, each beside issue 34's goal (≥ 50×
native, ≥ 30× Python, ≤ 0.5 s before the first step, writing ≤ stepping). ``--write`` records them with the
date, commit, machine and load in ``docs/run-speed.json`` and renders docs/benchmarks.md's table from it
(:mod:`scenarios.reports.speed_doc`; ``python -m scenarios results-page --check`` renders it again and compares).
The FMUs must be built and up to date first. CPU time, not wall time: the machine may be shared.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_results_writing import one_run  # noqa: E402
from bench_startup import measure  # noqa: E402

#: (kind, the scenarios command) measured; the start-up of the Jacobi run is not measured again (the same FMUs).
COMMANDS = (
    ("native", ["run", "table2", "--case", "none", "--native", "--no-plots"], True),
    ("python", ["run", "table2", "--case", "none", "--no-plots"], True),
    ("native", ["run", "lqg_jacobi", "--case", "none", "--native", "--no-plots"], False),
)


def measure_all(repeats: int) -> dict:
    from datetime import UTC, datetime

    from flexarm.provenance import git_commit

    load_before = os.getloadavg()
    rows = []
    for kind, command, start_up in COMMANDS:
        row = {"kind": kind, "command": command}
        if start_up:
            row["start_up_cpu_s"] = min(measure(command)["cpu_first_step_s"] for _ in range(repeats))
        runs = [one_run(command) for _ in range(repeats)]
        row.update({key: min(totals[label] for totals, _ in runs) for key, label in
                    (("run_cpu_s", "run (stepping)"), ("judge_cpu_s", "judge"), ("write_cpu_s", "write"))})
        case = json.loads(next(runs[-1][1].rglob(f"{command[command.index('--case') + 1]}.json")).read_text())
        row["simulated_s"] = case["samples"] * case["step_size_s"]
        rows.append(row)
        print(f"{kind:6} {' '.join(command)}: start-up {row.get('start_up_cpu_s', float('nan')):.3f} s, stepping "
              f"{row['run_cpu_s']:.3f} s ({row['simulated_s'] / row['run_cpu_s']:.0f}x real time), judging "
              f"{row['judge_cpu_s']:.3f} s, writing {row['write_cpu_s']:.3f} s", flush=True)
    return {**_stamp(load_before, git_commit(), datetime.now(UTC), repeats), "rows": rows}


def _stamp(load_before, commit, now, repeats) -> dict:
    return {"date": now.isoformat(timespec="seconds"), "commit": commit, "repeats": repeats,
            "machine": {"processor": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                        "python": platform.python_version(), "system": platform.platform()},
            "load_average_before": list(load_before), "load_average_after": list(os.getloadavg()),
            # Python's compiled-module cache: without it every start compiles the modules again (about 0.1 s)
            "bytecode_cache": not os.environ.get("PYTHONDONTWRITEBYTECODE"),
            # the master's stepping loop: in C (scenarios/master/step_loop.py) unless no compiler or turned off
            "master_loop": "c" if _master_loop() is not None else "python"}


def _master_loop():
    from scenarios.master.step_loop import loop_function

    return loop_function()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--write", action="store_true", help="record docs/run-speed.json and render its table")
    args = ap.parse_args(argv)
    from scenarios.reports.speed_doc import SPEED_JSON, render, write_block

    data = measure_all(max(1, args.repeats))
    print(render(data))
    if args.write:
        from flexarm.provenance import write_atomic

        write_atomic(SPEED_JSON, (json.dumps(data, indent=1) + "\n").encode())
        print(f"wrote {SPEED_JSON} and {write_block(data)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
