"""Command line: ``python -m scenarios list | run NAME|PATH|all``."""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

from .config import SCENARIO_DIR, ScenarioError, list_scenarios, load_scenario
from .master import CoSimulationError
from .runner import DEFAULT_FMU_DIR, REPO, desired_states, desired_trajectory, format_table, run_scenario


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m scenarios", description="Run the paper's experiments on our FMUs.")
    sub = ap.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="list the shipped scenarios")
    run = sub.add_parser("run", help="run scenarios: table1, table2, table3, all, or a path to a scenario file")
    run.add_argument("scenarios", nargs="+")
    run.add_argument("--out", type=Path, default=REPO / "results", help="results folder (default: results/)")
    run.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR, help="where built FMUs live")
    run.add_argument("--controller", help="controller FMU to use instead of the scenario's (name or .fmu path)")
    run.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    run.add_argument("--quiet", action="store_true", help="no progress bars")
    sweep = sub.add_parser("sweep", help="run a sweep / Monte Carlo on Dask: a name in scenarios/sweeps/ or a file")
    sweep.add_argument("sweep", help="a sweep name in scenarios/sweeps/ (robustness, schedule) or a sweep file")
    sweep.add_argument("--out", type=Path, default=REPO / "results" / "sweeps",
                       help="results folder (default: results/sweeps/; the sweep writes into OUT/<name>/)")
    sweep.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR, help="where built FMUs live")
    sweep.add_argument("--scheduler", help="address of a running Dask scheduler, e.g. tcp://host:8786")
    sweep.add_argument("--workers", type=int, help="local cluster: worker processes (default: the cores)")
    sweep.add_argument("--serial", action="store_true", help="run in this process, no Dask (debugging)")
    sweep.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    sweep.add_argument("--quiet", action="store_true", help="no progress bar")
    ssp = sub.add_parser("export-ssp", help="write a scenario's cases as SSP 1.0 packages (one .ssp per case)")
    ssp.add_argument("scenario", help="table1, table2, table3 or a path to a scenario file")
    ssp.add_argument("--out", type=Path, default=REPO / "build" / "ssp",
                     help="folder for <scenario>/<case>.ssp (default: build/ssp/)")
    ssp.add_argument("--case", action="append", help="export only this case (repeatable; default: all)")
    ssp.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR, help="where built FMUs live")
    args = ap.parse_args(argv)
    try:
        if args.command == "sweep":
            from .sweep import cli as sweep_cli

            return sweep_cli(args)
        if args.command == "export-ssp":
            from .ssp import SSPExportError, export_ssp

            try:
                paths = export_ssp(load_scenario(args.scenario), args.out, args.fmu_dir, cases=args.case)
            except SSPExportError as exc:
                print(f"error: {exc}", file=sys.stderr)
                return 2
            for key, path in paths.items():
                print(f"{key}: {path}")
            return 0
        if args.command == "list":
            for s in list_scenarios():
                print(f"{s.name:16s} {len(s.cases)} cases  {s.description}")
            return 0
        names = [s.name for s in list_scenarios()] if args.scenarios == ["all"] else args.scenarios
        paper = tomllib.loads((SCENARIO_DIR / "paper_tables.toml").read_text())
        for name in names:
            sc = load_scenario(name)
            results = run_scenario(sc, args.out, args.fmu_dir, args.controller, progress=not args.quiet)
            print(f"\n== {sc.name}: {sc.description}")
            print(format_table(results, paper.get(sc.paper_table) if sc.paper_table else None))
            for r in results:
                if r.status != "ok":
                    print(f"   {r.key}: unbounded ({r.message})")
            print("   wall time per case: " + ", ".join(f"{r.key} {r.wall_time_s:.2f} s" for r in results))
            if not args.no_plots:
                from .plots import plot_scenario

                traj = desired_trajectory()
                desired = desired_states(traj, len(results[0].series["time"]), sc.step_size)
                pngs = plot_scenario(sc.name, results, desired, traj, "plant", "controller", args.out / sc.name)
                print("   plots: " + ", ".join(str(p) for p in pngs))
            print(f"   results: {args.out / sc.name}")
        return 0
    except (ScenarioError, CoSimulationError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
