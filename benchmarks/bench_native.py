"""Native (C) FMUs beside the Python FMUs: plant step cost, first step after unpacking, three-FMU real time.

Prints, in one run:

1. the native plant's cost per 1 ms step (fmi2SetReal + fmi2DoStep + fmi2GetReal of every output, called
   through ctypes), the cost of those calls without the doStep, the step with damping and with the exponential
   scheme, against the Numba library step (flexarm.integrator.advance + observables, warm) and the Python plant
   FMU's step;
2. the time from a fresh unpack to the end of the first fmi2DoStep (instantiate, initialise, one step),
   native and Python;
3. the real-time factor of table2's first case (plant + sensors + controller, 1 ms) with the Python FMUs
   and with the native ones, in our fmpy master and in libcosim (the case exported as SSP, run by
   scenarios.conformance.libcosim_runner on the calling thread, then with libcosim's default worker pool; stepping
   only, loading excluded).

    python -m benchmarks.bench_native [--steps N] [--repeats N]

Builds what it needs into a temporary folder (the Python FMUs with build_fmus, the native ones with
fmu_build.native_build, linux64 only). Figures on a shared machine are noisy: take the best of repeats.
"""

from __future__ import annotations

import argparse
import ctypes
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

from flexarm.integrator import advance
from flexarm.model import ArmModel
from flexarm.trajectory import load_trajectory
from fmu_build.native_build import build_native_fmus


def _open(fmu: Path, folder: Path):
    """Unpack `fmu` into `folder`, instantiate, initialise; (slave, variables by name)."""
    with zipfile.ZipFile(fmu) as z:
        z.extractall(folder)
    md = read_model_description(str(fmu))
    s = FMU2Slave(guid=md.guid, unzipDirectory=str(folder), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="bench")
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    return s, {v.name: v for v in md.modelVariables}


