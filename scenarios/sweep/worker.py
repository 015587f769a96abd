"""Running sweep points: on Dask workers or in-process.

The client reads the FMU files once and a worker plugin (:class:`ShipFmus`) writes their bytes into a
content-addressed folder on every worker (also on workers that join or restart later); each process keeps
one loaded :class:`~scenarios.master.cosim.Master` per FMU set (reset between runs by ``fmi2Reset``).
A point's record carries the run's typed outcome (:class:`scenarios.master.cosim.Outcome`): its status is
``ok``, ``unbounded`` or ``error``, decided from the FMI status the master received, never from log text.
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
import tempfile
import threading
import time
import weakref
from collections import OrderedDict
from collections.abc import Iterator
from pathlib import Path

from distributed import WorkerPlugin

from flexarm.provenance import sha256_bytes, sha256_file, write_atomic
from scenarios.analysis.stability import loop_stability
from scenarios.master.cosim import CoSimulationError
from scenarios.master.interrupts import DeferSignals
from scenarios.run.plan import plan_case
from scenarios.run.runner import simulate
from scenarios.run.setup import prepare

from .plan import Plan, Point

#: Per process: setup key -> (Setup, open Master), least recently used first.
_LOADED: OrderedDict[str, tuple] = OrderedDict()
#: How many FMU sets a process keeps loaded.
CACHE_SIZE = 4
_TRAJECTORY_SHA: list[str] = []
#: Held by the point running in this process. The loaded FMUs are one instance each and not reentrant: a
#: worker with several threads runs its points one at a time, and :func:`close_loaded` never frees FMUs that a
#: point is still stepping (a cancelled Dask task runs on in its thread; freeing its FMUs under it corrupted
#: the worker's heap: "malloc(): unaligned tcache chunk detected" after a Ctrl-C in CI).
_BUSY = threading.Lock()
#: Set by :func:`close_loaded`: the running point stops at its next progress call (every 1 % of its steps).
_STOP = threading.Event()
#: Seconds :func:`close_loaded` waits for the running point to stop (it does within 1 % of its steps; longer
#: only when an FMU call hangs: its FMUs are then left to the process's exit).
STOP_WAIT_S = 10.0


class PointStopped(Exception):
    """The sweep is closing: the running point stopped part-way (its record is never used)."""


def _fmu_cache_dir() -> Path:
    return Path(os.environ.get("FLEXARM_SWEEP_FMU_CACHE", Path(tempfile.gettempdir()) / "flexarm-sweep-fmus"))


def _fmu_file(name: str, sha: str) -> Path:
    """Where the FMU with this SHA-256 lives in this machine's content-addressed cache."""
    return _fmu_cache_dir() / sha[:32] / f"{Path(name).stem}.fmu"


def store_fmus(names: dict[str, str], blobs: dict[str, bytes]) -> dict[str, str]:
    """Write FMU bytes into the content-addressed cache (once); instance -> SHA-256."""
    shas = {}
    for inst, data in blobs.items():
        sha = sha256_bytes(data)
        p = _fmu_file(names[inst], sha)
        if not (p.is_file() and p.stat().st_size == len(data)):
            _remove_stale_tmp(p.parent)
            write_atomic(p, data)
        shas[inst] = sha
    return shas


#: A temporary file older than this in the FMU cache was left by a killed writer (a write takes < 1 s).
STALE_TMP_S = 600.0


def _remove_stale_tmp(folder: Path) -> None:
    """Remove ``.*.tmp`` files a killed process left in `folder` (not a concurrent writer's: by age)."""
    if not folder.is_dir():
        return
    now = time.time()
    for tmp in folder.glob(".*.tmp"):
        try:
            if now - tmp.stat().st_mtime > STALE_TMP_S:
                tmp.unlink()
        except FileNotFoundError:
            pass


class ShipFmus(WorkerPlugin):
    """Dask worker plugin: writes one FMU set's files into every worker's cache, also on workers that
    join or restart later (registered with ``Client.register_plugin``)."""

    idempotent = True

    def __init__(self, names: dict[str, str], blobs: dict[str, bytes]):
        self.names, self.blobs = names, blobs

    def setup(self, worker=None) -> None:
        store_fmus(self.names, self.blobs)

    def teardown(self, worker=None) -> None:
        pass


