"""Running a sweep: plan, lock the folder, run the points not yet journaled, write the table and plots."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from flexarm.provenance import git_commit, package_version, write_json
from scenarios.master.cosim import RunInterrupted
from scenarios.master.fmu_proxy import DEFAULT_STEP_TIMEOUT_S
from scenarios.run.fmus import DEFAULT_FMU_DIR, DEFAULT_NATIVE_FMU_DIR
from scenarios.run.outdir import check_writable, folder_lock, remove_stale
from scenarios.run.setup import verify_data_chain

from ..results import portable
from .journal import DONE, STATUSES, Journal, table_columns, table_rows, write_table
from .plan import Plan, plan_sweep
from .report import Progress, _short, format_summary, summary_plots
from .spec import Sweep, SweepError, load_sweep
from .worker import close_loaded, close_local_cluster, iter_dask, iter_serial, local_cluster

#: Default results folder: relative to the current directory, so it works with any install.
DEFAULT_OUT_DIR = Path("results") / "sweeps"


@dataclass
class SweepResult:
    plan: Plan
    folder: Path
    rows: list[dict]
    ran: int  # points run by this call
    skipped: int  # points found done in the journal
    tables: list[Path]
    plots: list[Path]
    wall_time_s: float


def run_sweep(sweep: Sweep | str | Path, out_dir: Path = DEFAULT_OUT_DIR, fmu_dir: Path = DEFAULT_FMU_DIR, *,
              scheduler: str | None = None, workers: int | None = None, serial: bool = False,
              plots: bool = True, progress: bool = True, build: bool = True, allowed_failures: int = 1,
              on_record: Callable[[dict], None] | None = None, kind: str | None = None,
              native_fmu_dir: Path = DEFAULT_NATIVE_FMU_DIR, allow_large: bool = False, isolate: str = "foreign",
              step_timeout: float = DEFAULT_STEP_TIMEOUT_S) -> SweepResult:
    """Run every point of a sweep not yet in its journal; write the table and plots.

    Parameters
    ----------
    sweep : Sweep, str or Path
        A loaded sweep, a sweep name in ``scenarios/sweeps/`` or a path.
    out_dir : Path
        Results go to ``out_dir/<sweep name>/``: ``journal.jsonl``,
        ``<name>.csv`` (and ``.parquet``), ``sweep.json`` (provenance), PNGs.
        The folder is locked for the run (a second sweep into it is refused).
    fmu_dir : Path
        Where built FMUs live.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); the workers
        need this project installed. Default: a local cluster.
    workers : int, optional
        Worker processes of the local cluster (default: the machine's cores).
    serial : bool
        Run in this process, one point after the other (debugging).
    plots, progress : bool
        Write the summary PNGs; show the progress bar on stderr.
    build : bool
        Build stale FMUs first.
    allowed_failures : int
        Local cluster only: retries of a point whose worker died.
    on_record : callable, optional
        Called with each new journal record.
    kind : str, optional
        "python" or "native" FMUs (default: the scenario's ``kind``); native ones live in `native_fmu_dir`.
    allow_large : bool
        A sweep given by name or path may pass the caps on samples and points (:func:`load_sweep`).
    isolate, step_timeout
        Which FMUs run in a process of their own and how long one call may take (:func:`plan_sweep`): a point
        whose FMU crashes, hangs or exits is recorded as ``error`` and the sweep goes on.

    Returns
    -------
    SweepResult

    Raises
    ------
    SweepError
        Refused before any point ran (the field and its allowed values, or the FMU's message).
    RunInterrupted
        Ctrl-C: the points finished before it are in the journal (and the table); the interrupted
        ones are not, and a rerun runs them. The cluster is closed on this path and every other.
    """
    t_start = time.perf_counter()
    if not isinstance(sweep, Sweep):
        sweep = load_sweep(sweep, allow_large=allow_large)
    chain = verify_data_chain()
    kind = kind or sweep.scenario.kind
    plan = plan_sweep(sweep, fmu_dir, build, kind=kind, native_fmu_dir=native_fmu_dir, isolate=isolate,
                      step_timeout=step_timeout)
    out = Path(out_dir)
    folder = out / sweep.name
    with ExitStack() as stack:
        out.mkdir(parents=True, exist_ok=True)
        stack.enter_context(folder_lock(out, sweep.name))
        check_writable(folder)
        remove_stale(out, sweep.name, folder)
        for old in folder.glob("*.png"):  # regenerated from the journal at the end
            old.unlink()
        journal = Journal(folder / "journal.jsonl")
        records = journal.read()
        before = dict(records)
        done = {p.key for p in plan.points if records.get(p.key, {}).get("status") in DONE}
        todo = [p for p in plan.points if p.key not in done]
        commit = git_commit()
        mode = "serial" if serial else f"dask {scheduler or f'LocalCluster({workers or os.cpu_count()} workers)'}"
        meta = {
            "sweep": sweep.name, "description": sweep.description, "sweep_file": str(sweep.path),
            "sweep_sha256": sweep.sha256, "sweep_content_sha256": sweep.content_sha256,
            "scenario": sweep.scenario.name, "scenario_file": str(sweep.scenario.path),
            "scenario_content_sha256": plan.scenario_sha256, "base_case": sweep.case.key,
            "samples": sweep.scenario.samples,
            "axes": [{"field": a.field, "kind": a.kind, "values": a.values} for a in sweep.axes],
            "points": len(plan.points), "commit": commit, "version": package_version(), "execution": mode,
            "data_sha256": chain,
            "fmu_kind": kind,
            "fmu_sets": [{"fmus": fs.names, "fmu_sha256": fs.sha256} for fs in plan.fmu_sets.values()],
            "started_at": _now(), "journal": "journal.jsonl", "columns": table_columns(plan),
        }
        write_json(folder / "sweep.json", portable(meta, folder))
        bar = Progress(sweep.name, len(plan.points), len(done), progress)
        if progress and done:
            sys.stderr.write(f"{sweep.name}: {len(done)} of {len(plan.points)} points done in {journal.path}, "
                             f"{len(todo)} to run\n")
        unmatched = len(set(records) - {p.key for p in plan.points})
        if unmatched:  # say why points run again rather than rerun them silently
            sys.stderr.write(f"{sweep.name}: {unmatched} journal record(s) match no point of this sweep (other "
                             "parameters, scenario content, run length, FMU names or kind, or an older key scheme); "
                             "they are kept but not reused\n")
        if journal.problems():  # an edited line is never reported: its point runs again
            sys.stderr.write(f"{sweep.name}: {journal.problems()}; their points run again\n")
        other_build = sum(records[k].get("fmu_sha256") != plan.fmu_sets[plan.point_set[k]].sha256 for k in done)
        if other_build:
            sys.stderr.write(f"{sweep.name}: {other_build} point(s) in the journal ran on other FMU builds "
                             f"(fmu_sha256 columns); delete {journal.path} to run them again\n")
        ran = 0
        interrupted = None
        with ExitStack() as resources:  # closed in reverse order, each even when another one fails
            results = iter(())
            if todo:
                if serial:
                    resources.callback(close_loaded)
                    results = iter_serial(plan, todo)
                else:
                    from distributed import Client

                    # Callbacks run last-registered first: free the FMUs (and their unpacked folders) on the
                    # workers while the client is open, then close the client, then the local cluster, so
                    # that each worker exits by itself (not killed by its nanny after a timeout).
                    if scheduler:
                        client = Client(scheduler)
                        resources.callback(client.close)
                    else:
                        cluster = local_cluster(workers, allowed_failures)
                        resources.callback(close_local_cluster, cluster)
                        client = Client(cluster)
                        resources.callback(client.close)
                        resources.callback(_quietly, client.run, close_loaded)
                    results = iter_dask(client, plan, todo)
                resources.callback(journal.close)
                try:
                    for rec in results:
                        rec.update(commit=commit, finished_at=_now(), sweep_sha256=sweep.sha256)
                        journal.append(rec)
                        records[rec["key"]] = rec
                        ran += 1
                        bar.update(rec)
                        if on_record is not None:
                            on_record(rec)
                except (KeyboardInterrupt, SystemExit) as exc:  # Ctrl-C, SIGTERM (SystemExit(143)): the table
                    interrupted = exc  # is written from the journal before the exception goes on
                finally:
                    if hasattr(results, "close"):
                        results.close()  # a generator's finally cancels the pending futures
        if interrupted is not None:  # a Ctrl-C may fall between a record's append and its bookkeeping
            now = journal.read()
            ran = sum(now.get(p.key) is not None and now.get(p.key) != before.get(p.key) for p in todo)
            records = now
        rows = table_rows(plan, records)
        tables = write_table(folder / f"{sweep.name}.csv", table_columns(plan), rows)
        write_json(folder / "sweep.json", portable({**meta, "finished_at": _now(), "run_now": ran,
                                                    "from_journal": len(done), "interrupted": interrupted is not None,
                                                    "status_counts": {st: sum(r["status"] == st for r in rows)
                                                                      for st in STATUSES}}, folder))
        if isinstance(interrupted, SystemExit):
            raise interrupted
        if interrupted is not None:
            raise RunInterrupted(f"sweep {sweep.name}: interrupted after {ran} new point(s); "
                                 f"{len(rows)} of {len(plan.points)} in {journal.path}; rerun to resume") \
                from interrupted
        pngs = summary_plots(plan, rows, folder) if plots else []
    return SweepResult(plan, folder, rows, ran, len(done), tables, pngs, time.perf_counter() - t_start)


def _quietly(fn, *args) -> None:
    try:
        fn(*args)
    except Exception:  # noqa: BLE001 - e.g. the workers are gone already; the cluster is closed next
        pass


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def cli(args) -> int:
    """``python -m scenarios sweep``: run, then print the summary table and where the results are.

    Returns 0 when every point finished ok or unbounded, 1 when some ended with an error.
    """
    if args.serial and args.scheduler:
        raise SweepError("--serial and --scheduler: choose one")
    if args.workers is not None and (args.serial or args.scheduler):
        raise SweepError("--workers: only for the local cluster (not with --serial or --scheduler)")
    if args.workers is not None and args.workers < 1:
        raise SweepError(f"--workers: an integer >= 1, got {args.workers}")
    res = run_sweep(args.sweep, args.out, args.fmu_dir, scheduler=args.scheduler, workers=args.workers,
                    serial=args.serial, plots=not args.no_plots, progress=not args.quiet, kind=args.kind,
                    native_fmu_dir=args.native_fmu_dir, allow_large=args.allow_large, isolate=args.isolate,
                    step_timeout=args.step_timeout)
    counts = {s: sum(r["status"] == s for r in res.rows) for s in STATUSES}
    sw = res.plan.sweep
    print(f"\n== sweep {sw.name}: {sw.description}")
    print(f"   base: {sw.scenario.name}:{sw.case.key}, samples {sw.scenario.samples}; "
          f"{len(res.plan.points)} points ({res.ran} run now, {res.skipped} from the journal) in "
          f"{res.wall_time_s:.1f} s; ok {counts['ok']}, unbounded {counts['unbounded']}, error {counts['error']}")
    print(format_summary(res.plan, res.rows))
    for r in res.rows:
        if r["status"] == "error":
            print(f"   error #{r['index']} ({', '.join(_short(k, r[k]) for k in res.plan.points[0].values)}): "
                  f"{r['message'][:300]}")
    print("   table: " + ", ".join(str(p) for p in res.tables))
    if res.plots:
        print("   plots: " + ", ".join(str(p) for p in res.plots))
    return 1 if counts["error"] or len(res.rows) != len(res.plan.points) else 0
