"""Run an exported scenario (``.ssp``, see :mod:`scenarios.conformance.ssp`) in libcosim, a second, independent FMI
master.

libcosim is the Open Simulation Platform's co-simulation library (C++), used
here through its Python binding libcosimpy. :func:`run_case_libcosim` loads the
archive of one case (:func:`scenarios.conformance.ssp.export_ssp` writes one per case; its
FMUs default to the case's values and its parameter bindings say the same), observes the requested variables with
a time-series observer and steps the whole run.

How libcosim's fixed-step algorithm exchanges values (libcosim 0.11,
``fixed_step_algorithm.cpp`` and ``slave_simulator.cpp``), which is what our
master's ``algorithm="jacobi"`` has to reproduce:

* **Initialisation.** Every FMU: ``fmi2SetupExperiment``,
  ``fmi2EnterInitializationMode``, then its outputs are read. Then N rounds (N =
  the number of FMUs): every FMU gets its pending values set (in round 1 the
  parameter set, unless this libcosim version set it before
  ``fmi2SetupExperiment``; then the connected inputs of the previous round),
  its outputs are read; then every connection copies source output → target
  input (buffered, set in the next round). So the start values propagate through the chain inside
  initialisation mode: plant(0) → sensors → controller. Finally every FMU gets
  its pending inputs set, ``fmi2ExitInitializationMode``, outputs read, and the
  connections copy once more. The first torque the plant steps with is thus the
  controller's output read right after its exit from initialisation.
* **Each step** t_k → t_k + h, all FMUs alike (in any order, by default on
  worker threads): set the inputs buffered by the last transfer, ``fmi2DoStep``, read
  the outputs. After all FMUs have stepped: copy every connection's source value
  to the target's buffer. Outputs are read only right after ``fmi2DoStep`` (and
  never after the inputs of the same communication point are set), so an output
  of a direct-feedthrough FMU at t_k + h is computed from the inputs it stepped
  with at t_k: one step of delay per FMU in the chain (plant → sensors →
  controller → plant: the torque applied over [t_k, t_k + h) comes from the
  plant state at t_(k-2)).
* **Observed values** (the observer) are these cached outputs: at step 0 the
  ones read after ``fmi2ExitInitializationMode``, at step k those read after the
  k-th ``fmi2DoStep``.
* **Time.** libcosim counts time in integer nanoseconds and passes
  ``currentCommunicationPoint`` = t_k = (k · 1 000 000 ns) / 1e9, correctly
  rounded, and ``communicationStepSize`` = t_(k+1) − t_k computed in doubles
  (``to_double_duration``), which is 0.0009999999999999992 rather than 0.001
  for most k ≥ 8. Our plant integrates over exactly the h it is given, so a
  master that passes h = 0.001 differs from libcosim in the last bit from
  step 9 on.

**Threads.** By default libcosim steps the FMUs on a pool of worker threads
(one per core; idle workers spin). Our FMUs run Python under the GIL, so
threads gain nothing: a full Table 2 slew takes 2.0-2.3 s with libcosim's
default pool and 1.5-1.8 s without. With an earlier build of our FMUs, a
process that had stepped them on worker threads aborted at exit about one run
in ten (heap corruption, glibc's "corrupted double-linked list"; none in 20
runs without worker threads; the current build: none in 20 either way).
:func:`run_case_libcosim` therefore sets ``numWorkerThreads="0"`` in the
selected SSD by default: libcosim then makes every FMU call on the calling thread (ctypes releases the GIL for
``cosim_execution_step``, pythonfmu takes it back for each call).
``worker_threads=None`` keeps libcosim's default.
"""

from __future__ import annotations

import ctypes
import io
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
from lxml import etree

from flexarm.signals import names as signal_names
from scenarios.conformance.ssp import DEFAULT_SSD, NS, SSPExportError
from scenarios.master.compat import libcosim_last_error, libcosim_real_samples_reader

NANO = 1_000_000_000


class LibcosimError(RuntimeError):
    """libcosim refused the archive, or a step failed."""


def _import_libcosimpy():
    try:
        from libcosimpy.CosimEnums import CosimVariableType
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimObserver import CosimObserver
    except (ImportError, OSError) as exc:  # OSError: the bundled libcosimc.so does not load
        raise LibcosimError(f"libcosimpy is not available ({exc}); pip install libcosimpy") from exc
    return CosimExecution, CosimObserver, CosimVariableType


def _quiet_logging() -> None:
    """libcosim logs at debug level by default (every FMI call): warnings and errors only."""
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level

    log_output_level(CosimLogLevel.WARNING)


def _last_error() -> str:
    return libcosim_last_error()


