"""Cost of one 1 ms plant step: the library call and the plant FMU driven by fmpy.

Prints, for the Numba kernels (this process) and the NumPy-only path
(a subprocess with FLEXARM_NO_NUMBA=1), the median cost per step in µs
after a warm-up, and the real-time factor (1 ms divided by that cost):

* library: ``flexarm.integrator.advance`` with the default substeps (2 per
  ms), for each integration scheme (``rodas4``, ``exponential``, ``gauss``,
  ``reference``), and Gauss at 4 and 32 substeps per ms (the settings
  docs/model.md quotes for its energy and bracket-mode accuracy);
* FMU: ``FMU2Slave.doStep`` plus ``getReal`` of all 40 outputs, the work a
  master does per communication step, for each scheme (``integrator`` 1-4).

* table2/none (native FMUs, closed loop) at communication steps of 1 and 4
  ms: its torques replayed through the library's error-controlled RODAS4
  (``flexarm._kernels.advance``) at the default settings, with the RODAS4
  substeps taken per ms of simulated time (nominal: 2; rejected substeps
  count) and the library's cost per ms of simulated time (issue 26 W1).

The reference (RK4 at 2.5 µs) costs about a hundred times RODAS4: it is timed
over fewer steps; the exponential scheme over at most 2.5 s of simulated time
(it refuses to run past 3 s).

``--write`` measures only docs/model.md's cost table (library, Python and native plant FMUs, per scheme) into
``docs/plant-step-cost.json`` with the date, commit, machine and load average, and renders the table from it
(:mod:`scenarios.reports.cost_doc`; ``python -m scenarios results-page --check`` checks the render, without re-timing).

Usage: ``python benchmarks/bench_plant_step.py [--write]`` (a few seconds, plus a
one-off Numba compile of about 20 s if the cache is cold; builds
``build/fmus/plant.fmu`` first if it is missing or stale).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DT = 1e-3


def _median_us(fn, n_warm: int, n: int) -> float:
    for _ in range(n_warm):
        fn()
    samples = []
    for _ in range(n):
        t0 = time.perf_counter_ns()
        fn()
        samples.append(time.perf_counter_ns() - t0)
    return statistics.median(samples) / 1e3


def measure(fmu_path: Path, n_lib: int, n_fmu: int) -> dict:
    """Median µs per step for the library call and for the FMU; dict with both and the backend."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    from flexarm import ArmModel, rigid_configuration
    from flexarm._kernels import HAVE_NUMBA
    from flexarm.integrator import DEFAULT_SUBSTEPS, INTEGRATORS, advance
    from flexarm.model import N

    model = ArmModel()
    tau = np.array([1.0, 0.3])
    state = {"z": np.concatenate([rigid_configuration(0.0, np.pi / 2), np.zeros(N)])}

    md = read_model_description(str(fmu_path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    out_vrs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    unzipped = extract(str(fmu_path))
    result = {"backend": "Numba" if HAVE_NUMBA else "NumPy", "n_outputs": len(out_vrs)}
    for integrator, substeps in (("gauss", 4), ("gauss", 32)):
        z0 = state["z"].copy()

        def lib_step_sub(integrator=integrator, substeps=substeps):
            state["z"], _ = advance(model, state["z"], tau, DT, substeps, integrator)

        n = max(20, n_lib // (4 * substeps))
        result[f"library_us/{integrator} {substeps}/ms"] = _median_us(lib_step_sub, max(5, n // 10), n)
        state["z"] = z0
    for code, integrator in enumerate(INTEGRATORS, start=1):
        z0 = state["z"].copy()
        scale = {"reference": 100, "exponential": 2}.get(integrator, 1)
        n_lib_s, n_fmu_s = max(20, n_lib // scale), max(20, min(n_fmu // scale, 2200))

        def lib_step(integrator=integrator):
            state["z"], _ = advance(model, state["z"], tau, DT, DEFAULT_SUBSTEPS, integrator)

        result[f"library_us/{integrator}"] = _median_us(lib_step, max(5, n_lib_s // 10), n_lib_s)
        state["z"] = z0
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                        instanceName=f"bench-{integrator}")
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.setInteger([vr["integrator"]], [code])
        fmu.exitInitializationMode()
        fmu.setReal([vr["tau1"], vr["tau2"]], tau.tolist())
        clock = {"t": 0.0}

        def fmu_step(fmu=fmu, clock=clock):
            fmu.doStep(clock["t"], DT)
            fmu.getReal(out_vrs)
            clock["t"] += DT

        result[f"fmu_us/{integrator}"] = _median_us(fmu_step, max(5, n_fmu_s // 10), n_fmu_s)
        fmu.terminate()
        fmu.freeInstance()
    return result


#: docs/model.md's cost table: (integrator, substeps per ms) per row, the JSON that ``--write`` measures into.
COST_ROWS = (("rodas4", 2), ("exponential", 2), ("gauss", 2), ("gauss", 4), ("gauss", 32), ("reference", 2))
COST_JSON = ROOT / "docs" / "plant-step-cost.json"


def fmu_step_us(fmu_path: Path, integrator: str, substeps: int, n: int) -> float:
    """Median µs of doStep + getReal(every output) of a plant FMU (either kind) at 1 ms, torques held."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    from flexarm.integrator import INTEGRATORS

    md = read_model_description(str(fmu_path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu_path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=f"cost-{integrator}")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setInteger([vr["integrator"], vr["substeps"]], [INTEGRATORS.index(integrator) + 1, substeps])
    fmu.exitInitializationMode()
    fmu.setReal([vr["tau1"], vr["tau2"]], [1.0, 0.3])
    clock = {"t": 0.0}

    def step():
        fmu.doStep(clock["t"], DT)
        fmu.getReal(outs)
        clock["t"] += DT

    try:
        return _median_us(step, max(5, n // 10), n)
    finally:
        fmu.terminate()
        fmu.freeInstance()


def cost_table(n: int = 2000) -> dict:
    """Median µs per 1 ms step of every row of :data:`COST_ROWS`: the Numba library call, the Python plant FMU and
    the native one (both through fmpy, doStep + every output), with the machine and its load, for ``--write``."""
    import platform
    from datetime import UTC, datetime

    from flexarm import ArmModel, rigid_configuration
    from flexarm._kernels import HAVE_NUMBA
    from flexarm.integrator import advance
    from flexarm.model import N
    from flexarm.provenance import git_commit
    from fmu_build import build_all, build_native_all

    if not HAVE_NUMBA:
        raise SystemExit("--write measures the Numba kernels: install numba (FLEXARM_NO_NUMBA unset)")
    python_fmus = build_all(only="plant")
    fmus = {"python_fmu": python_fmus["plant"], "native_fmu": build_native_all(python_fmus, only="plant")["plant"]}
    model = ArmModel()
    load_before = os.getloadavg()
    rows = {}
    for integrator, sub in COST_ROWS:
        # fewer steps for the costly rows; the exponential scheme refuses to run past 3 s of simulated time
        count = max(200, min(n // max(1, sub // 2) // (10 if integrator == "reference" else 1), 2500))
        state = {"z": np.concatenate([rigid_configuration(0.0, np.pi / 2), np.zeros(N)])}

        def lib_step(integrator=integrator, sub=sub, state=state):
            state["z"], _ = advance(model, state["z"], (1.0, 0.3), DT, sub, integrator)

        row = {"library_us": _median_us(lib_step, max(5, count // 10), count)}
        for kind, path in fmus.items():
            row[f"{kind}_us"] = fmu_step_us(path, integrator, sub, min(count, 2200))
        rows[f"{integrator}|{sub}"] = row
        print(f"  {integrator} {sub}/ms: " + ", ".join(f"{k} {v:.0f} µs" for k, v in row.items()), flush=True)
    return {"date": datetime.now(UTC).isoformat(timespec="seconds"), "commit": git_commit(),
            "machine": {"processor": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                        "python": platform.python_version(), "system": platform.platform()},
            "load_average_before": list(load_before), "load_average_after": list(os.getloadavg()),
            "rows": rows}


def table2_substeps(steps_ms=(1, 4)) -> list[str]:
    """Lines: RODAS4 substeps taken per ms and library µs per ms of simulated time over table2/none's closed-loop
    torques at each communication step (default plant settings)."""
    import copy
    import math
    import tempfile

    from flexarm import ArmModel
    from flexarm import _kernels as kern
    from flexarm.integrator import DEFAULT_SUBSTEPS, substep_count
    from scenarios.config import load_scenario
    from scenarios.run.runner import run_scenario

    model = ArmModel()
    lines = []
    for ms in steps_ms:
        s = copy.deepcopy(load_scenario("table2"))
        s.name, s.cases = f"bench-{ms}ms", [c for c in s.cases if c.key == "none"]
        s.step_size, s.samples = ms * 1e-3, math.ceil(2058 / ms)
        with tempfile.TemporaryDirectory() as tmp:
            (r,) = run_scenario(s, Path(tmp), progress=False, kind="native")
        tau = np.column_stack([r.series["controller.tau1"], r.series["controller.tau2"]])[:-1]
        z = np.array([r.series[f"plant.{v}{i}"][0] for v in ("theta", "omega") for i in range(1, 12)])
        dt = ms * 1e-3
        count = substep_count(dt, DEFAULT_SUBSTEPS)
        taken = 0
        t0 = time.perf_counter()
        for k in range(len(tau)):
            z, _, n = kern.advance(z, np.ascontiguousarray(tau[k]), dt, count, model.mass_coefficients,
                                   model.stiffness, model.j2p, model.j2d, model.damping, kern.RODAS4_A, kern.RODAS4_C,
                                   kern.RODAS4_GAMMA, kern.RODAS4_ANGLE_TOL, kern.RODAS4_MAX_HALVINGS)
            taken += n
        wall = time.perf_counter() - t0
        sim_ms = len(tau) * ms
        lines.append(f"  table2/none at {ms} ms ({r.status}): {taken / sim_ms:.2f} RODAS4 substeps per ms taken "
                     f"(nominal {DEFAULT_SUBSTEPS}), library {1e6 * wall / sim_ms:.1f} µs per ms simulated")
    return lines


def _print(result: dict) -> None:
    for key in sorted(k for k in result if "/" in k):
        kind, integrator = key.split("/", 1)
        label = ("library advance()" if kind == "library_us"
                 else f"FMU doStep + getReal({result['n_outputs']} outputs)") + f" [{integrator}]"
        us = result[key]
        print(f"  {result['backend']:5s}  {label:50s} {us:9.1f} µs/step   real-time factor {1e3 / us:7.1f}x")


def main() -> int:
    if "--child" in sys.argv:  # NumPy-only measurement, run by the parent with FLEXARM_NO_NUMBA=1
        print(json.dumps(measure(Path(sys.argv[sys.argv.index("--child") + 1]), n_lib=400, n_fmu=400)))
        return 0
    if "--write" in sys.argv:  # docs/model.md's cost table: measure, write the JSON, render the block
        from flexarm.provenance import write_atomic
        from scenarios.reports.cost_doc import write_block

        data = cost_table()
        write_atomic(COST_JSON, json.dumps(data, indent=1) + "\n")
        print(f"wrote {COST_JSON.relative_to(ROOT)} and {write_block(data).relative_to(ROOT)}")
        return 0
    from fmu_build import build_all

    t_start = time.perf_counter()
    fmu_path = build_all(only="plant")["plant"]
    print(f"plant step cost per 1 ms communication step (median after warm-up), FMU {fmu_path}")
    _print(measure(fmu_path, n_lib=5000, n_fmu=5000))
    print("error-controlled RODAS4 over a closed loop (Numba; substeps include rejected ones):")
    print("\n".join(table2_substeps()))
    env = {**os.environ, "FLEXARM_NO_NUMBA": "1"}
    proc = subprocess.run([sys.executable, __file__, "--child", str(fmu_path)], env=env, capture_output=True,
                          text=True, timeout=300)
    if proc.returncode != 0:
        print(f"NumPy-only run failed:\n{proc.stderr}", file=sys.stderr)
        return 1
    _print(json.loads(proc.stdout.strip().splitlines()[-1]))
    print(f"(benchmark wall time {time.perf_counter() - t_start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