def _loaded(task: dict):
    key = task["setup_key"]
    if key in _LOADED:
        _LOADED.move_to_end(key)
        return _LOADED[key]
    while len(_LOADED) >= CACHE_SIZE:
        _, (_, old) = _LOADED.popitem(last=False)
        old.close()
    paths = {}
    for inst, sha in task["fmu_sha256"].items():
        p = _fmu_file(task["fmu_names"][inst], sha)
        if not p.is_file():
            raise CoSimulationError(f"fmus.{inst}: {p} missing on this worker (the client ships FMUs with a "
                                    "worker plugin: was the sweep started through scenarios.sweep?)")
        paths[inst] = str(p)
    setup = prepare(task["scenario"], names=paths, build=False, **task.get("where", {}), isolate=task["isolate"],
                    step_timeout=task["step_timeout"], named_as=task["fmu_names"])  # foreign as named, not cached
    m = setup.open_master()
    _LOADED[key] = (setup, m)
    return setup, m


def close_loaded(wait: float = STOP_WAIT_S) -> int:
    """Close every FMU set this process keeps loaded, after stopping the point that runs on them, if any.

    Returns how many were closed; -1 when a point did not stop within `wait` seconds (an FMU call that hangs):
    its FMUs are then left open, to be freed with the process.
    """
    _STOP.set()
    if not _BUSY.acquire(timeout=wait):
        return -1
    try:
        n = len(_LOADED)
        while _LOADED:
            _, (_, m) = _LOADED.popitem(last=False)
            m.close()
        return n
    finally:
        _STOP.clear()
        _BUSY.release()


def _stop_requested(k: int, n: int) -> None:
    if _STOP.is_set():
        raise PointStopped(f"stopped at step {k} of {n}: the sweep is closing")


def run_point(task: dict) -> dict:
    """Run one point (on a worker or in-process) and return its journal record; never raises.

    Parameters
    ----------
    task : dict
        From :meth:`Plan.task`. The FMU files must be in this machine's cache
        (:func:`store_fmus`, done on Dask workers by :class:`ShipFmus`).

    Returns
    -------
    dict
        ``key``, ``index``, ``status`` (ok, unbounded or error), ``message``, ``outcome`` (the details:
        when and which signal diverged; which FMU, function, FMI status and FMU message),
        ``metrics`` (None unless ok), ``wall_time_s`` (the run), ``setup_time_s``
        (loading the FMUs, 0 when they were loaded), ``steps_done``, ``worker``
        (host:pid), ``fmu_sha256``, ``trajectory_sha256``; when the point ran, ``warnings`` and
        ``loop_stability`` as a scenario run's case JSON (:func:`scenarios.analysis.stability.loop_stability`).
    """
    t0 = time.perf_counter()
    rec = {"key": task["key"], "index": task["index"], "status": "error", "message": "", "metrics": None,
           "wall_time_s": 0.0, "setup_time_s": 0.0, "steps_done": 0, "worker": f"{socket.gethostname()}:{os.getpid()}",
           "fmu_sha256": task["fmu_sha256"]}
    with _BUSY:
        return _run_point(task, rec, t0)


def _run_point(task: dict, rec: dict, t0: float) -> dict:
    try:
        fresh = task["setup_key"] not in _LOADED
        setup, m = _loaded(task)
        t1 = time.perf_counter()
        rec["setup_time_s"] = t1 - t0 if fresh else 0.0
        if not _TRAJECTORY_SHA:
            from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE

            _TRAJECTORY_SHA.append(sha256_file(DEFAULT_TRAJECTORY_FILE))
        case = plan_case(setup, task["key"], task["key"], task["parameters"])  # checked once, as a run's case
        out, metrics = simulate(setup, m, case.parameters, progress=_stop_requested)
        rec["wall_time_s"] = time.perf_counter() - t1
        outcome = out["outcome"]
        rec.update(status=outcome.status, message=outcome.message, outcome=outcome.as_dict(), metrics=metrics,
                   steps_done=out["steps_done"])
        # a point whose loop grows in a way its plant scheme cannot show says so, as a scenario run does
        stab = loop_stability(setup.paths, setup.plant, setup.driver, case.parameters,
                              setup.scenario.step_size, setup.n_steps * setup.scenario.step_size,
                              setup.scenario.algorithm, metrics=metrics)
        rec.update(warnings=list(out.get("warnings", [])) + ([stab["note"]] if stab and stab["note"] else []),
                   loop_stability=stab)
    except Exception as exc:  # noqa: BLE001 - recorded against the point, never fatal to the sweep
        rec.update(status="error", message=f"{type(exc).__name__}: {exc}", wall_time_s=time.perf_counter() - t0)
        if not isinstance(exc, CoSimulationError) and task["setup_key"] in _LOADED:
            _LOADED.pop(task["setup_key"])[1].close()
    rec["trajectory_sha256"] = _TRAJECTORY_SHA[0] if _TRAJECTORY_SHA else None
    return rec