def default_record(ssd: bytes) -> list[tuple[str, str]]:
    """The plant's state and tip outputs and the torques (signal catalogue): what the table metrics need.

    The plant is the component whose input ``tau1`` is connected; the driver (controller) its source.
    """
    doc = etree.parse(io.BytesIO(ssd))
    for c in doc.iterfind("ssd:System/ssd:Connections/ssd:Connection", NS):
        if c.get("endConnector") == "tau1":
            plant, driver = c.get("endElement"), c.get("startElement")
            break
    else:
        raise SSPExportError("no connection drives an input 'tau1' (the plant's torque)")
    return [(plant, v) for v in signal_names("plant", "output", ("state", "tip"))] + \
        [(driver, v) for v in signal_names("controller", "output", indices=False)]


def _prepare_ssd(ssd: bytes, worker_threads: int | None) -> tuple[bytes, float, float]:
    """The SSD with libcosim's worker-thread count set; also its step size and run length."""
    doc = etree.parse(io.BytesIO(ssd))
    algo = doc.find("ssd:DefaultExperiment/ssd:Annotations/ssc:Annotation/osp:Algorithm/osp:FixedStepAlgorithm", NS)
    exp = doc.find("ssd:DefaultExperiment", NS)
    if algo is None or exp is None or exp.get("stopTime") is None:
        raise SSPExportError("the SSD has no DefaultExperiment stopTime / osp:FixedStepAlgorithm baseStepSize")
    if worker_threads is not None:
        algo.set("numWorkerThreads", str(int(worker_threads)))
    return etree.tostring(doc, xml_declaration=True, encoding="UTF-8"), float(algo.get("baseStepSize")), \
        float(exp.get("stopTime")) - float(exp.get("startTime", 0.0))


def run_case_libcosim(ssp_path: str | Path, n_steps: int | None = None,
                      record: list[tuple[str, str]] | list[str] | None = None,
                      worker_threads: int | None = 0) -> dict:
    """Run one case of an exported scenario in libcosim.

    Parameters
    ----------
    ssp_path : path
        A case's archive, written by :func:`scenarios.conformance.ssp.export_ssp`.
    n_steps : int, optional
        Communication steps (default: the SSD's DefaultExperiment, i.e. the scenario's run length).
    record : list of (instance, variable) or "instance.variable", optional
        Real variables to observe (default :func:`default_record`).
    worker_threads : int or None
        libcosim's worker-thread count; 0 (the default) runs the FMUs on the calling
        thread, None leaves libcosim's default (see the module docstring).

    Returns
    -------
    dict
        ``time`` (n+1,) in s, ``signals`` {"instance.variable": ndarray (n+1,)}
        (sample 0 = after initialisation, sample k = after the k-th step), ``step_size``,
        ``step_wall_s``: wall time of the n steps alone (s; loading and initialisation excluded).
    """
    CosimExecution, CosimObserver, CosimVariableType = _import_libcosimpy()

    _quiet_logging()

    ssp_path = Path(ssp_path)
    ssd_name = DEFAULT_SSD
    with tempfile.TemporaryDirectory(prefix="flexarm-libcosim-") as tmp:
        unpacked = Path(tmp)
        with zipfile.ZipFile(ssp_path) as zf:
            zf.extractall(unpacked)
        ssd, h, duration = _prepare_ssd((unpacked / ssd_name).read_bytes(), worker_threads)
        (unpacked / ssd_name).write_bytes(ssd)
        n = int(round(duration / h)) if n_steps is None else int(n_steps)
        if record is None:
            record = default_record(ssd)
        record = [tuple(r.split(".", 1)) if isinstance(r, str) else tuple(r) for r in record]

        try:
            execution = CosimExecution.from_ssp_file(str(unpacked / ssd_name))
        except AssertionError as exc:
            raise LibcosimError(f"libcosim could not load {ssp_path} ({ssd_name}): {_last_error()}") from exc
        observer = CosimObserver.create_time_series(buffer_size=n + 1)
        execution.add_observer(observer)
        columns = []
        indices = {}
        for inst, var in record:
            if inst not in indices:
                idx = execution.slave_index_from_instance_name(inst)
                if idx is None:
                    raise LibcosimError(f"record: no component '{inst}' in {ssd_name}")
                refs = {v.name.decode(): (v.reference, v.type) for v in execution.slave_variables(idx)}
                indices[inst] = (idx, refs)
            idx, refs = indices[inst]
            if var not in refs or refs[var][1] != CosimVariableType.REAL.value:
                raise LibcosimError(f"record: {inst} has no Real variable '{var}'")
            if not observer.start_time_series(idx, refs[var][0], CosimVariableType.REAL):
                raise LibcosimError(f"record: cannot observe {inst}.{var}: {_last_error()}")
            columns.append((idx, refs[var][0]))

        t_step = time.perf_counter()
        stepped = execution.step(n)
        step_wall = time.perf_counter() - t_step
        if not stepped:
            status = execution.status()
            raise LibcosimError(f"{ssp_path.name}: stepping failed at t = {status.current_time / NANO:.3f} s: "
                                f"{_last_error()}")

        # libcosimpy's sample reader drops sample 0 (it counts step number 0 as "missing"): read directly.
        get_samples = libcosim_real_samples_reader()
        values = np.empty(n + 1)
        steps = np.empty(n + 1, dtype=np.int64)
        times = np.empty(n + 1, dtype=np.int64)
        as_ptr = np.ctypeslib.as_ctypes_type
        signals = {}
        times_s = None
        obs_ptr = ctypes.cast(observer.ptr(), ctypes.c_void_p)
        for (inst, var), (idx, ref) in zip(record, columns):
            got = get_samples(obs_ptr, idx, ref, 0, n + 1,
                              values.ctypes.data_as(ctypes.POINTER(as_ptr(np.float64))),
                              steps.ctypes.data_as(ctypes.POINTER(ctypes.c_int64)),
                              times.ctypes.data_as(ctypes.POINTER(ctypes.c_int64)))
            if got != n + 1 or not np.array_equal(steps, np.arange(n + 1)):
                raise LibcosimError(f"observer returned {got} samples of {inst}.{var}, expected steps 0..{n}")
            signals[f"{inst}.{var}"] = values.copy()
            if times_s is None:
                times_s = times / NANO
        del observer, execution  # free the FMUs before the unpacked files go
    return {"time": times_s, "signals": signals, "step_size": h, "step_wall_s": step_wall}


