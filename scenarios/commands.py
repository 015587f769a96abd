"""What each command of ``python -m scenarios`` does once its arguments are parsed (:mod:`scenarios.__main__`
parses them and maps the errors to exit codes): run, list, export-ssp, results-page; sweep and score hand on to
their packages, an ILC scenario to :mod:`scenarios.ilc`."""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

from scenarios.config import (
    SCENARIO_DIR,
    ScenarioError,
    check_size,
    list_scenarios,
    load_scenario,
    parse_assignment,
    select_cases,
)
from scenarios.run.fmus import check_kind
from scenarios.run.outdir import describe_os_error
from scenarios.run.paper import paper_columns
from scenarios.run.runner import format_table, run_scenario

#: Exit codes (docs/outcomes.md; :mod:`scenarios.__main__` maps the errors to them).
EXIT_OK, EXIT_ERROR, EXIT_REFUSED, EXIT_OUTPUT, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 3, 130, 143
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a writer whose reader left
EXIT_STDOUT = 4  # the results were written, but standard output could not take the table (e.g. /dev/full)


class StdoutUnwritable(Exception):
    """Standard output refused what we printed (not a broken pipe): the results already written stay."""

    def __init__(self, exc: OSError, written: list[Path]):
        super().__init__(describe_os_error(exc))
        self.written = written


def say_error(text: str) -> None:
    """A message on standard error; nothing if standard error cannot take it (``2>/dev/full``)."""
    try:
        print(text, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def dispatch(args) -> int:
    """Run the parsed command (every command but ``conformance``, which parses its own line)."""
    commands = {"run": run_command, "list": list_command, "sweep": sweep_command, "score": score_command,
                "export-ssp": export_ssp_command, "results-page": results_page_command}
    return commands[args.command](args)


def sweep_command(args) -> int:
    """``sweep``: :mod:`scenarios.sweep`."""
    from scenarios.sweep import cli as sweep_cli

    return sweep_cli(args)


def score_command(args) -> int:
    """``score``: :mod:`scenarios.score`."""
    from scenarios.score.cli import main as score_main

    return score_main(args)


def export_ssp_command(args) -> int:
    """``export-ssp``: one SSP package per case."""
    from scenarios.conformance.ssp import SSPExportError, export_ssp

    try:
        paths = export_ssp(load_scenario(args.scenario), args.out, args.fmu_dir, cases=args.case, kind=args.kind,
                           native_fmu_dir=args.native_fmu_dir)
    except SSPExportError as exc:
        say_error(f"error: {exc}")
        return EXIT_REFUSED
    for key, path in paths.items():
        print(f"{key}: {path}")
    return EXIT_OK


def results_page_command(args) -> int:
    """``results-page [--check]``."""
    from scenarios.reports import results_page

    try:
        return _results_page(results_page, args)
    except results_page.ResultsPageError as exc:
        say_error(f"error: {exc}")
        return EXIT_ERROR


def list_command(args) -> int:
    """``list``: the shipped scenarios."""
    for s in list_scenarios():
        print(f"{s.name:16s} {len(s.cases)} cases  {s.description}")
    return EXIT_OK


def run_command(args) -> int:
    """``run``: check every scenario named, then run them one after the other and print their tables."""
    names = [s.name for s in list_scenarios()] if args.scenarios == ["all"] else args.scenarios
    # scenarios with an [ilc] table repeat a case and learn between trials (scenarios/ilc/)
    from scenarios.ilc.scenario import is_ilc_scenario, load_ilc
    from scenarios.ilc.trials import cli as ilc_cli

    if args.scenarios != ["all"] and any(is_ilc_scenario(n) for n in names):
        if len(names) != 1:
            raise ScenarioError(f"run: an ILC scenario runs alone, got {names}")
        for n in names:
            load_ilc(n)
        args.scenario_name = names[0]
        return ilc_cli(args)
    skipped = [n for n in names if is_ilc_scenario(n)]
    if skipped:  # `all`: the single-run scenarios; an ILC scenario runs alone
        say_error(f"run all: not running the ILC scenario{'s' * (len(skipped) > 1)} {', '.join(skipped)} "
                  f"(each runs alone: python -m scenarios run {skipped[0]})")
    names = [n for n in names if n not in skipped]
    controller, overrides = _controller_arg(args.controller), _overrides(args.sets)
    scenarios = [select_cases(load_scenario(name), args.cases) for name in names]  # all refused before any runs
    for sc in scenarios:
        sc.allow_large = args.allow_large
        check_size(sc)  # the number of cases now; the steps per case once the trajectory is read (run_length)
    kinds = [check_kind(sc, args.kind, controller) for sc in scenarios]  # and every FMU without that kind
    paper = tomllib.loads((SCENARIO_DIR / "paper_tables.toml").read_text())
    code = EXIT_OK
    written: list[Path] = []
    progress = not args.quiet
    for sc, kind in zip(scenarios, kinds):
        results = run_scenario(sc, args.out, args.fmu_dir, controller, progress=progress,
                               plots=not args.no_plots, kind=kind, native_fmu_dir=args.native_fmu_dir,
                               overrides=overrides, isolate=args.isolate, step_timeout=args.step_timeout)
        written.append(args.out / sc.name)
        columns = paper_columns(sc, overrides, paper)  # by the parameters run, not by the case's key
        lines = [f"\n== {sc.name}: {sc.description} [{kind} FMUs]",
                 format_table(results, {k: col for k, (_, col) in columns.items()} if sc.paper_table else None)]
        for r in results:
            if sc.paper_table and r.key not in columns:
                lines.append(f"   {r.key}: no paper column: no case of the paper's {sc.paper_table} has the "
                             "parameters this run used")
            elif sc.paper_table and columns[r.key][0] != r.key:
                lines.append(f"   {r.key}: the paper column is the paper's case {columns[r.key][0]}, whose "
                             "parameters this run used")
            if r.status != "ok":
                lines.append(f"   {r.key}: {r.status} ({r.message})")
            lines += [f"   {r.key}: warning: {w}" for w in r.warnings]
            if r.status == "error":
                code = EXIT_ERROR
        lines.append("   wall time per case: " + ", ".join(f"{r.key} {r.wall_time_s:.2f} s" for r in results))
        lines.append(f"   results: {args.out / sc.name}")
        try:
            print("\n".join(lines), flush=True)
        except BrokenPipeError:
            raise
        except OSError as exc:
            raise StdoutUnwritable(exc, written) from exc
    return code


def _controller_arg(value: str | None) -> str | None:
    """``--controller``: a project FMU name as it is; a .fmu path made absolute against the current directory
    (a path in a scenario file's [fmus] resolves against the scenario file instead)."""
    if value is None or not value.endswith(".fmu"):
        return value
    return str(Path(value).expanduser().resolve())


def _overrides(sets: list[str]) -> dict[str, dict]:
    """``--set`` arguments as {instance: {variable: value}} (:func:`scenarios.config.parse_assignment`)."""
    out: dict[str, dict] = {}
    for text in sets:
        inst, var, value = parse_assignment(text)
        out.setdefault(inst, {})[var] = value
    return out


def _results_page(results_page, args) -> int:
    if args.check:
        diffs = results_page.check(args.fmu_dir, progress=True)
        for d in diffs:
            print(d)
        print("results page: " + ("differs from a fresh run (rerun python -m scenarios results-page)"
                                  if diffs else "matches a fresh run"))
        return EXIT_ERROR if diffs else EXIT_OK
    for path in results_page.write(args.fmu_dir):
        print(f"wrote {path}")
    return EXIT_OK