def iter_serial(plan: Plan, points: list[Point]) -> Iterator[dict]:
    """Run `points` one after the other in this process (FMUs loaded once per FMU set)."""
    for k in {plan.point_set[p.key] for p in points}:
        store_fmus(plan.fmu_sets[k].names, plan.fmu_sets[k].blobs)
    for p in points:
        yield run_point(plan.task(p))


#: Seconds between two looks at the finished points (and at a deferred Ctrl-C) while waiting for them.
POLL_S = 0.05


def _completed(futures) -> Iterator:
    """The futures of a :class:`distributed.as_completed` as they finish, with Ctrl-C and SIGTERM deferred to
    the waits between them (:class:`~scenarios.master.interrupts.DeferSignals`).

    A KeyboardInterrupt raised inside Dask's ``sync`` before its coroutine started makes Dask's own cancel
    callback fail (a NameError that tornado logs with a traceback, seen in CI after a Ctrl-C): here the signal
    is acted on only in this loop, outside every Dask call.
    """
    with DeferSignals() as interrupted:
        while True:
            batch = futures.next_batch(block=False)
            if not batch and futures.is_empty():
                return
            for fut in batch:
                interrupted.raise_pending("while the sweep's points ran")
                yield fut
            interrupted.raise_pending("while the sweep's points ran")
            if not batch:
                time.sleep(POLL_S)


def local_cluster(n_workers: int | None = None, allowed_failures: int = 1):
    """A :class:`distributed.LocalCluster` for sweeps: processes, one thread each.

    Parameters
    ----------
    n_workers : int, optional
        Worker processes (default: the machine's cores).
    allowed_failures : int
        How often the scheduler retries a point whose worker died before it
        marks it lost (recorded as ``error``, naming KilledWorker).

    Notes
    -----
    ``worker-saturation`` 1.0 keeps exactly one point per worker in flight,
    so a worker that dies takes only its own point with it; the workers'
    statistical profiler is off (it interrupts the co-simulation's thread).
    """
    import dask
    from distributed import LocalCluster

    _quiet_cancellations()
    with dask.config.set({"distributed.scheduler.allowed-failures": allowed_failures,
                          "distributed.scheduler.worker-saturation": 1.0,
                          # the statistical profiler takes the GIL every 10 ms from the running co-simulation
                          "distributed.worker.profile.enabled": False}):
        return LocalCluster(n_workers=n_workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                            dashboard_address=None)


#: Seconds a worker of our local cluster gets to exit by itself when the sweep ends (Dask's default, 4 s,
#: is shorter than a busy machine takes to finalise a process that loaded NumPy, SciPy, Numba and the FMUs:
#: its nanny then kills it with a warning).
WORKER_EXIT_TIMEOUT_S = 30.0


class _DropCancellations(logging.Filter):
    """Drop Dask's log records of a cancelled coroutine (e.g. a nanny's unregister cut short by our closing).

    Closing the cluster cancels what is still pending; under load a nanny can be half-way through telling the
    scheduler that its worker exited, and Dask logs that cancellation as an ERROR with a traceback (issue 35:
    a user saw a traceback after a one-line "disk full" message). A cancellation is not an error of the sweep;
    every other record (a worker killed, a point lost) still reaches the user.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        return not isinstance(exc, asyncio.CancelledError)


_DROP_CANCELLATIONS = _DropCancellations()


class _DropOwnCloseHeartbeat(logging.Filter):
    """Drop a worker's "Failed to communicate with scheduler during heartbeat" while that worker is closing.

    Dask's ``Worker.close`` stops the heartbeat's timer and then closes its connections, but a heartbeat
    already on the wire is cut by that close, and the worker logs it as an ERROR with a traceback (CI under
    load, a SIGTERM sweep: the sweep exited 143 as it should, with a Dask traceback on stderr). A heartbeat
    that fails while the worker is running (the scheduler lost) is still logged.
    """

    def __init__(self, worker):
        super().__init__()
        self._worker = weakref.ref(worker)

    def filter(self, record: logging.LogRecord) -> bool:
        if not (record.name == "distributed.worker" and record.msg == _HEARTBEAT_FAILED and record.exc_info
                and isinstance(record.exc_info[1], OSError)):
            return True
        worker = self._worker()
        return worker is None or worker.status.name not in _CLOSING


_HEARTBEAT_FAILED = "Failed to communicate with scheduler during heartbeat."
_CLOSING = frozenset({"closing", "closing_gracefully", "closed"})


class QuietClose(WorkerPlugin):
    """Dask worker plugin: a worker's own closing is not reported as an error (:class:`_DropOwnCloseHeartbeat`,
    :class:`_DropCancellations`), on the handlers of the worker's process."""

    idempotent = True

    def setup(self, worker=None) -> None:
        filters = [_DROP_CANCELLATIONS] + ([_DropOwnCloseHeartbeat(worker)] if worker is not None else [])
        _add_to_dask_handlers(filters)

    def teardown(self, worker=None) -> None:
        pass  # the filters stay: the worker's close, which they are for, comes after the sweep unregisters us


