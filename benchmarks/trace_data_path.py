"""How far a scenario's data travels between the modules of ``scenarios`` (issue 33 item 2, "The data's path is short").

Runs :func:`scenarios.run.runner.run_scenario` for one case (default: ``table2`` case ``none``, no plots) under
:func:`sys.setprofile` and counts, for calls of functions defined in ``scenarios/**``:

* **entries** per module: calls whose nearest calling ``scenarios`` function lives in another module;
* **bounces**: the sum of the entries (every module-to-module hand-over of the control flow);
* **modules crossed**: how many distinct modules the control flow visits;
* **trajectory loads**: calls of :func:`flexarm.trajectory.load_trajectory`, and how many of them a function of
  ``scenarios`` made itself (the others are flexarm's: its data-chain check, the reference signals, the
  sampled-loop model);
* **case parameter checks**: calls of :func:`scenarios.master.values.check_parameters` (a case's, the ``--set``
  values') and of the FMU set's ``case_parameters``.

The co-simulation master's inside (everything called while a function of ``scenarios/master/`` runs) is not
followed: it is the same before and after, and its thousands of calls per step would drown the data's path. The
entry into the master is counted.

Usage::

    python benchmarks/trace_data_path.py [--scenario table2] [--case none] [--native]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"
MASTER = SCENARIOS / "master"


def _module(filename: str) -> str | None:
    """The dotted name of a module of ``scenarios`` from its file name; None for anything else."""
    path = Path(filename)
    if not path.is_relative_to(SCENARIOS):
        return None
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


class DataPathTrace:
    """A profile hook counting the hand-overs of the control flow between modules of ``scenarios``."""

    def __init__(self):
        self.entries: Counter[str] = Counter()
        self.visited: set[str] = set()
        self.trajectory_loads = 0
        self.trajectory_loads_by_scenarios = 0
        self.parameter_checks = 0
        self.case_parameter_calls = 0
        self._modules: dict = {}

    def _of(self, code) -> str | None:
        mod = self._modules.get(code, 0)
        if mod == 0:
            mod = self._modules[code] = _module(code.co_filename)
        return mod

    def __call__(self, frame, event, arg):
        if event != "call":
            return
        code = frame.f_code
        if code.co_name == "load_trajectory" and "flexarm" in code.co_filename:
            self.trajectory_loads += 1
            self.trajectory_loads_by_scenarios += self._of(frame.f_back.f_code) is not None
        mod = self._of(code)
        if mod is None:
            return
        caller, inside_master = None, False
        f = frame.f_back
        while f is not None:  # the nearest scenarios function that called this one, and whether the master runs
            m = self._of(f.f_code)
            if m is not None:
                if caller is None:
                    caller = m
                if m.startswith("scenarios.master"):
                    inside_master = True
                    break
            f = f.f_back
        if inside_master:
            return
        if code.co_name == "check_parameters" and mod == "scenarios.master.values":
            self.parameter_checks += 1
        if code.co_name == "case_parameters":
            self.case_parameter_calls += 1
        self.visited.add(mod)
        if caller is not None and caller != mod:
            self.entries[mod] += 1

    def report(self) -> str:
        lines = [f"{'module':40s} entries"]
        lines += [f"{m:40s} {n:7d}" for m, n in sorted(self.entries.items(), key=lambda kv: (-kv[1], kv[0]))]
        lines += ["", f"bounces (module-to-module hand-overs): {sum(self.entries.values())}",
                  f"modules crossed:                       {len(self.visited)}",
                  f"trajectory loads:                      {self.trajectory_loads} "
                  f"({self.trajectory_loads_by_scenarios} by scenarios, the others inside flexarm's own functions)",
                  f"parameter checks (check_parameters):   {self.parameter_checks}",
                  f"case_parameters calls:                 {self.case_parameter_calls}"]
        return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="table2")
    ap.add_argument("--case", default="none")
    ap.add_argument("--native", action="store_true", help="the native FMUs (default: the scenario's kind)")
    args = ap.parse_args(argv)
    from scenarios.config import load_scenario, select_cases
    from scenarios.run.runner import run_scenario

    scenario = select_cases(load_scenario(args.scenario), [args.case])
    trace = DataPathTrace()
    with tempfile.TemporaryDirectory() as tmp:
        sys.setprofile(trace)
        try:
            (result,) = run_scenario(scenario, Path(tmp), progress=False, kind="native" if args.native else None)
        finally:
            sys.setprofile(None)
    print(f"{args.scenario}:{args.case} -> {result.status}")
    print(trace.report())
    return 0


if __name__ == "__main__":
    sys.exit(main())