def main(argv=None) -> int:
    """``python -m scenarios.conformance.libcosim_runner SSP [--steps N] [--out FILE.csv|.npz]``: one case in
    libcosim."""
    import argparse
    import sys

    from scenarios.metrics import LABELS, METRICS, table_metrics
    from scenarios.results import write_csv
    from scenarios.run.setup import desired_states, desired_trajectory

    ap = argparse.ArgumentParser(prog="python -m scenarios.conformance.libcosim_runner",
                                 description="Run one case of an exported scenario (.ssp) in libcosim.")
    ap.add_argument("ssp", type=Path, help="a case's archive from `python -m scenarios export-ssp`, "
                    "e.g. build/ssp/table2/none.ssp")
    ap.add_argument("--steps", type=int, help="communication steps (default: the scenario's run length)")
    ap.add_argument("--out", type=Path, help="write the time series: .csv (as `scenarios run`) or .npz")
    ap.add_argument("--worker-threads", type=int, default=0,
                    help="libcosim worker threads (default 0: FMUs run on the calling thread; -1: libcosim's default)")
    args = ap.parse_args(argv)
    if not args.ssp.is_file():
        print(f"error: ssp: no such file {args.ssp} (write one with `python -m scenarios export-ssp SCENARIO`)",
              file=sys.stderr)
        return 2
    try:
        t0 = time.perf_counter()
        out = run_case_libcosim(args.ssp, args.steps,
                                worker_threads=None if args.worker_threads < 0 else args.worker_threads)
        wall = time.perf_counter() - t0
    except (LibcosimError, SSPExportError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    series = {"time": out["time"], **out["signals"]}
    if args.out is not None:
        if args.out.suffix == ".npz":
            args.out.parent.mkdir(parents=True, exist_ok=True)
            tmp = args.out.with_name(f".{args.out.name}.tmp.npz")
            np.savez(tmp, **series)
            tmp.replace(args.out)
        else:
            write_csv(args.out, series)
    print(f"{args.ssp}: {len(out['time']) - 1} steps of {out['step_size']} s in libcosim, "
          f"{wall:.2f} s wall time ({out['step_wall_s']:.3f} s stepping)")
    sig = out["signals"]
    plant = next((k.split(".")[0] for k in sig if k.endswith(".theta1")), None)
    driver = next((k.split(".")[0] for k in sig if k.endswith(".tau1")), None)
    if plant and driver and all(f"{plant}.omega{i}" in sig for i in range(1, 12)):
        desired = desired_states(desired_trajectory(), len(out["time"]), out["step_size"])
        theta = np.column_stack([sig[f"{plant}.theta{i}"] for i in range(1, 12)])
        omega = np.column_stack([sig[f"{plant}.omega{i}"] for i in range(1, 12)])
        tau = np.column_stack([sig[f"{driver}.tau1"], sig[f"{driver}.tau2"]])
        metrics = table_metrics(tau, theta, omega, desired["theta"], desired["omega"])
        for m in METRICS:
            print(f"   {LABELS[m]:32s} {metrics[m]:10.4f}")
    if args.out is not None:
        print(f"   series: {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
