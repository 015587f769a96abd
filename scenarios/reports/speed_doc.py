"""docs/benchmarks.md's run-speed table, rendered from ``docs/run-speed.json`` (issue 34's goals, measured).

``python benchmarks/bench_run_speed.py --write`` measures (CPU time: start-up before the master's first step, then
each run's stepping, judging and writing) and writes the JSON with the date, commit, machine and load, and this
block; ``python -m scenarios results-page`` renders the same block from the committed JSON and ``--check`` fails
when the text differs. Neither re-times anything: timings on a shared machine do not repeat, the render does.
"""

from __future__ import annotations

import json

from scenarios.reports.page_blocks import REPO, PageRuns, block, rewrite_block

SPEED_JSON = REPO / "docs" / "run-speed.json"
DOC = REPO / "docs" / "benchmarks.md"
#: Issue 34's goals: CPU before the first step (s), real-time factor of three FMUs by kind, writing / simulating.
GOALS = {"start_up_s": 0.5, "real_time": {"native": 50.0, "python": 30.0}, "write_per_run": 1.0}


def _verdict(ok: bool) -> str:
    return "met" if ok else "missed"


def render(data: dict) -> str:
    """The table (one row per measured command) and the line that says where, when and under what load."""
    lines = ["| command | FMUs | CPU before the first step | stepping (real-time factor) | judging | writing "
             "(÷ stepping) |", "|---|---|---|---|---|---|"]
    for row in data["rows"]:
        kind = row["kind"]
        rtf = row["simulated_s"] / row["run_cpu_s"]
        start = row.get("start_up_cpu_s")
        start_text = "—" if start is None else (f"{start:.3f} s ({_verdict(start <= GOALS['start_up_s'])}, goal "
                                               f"≤ {GOALS['start_up_s']} s)")
        goal = GOALS["real_time"][kind]
        ratio = row["write_cpu_s"] / row["run_cpu_s"]
        lines.append(f"| `python -m scenarios {' '.join(row['command'])}` | {kind} | {start_text} | "
                     f"{row['run_cpu_s']:.3f} s for {row['simulated_s']:.3f} s: {rtf:.0f}× ({_verdict(rtf >= goal)}, "
                     f"goal ≥ {goal:.0f}×) | {row['judge_cpu_s']:.3f} s | {row['write_cpu_s']:.3f} s ({ratio:.2f}, "
                     f"{_verdict(ratio <= GOALS['write_per_run'])}, goal ≤ {GOALS['write_per_run']:.0f}) |")
    m = data["machine"]
    lines += ["", f"CPU seconds, the best of {data['repeats']} runs each (start-up: a fresh process, "
              "`benchmarks/bench_startup.py`; the stages: thread CPU time in one process, "
              "`benchmarks/bench_results_writing.py`), measured "
              f"{data['date'][:10]} at commit `{data['commit'][:12]}` on {m['cpus']} CPUs ({m['processor']}, Python "
              f"{m['python']}), load average {data['load_average_before'][0]:.1f} before and "
              f"{data['load_average_after'][0]:.1f} after; Python's compiled-module cache "
              + ("on" if data.get("bytecode_cache", True) else "off (PYTHONDONTWRITEBYTECODE set)")
              + {"c": "; the master's stepping loop in C (`scenarios/master/step_loop.py`).",
                 "python": "; the master's stepping loop in Python (no C compiler, or `FLEXARM_MASTER_LOOP=python`)."
                 }.get(data.get("master_loop"), ".")]
    return "\n".join(lines)


@block("run-speed")
def _run_speed(runs: PageRuns) -> str:
    return render(json.loads(SPEED_JSON.read_text(encoding="utf-8")))


def write_block(data: dict):
    """Rewrite docs/benchmarks.md's block from `data` (atomically); returns the path."""
    return rewrite_block(DOC, "run-speed", render(data))