def _quiet_cancellations() -> None:
    _add_to_dask_handlers([_DROP_CANCELLATIONS])


def _add_to_dask_handlers(filters: list[logging.Filter]) -> None:
    # On the handlers that Dask's records reach (its own, or the root's when a host configured logging first):
    # a logger's own filters do not see the records its children propagate to it.
    log: logging.Logger | None = logging.getLogger("distributed")
    while log is not None:
        for handler in log.handlers:
            for f in filters:
                if f not in handler.filters:
                    handler.addFilter(f)
        log = log.parent if log.propagate else None


def close_local_cluster(cluster, timeout: float = WORKER_EXIT_TIMEOUT_S) -> None:
    """Close a :func:`local_cluster`: each worker asked to exit and given `timeout` seconds, then the cluster."""
    import asyncio

    async def close_workers():
        await asyncio.gather(*(w.close(timeout=timeout) for w in list(cluster.workers.values())),
                             return_exceptions=True)

    try:
        cluster.sync(close_workers)
    finally:
        cluster.close()


def iter_dask(client, plan: Plan, points: list[Point]) -> Iterator[dict]:
    """Submit `points` to a Dask cluster and yield their records as they complete.

    The FMU files go to every worker through a worker plugin (:class:`ShipFmus`),
    so the tasks carry no data and the scheduler queues them (one point in
    flight per worker thread on our local cluster: a worker that dies takes
    only its own point with it). A point whose worker died, or any other
    error outside :func:`run_point`, comes back as an ``error`` record naming it.
    """
    from distributed import as_completed

    needed = sorted({plan.point_set[p.key] for p in points})
    client.register_plugin(QuietClose(), name="flexarm-sweep-quiet-close")
    plugins = ["flexarm-sweep-quiet-close"]
    for k in needed:
        name = f"flexarm-sweep-fmus-{k}"
        client.register_plugin(ShipFmus(plan.fmu_sets[k].names, plan.fmu_sets[k].blobs), name=name)
        plugins.append(name)
    # Points of one FMU set together (Dask runs earlier tasks first): workers rarely switch FMU sets.
    order = sorted(points, key=lambda p: (plan.point_set[p.key], p.index))
    stamp = time.time_ns()
    # One batch (client.map): the scheduler sees the whole group and queues it instead of spreading it.
    futures = client.map(run_point, [plan.task(p) for p in order], pure=False,
                         key=[f"sweep-point-{p.key}-{stamp}" for p in order])
    point_of = {fut.key: p for fut, p in zip(futures, order)}
    completed = _completed(as_completed(futures))
    try:
        for fut in completed:
            p = point_of[fut.key]
            if fut.status == "finished":
                rec = fut.result()
            else:
                try:
                    exc = fut.exception()
                except Exception as e:  # noqa: BLE001 - e.g. cancelled
                    exc = e
                rec = {"key": p.key, "index": p.index, "status": "error",
                       "message": f"{type(exc).__name__}: {exc}", "metrics": None, "wall_time_s": 0.0,
                       "setup_time_s": 0.0, "steps_done": 0, "worker": None,
                       "fmu_sha256": plan.fmu_sets[plan.point_set[p.key]].sha256, "trajectory_sha256": None}
            fut.release()
            yield rec
    finally:
        completed.close()  # the signal handlers as they were before the wait
        pending = [f for f in futures if not f.done()]
        if pending:
            client.cancel(pending, force=True)
        for name in plugins:
            try:
                client.unregister_worker_plugin(name)
            except Exception:  # noqa: BLE001 - the cluster may be gone
                pass

