"""The battery of one controller, on Dask (a local cluster, or a scheduler's address) or in this process."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from . import battery


def prepare_fmus(controller: battery.Controller, kind: str, fmu_dir: Path, native_fmu_dir: Path) -> None:
    """Build (when needed) and check the FMUs once, here, before workers load them: an unknown name, a file
    that is no FMU or a value the controller does not take is refused now (ScenarioError), not on a worker."""
    from scenarios.run.setup import check_overrides, prepare

    from ..config import load_scenario

    setup = prepare(load_scenario("table2"), fmu_dir, controller.fmu, build=True, kind=kind,
                    native_fmu_dir=native_fmu_dir)
    if controller.parameters:
        check_overrides(setup, {"controller": {**controller.parameters, **controller.jacobi_parameters}})


def _say(text: str) -> None:
    try:
        print(text, file=sys.stderr, flush=True)
    except (OSError, ValueError):  # standard error unwritable: no reason to stop
        pass


def run_battery(controller: battery.Controller, kind: str, fmu_dir: Path, native_fmu_dir: Path,
                workers: int | None = None, scheduler: str | None = None, serial: bool = False,
                progress: bool = True) -> dict:
    """Every case of :func:`battery.cases` for `controller`.

    Returns
    -------
    dict
        ``cases``: case key -> :func:`battery.run_case`'s record (paper cases with their series);
        ``wall_time_s``; ``workers`` (0 in this process).
    """
    prepare_fmus(controller, kind, fmu_dir, native_fmu_dir)
    todo = battery.cases()
    args = [(c, controller, kind, str(Path(fmu_dir).resolve()), str(Path(native_fmu_dir).resolve()),
             c.group == "paper") for c in todo]
    t0 = time.perf_counter()
    done: dict[str, dict] = {}

    def report(rec: dict) -> None:
        done[rec["case"]] = rec
        if progress:
            g = f", growth {rec['growth_rate_per_s']:.3g} /s" if rec.get("growth_rate_per_s") else ""
            _say(f"score {controller.name}: [{len(done):2d}/{len(todo)}] {rec['case']:14s} {rec['status']}{g}")

    if serial:
        try:
            for a in args:
                report(battery.run_case(*a))
        finally:
            battery.close_all()
        return {"cases": {c.key: done[c.key] for c in todo}, "wall_time_s": time.perf_counter() - t0, "workers": 0}
    from distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        import os

        n = workers or min(len(os.sched_getaffinity(0)), 8)
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
    try:
        with Client(scheduler or cluster) as client:
            futures = [client.submit(battery.run_case, *a, pure=False) for a in args]
            for fut in as_completed(futures):
                report(fut.result())
            n_workers = len(client.scheduler_info()["workers"])
            if cluster is not None:  # free the workers' FMUs before the cluster stops them (else the nanny kills)
                client.run(battery.close_all)
    finally:
        if cluster is not None:
            cluster.close()
    return {"cases": {c.key: done[c.key] for c in todo}, "wall_time_s": time.perf_counter() - t0,
            "workers": n_workers}