def plant_step_cost(fmu: Path, tmp: Path, torques: np.ndarray, repeats: int, params: dict | None = None,
                    step: bool = True) -> float:
    """Best wall time per 1 ms step (s) of set torques + doStep + get all outputs.

    `params` (name -> value) are set in initialisation mode; ``step=False`` leaves out the doStep: the cost of the
    ctypes calls themselves (what the host pays whatever the model does).
    """
    s, var = _open(fmu, tmp)
    outs = [v.valueReference for v in var.values() if v.causality == "output"]
    vr_in = (ctypes.c_uint * 2)(var["tau1"].valueReference, var["tau2"].valueReference)
    vr_out = (ctypes.c_uint * len(outs))(*outs)
    y = (ctypes.c_double * len(outs))()
    u = (ctypes.c_double * 2)()
    # fmpy's raw ctypes functions (its wrappers add logging checks that cost more than the native step)
    set_real, do_step, get_real = (s._functions[f] for f in ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal"))
    best = float("inf")
    for _ in range(repeats):
        s.reset()
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        for name, value in (params or {}).items():
            (s.setReal if var[name].type == "Real" else s.setInteger)([var[name].valueReference], [value])
        s.exitInitializationMode()
        t0 = time.perf_counter()
        for k, tau in enumerate(torques):
            u[0], u[1] = tau
            set_real(s.component, vr_in, 2, u)
            if step:
                do_step(s.component, k * 1e-3, 1e-3, 1)
            get_real(s.component, vr_out, len(outs), y)
        best = min(best, (time.perf_counter() - t0) / len(torques))
    s.terminate()
    s.freeInstance()
    return best


def plant_step_cost_in_c(fmu: Path, tmp: Path, torques: np.ndarray, repeats: int) -> float:
    """Best wall time per 1 ms step (s) of the same calls from C (benchmarks/plant_step_timing.c, compiled with gcc
    -O2; it loads the FMU's shipped linux64 binary): the plant's own cost, without Python's ctypes calls."""
    import fmpy

    with zipfile.ZipFile(fmu) as z:
        z.extractall(tmp)
    md = read_model_description(str(fmu))
    var = {v.name: v for v in md.modelVariables}
    exe, tau_file = tmp / "plant_step_timing", tmp / "torques.txt"
    subprocess.run(["gcc", "-std=c99", "-O2", "-I", str(Path(fmpy.__file__).parent / "c-code"), "-o", str(exe),
                    str(Path(__file__).with_name("plant_step_timing.c")), "-ldl"], check=True, capture_output=True)
    np.savetxt(tau_file, torques, fmt="%.17g")
    library = tmp / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    outs = ",".join(str(v.valueReference) for v in md.modelVariables if v.causality == "output")
    run = subprocess.run([str(exe), str(library), (tmp / "resources").as_uri(), md.guid, str(tau_file), str(repeats),
                          f"{var['tau1'].valueReference},{var['tau2'].valueReference}", outs],
                         capture_output=True, text=True, check=True)
    return float(run.stdout.strip()) * 1e-6


def library_step_cost(torques: np.ndarray, repeats: int) -> float:
    """Best wall time per 1 ms step (s) of the library: advance (Numba when installed) + observables."""
    model = ArmModel()
    z0 = np.zeros(22)
    z0[6:11] = np.pi / 2
    advance(model, z0, torques[0], 1e-3)  # compile / warm up
    best = float("inf")
    for _ in range(repeats):
        z = z0.copy()
        t0 = time.perf_counter()
        for tau in torques:
            z, _ = advance(model, z, tau, 1e-3)
            model.observables(z, tau)
        best = min(best, (time.perf_counter() - t0) / len(torques))
    return best


_FIRST_STEP = """
import sys, time, zipfile
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave
t0 = time.perf_counter()
with zipfile.ZipFile(sys.argv[1]) as z:
    z.extractall(sys.argv[2])
md = read_model_description(sys.argv[2])
s = FMU2Slave(guid=md.guid, unzipDirectory=sys.argv[2], modelIdentifier=md.coSimulation.modelIdentifier)
s.instantiate()
s.setupExperiment(startTime=0.0)
s.enterInitializationMode()
s.exitInitializationMode()
s.setReal([next(v.valueReference for v in md.modelVariables if v.name == "tau1")], [1.0])
s.doStep(0.0, 1e-3)
print(time.perf_counter() - t0)
"""


def first_step(fmu: Path, tmp: Path) -> float:
    """Seconds from a fresh unpack to the end of the first doStep, in a new process (fmpy imported) and a new
    folder (nothing loaded or cached: for the Python FMU this includes starting its Python side)."""
    run = subprocess.run([sys.executable, "-c", _FIRST_STEP, str(fmu), str(tmp)], capture_output=True, text=True,
                         check=True, cwd=Path(__file__).resolve().parents[1])
    return float(run.stdout.strip().splitlines()[-1])


def _choice_values(setup, params: dict) -> dict:
    """Choice names (gain_set = "gamma0.1") as their Enumeration values where an FMU declares one."""
    out = {}
    for inst, values in params.items():
        var = {v.name: v for v in read_model_description(str(setup.paths[inst])).modelVariables}
        out[inst] = {k: next(int(i.value) for i in var[k].declaredType.items if i.name == v)
                     if k in var and var[k].type == "Enumeration" and isinstance(v, str) else v
                     for k, v in values.items()}
    return out


def cosim_rtf(fmu_dir: Path, repeats: int) -> tuple[float, float, dict]:
    """table2's first case in our master: (best wall time per run s, simulated s, metrics)."""
    from scenarios.config import load_scenario
    from scenarios.run.setup import prepare

    sc = load_scenario("table2")
    case = sc.cases[0]
    setup = prepare(sc, fmu_dir, names=case.fmus or None, build=False)
    params = _choice_values(setup, setup.case_parameters(case.parameters))
    with setup.open_master("gauss-seidel") as m:
        out = m.run(params, setup.record, setup.n_steps, sc.step_size)
        if out["status"] != "ok":
            raise SystemExit(f"{fmu_dir}: run failed: {out['message']}")
        walls = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            m.run(params, setup.record, setup.n_steps, sc.step_size)
            walls.append(time.perf_counter() - t0)
    q1 = out["signals"][f"{setup.plant}.theta1"]
    return min(walls), setup.n_steps * sc.step_size, {"theta1_end": float(q1[-1])}


_LIBCOSIM = """
import sys
from scenarios.conformance.libcosim_runner import run_case_libcosim
threads = None if sys.argv[3] == "default" else int(sys.argv[3])
walls = [run_case_libcosim(sys.argv[1], worker_threads=threads)["step_wall_s"] for _ in range(int(sys.argv[2]))]
first = [run_case_libcosim(sys.argv[1], n_steps=2, worker_threads=threads)["step_wall_s"]
         for _ in range(int(sys.argv[2]))]
print(min(first), min(walls))
"""


def libcosim_rtf(fmu_dir: Path, native_dir: Path, kind: str, out: Path, repeats: int,
                 worker_threads: str = "0") -> float:
    """table2's first case exported as SSP with the `kind` FMUs and stepped in libcosim (a new process):
    best wall time of the stepping (s). `worker_threads`: "0" (the calling thread) or "default" (libcosim's).
    Also prints the best wall time of the first two steps alone: a Jacobi master's second step is where the
    paper's controller measures the loop delay and starts its predictor (the longest step a real-time host
    must absorb)."""
    from scenarios.config import load_scenario
    from scenarios.conformance.ssp import export_ssp

    sc = load_scenario("table2")
    ssp = export_ssp(sc, out / kind, fmu_dir, build=False, cases=[sc.cases[0].key], kind=kind,
                     native_fmu_dir=native_dir)[sc.cases[0].key]
    run = subprocess.run([sys.executable, "-c", _LIBCOSIM, str(ssp), str(repeats), worker_threads],
                         capture_output=True, text=True, check=True, cwd=Path(__file__).resolve().parents[1])
    first, whole = map(float, run.stdout.strip().splitlines()[-1].split())
    print(f"    ({kind}, {worker_threads} worker threads: the first two steps alone {first * 1e3:.1f} ms)")
    return whole


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000, help="plant steps per timing")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    from fmu_build import build_all

    traj = load_trajectory()
    torques = np.array([traj.tau[min(k, len(traj.tau) - 1)] for k in range(args.steps)])
    with tempfile.TemporaryDirectory(prefix="bench-native-") as tmp:
        tmp = Path(tmp)
        python = build_all(tmp / "python", only=["plant", "sensors", "controller"])
        native = build_native_fmus(tmp / "native", python, platforms=("linux64",))
        print(f"native FMU sizes (linux64 only here; with all three platforms see docs/native-fmus.md): "
              f"{', '.join(f'{n} {p.stat().st_size / 1024:.0f} KiB' for n, p in native.items())}")

        t_native = plant_step_cost(native["plant"], tmp / "u1", torques, args.repeats)
        t_calls = plant_step_cost(native["plant"], tmp / "u1", torques, args.repeats, step=False)
        t_c = plant_step_cost_in_c(native["plant"], tmp / "u3", torques, args.repeats)
        t_damped = plant_step_cost(native["plant"], tmp / "u1", torques, args.repeats, {"damping_ratio": 0.02})
        t_exp = plant_step_cost(native["plant"], tmp / "u1", torques[:500], args.repeats, {"integrator": 2})
        t_gauss = plant_step_cost(native["plant"], tmp / "u1", torques[:500], args.repeats, {"integrator": 3})
        t_gauss32 = plant_step_cost(native["plant"], tmp / "u1", torques[:100], args.repeats,
                                    {"integrator": 3, "substeps": 32})
        t_ref = plant_step_cost(native["plant"], tmp / "u1", torques[:100], args.repeats, {"integrator": 4})
        t_lib = library_step_cost(torques, args.repeats)
        t_py = plant_step_cost(python["plant"], tmp / "u2", torques[:300], 2)
        print(f"plant, per 1 ms step (2 substeps, torques set and every output read; best of {args.repeats}):")
        print(f"  native FMU (C, via ctypes), rodas4:  {t_native * 1e6:8.1f} us   (goal: <= 8 us)")
        print(f"    of which the three ctypes calls:   {t_calls * 1e6:8.1f} us   (set + get alone, no doStep)")
        print(f"  native FMU, the same calls from C:   {t_c * 1e6:8.1f} us   (benchmarks/plant_step_timing.c)")
        print(f"  native, damping_ratio = 0.02:        {t_damped * 1e6:8.1f} us")
        print(f"  native, integrator = exponential:    {t_exp * 1e6:8.1f} us")
        print(f"  native, integrator = gauss:          {t_gauss * 1e6:8.1f} us")
        print(f"  native, gauss at 32 substeps per ms: {t_gauss32 * 1e6:8.1f} us")
        print(f"  native, integrator = reference:      {t_ref * 1e6:8.1f} us   (RK4 at 2.5 us)")
        print(f"  library step (flexarm, Numba/NumPy): {t_lib * 1e6:8.1f} us")
        print(f"  Python FMU (pythonfmu), rodas4:      {t_py * 1e6:8.1f} us")

        print("first doStep after a fresh unpack, new process (unpack + instantiate + initialise + one step):")
        print(f"  native plant: {first_step(native['plant'], tmp / 'f1'):.3f} s   (goal: < 0.1 s)")
        print(f"  Python plant: {first_step(python['plant'], tmp / 'f2'):.3f} s")

        wall_py, simulated, end_py = cosim_rtf(tmp / "python", args.repeats)
        wall_nat, _, end_nat = cosim_rtf(tmp / "native", args.repeats)
        print(f"table2 'none', {simulated:.3f} s simulated, our master (gauss-seidel), best of {args.repeats}:")
        print(f"  Python plant + sensors + controller: {wall_py:.3f} s, real-time factor {simulated / wall_py:.1f}x")
        print(f"  native plant + sensors + controller: {wall_nat:.3f} s, real-time factor "
              f"{simulated / wall_nat:.1f}x   (goal: >= 30x)")
        print(f"  final theta1: Python {end_py['theta1_end']!r} rad, native {end_nat['theta1_end']!r} rad")
        print(f"table2 'none' in libcosim (exported as SSP; stepping only, loading excluded), best of {args.repeats}:")
        lc_py = libcosim_rtf(tmp / "python", tmp / "native", "python", tmp / "ssp", args.repeats)
        print(f"  Python plant + sensors + controller: {lc_py:.3f} s, real-time factor {simulated / lc_py:.1f}x")
        lc_nat = libcosim_rtf(tmp / "python", tmp / "native", "native", tmp / "ssp", args.repeats)
        print(f"  native plant + sensors + controller: {lc_nat:.3f} s, real-time factor "
              f"{simulated / lc_nat:.1f}x   (goal: >= 50x)")
        lc_pool = libcosim_rtf(tmp / "python", tmp / "native", "native", tmp / "ssp", args.repeats, "default")
        print(f"  native, libcosim's default worker pool: {lc_pool:.3f} s, real-time factor {simulated / lc_pool:.1f}x")


if __name__ == "__main__":
    main()
