"""The native controller_lqg FMU: cost per 1 ms sample of each estimator, instantiation, size.

Prints, in one run:

1. the cost per 1 ms sample (fmi2SetReal of the ten measurements, fmi2GetReal of the torques, which
   evaluates the sample, and fmi2DoStep, called through ctypes) of the native FMU with ``estimator`` 1
   (kalman) and 2 (payload_bank), of the Python FMU with each, and of the library law alone (warm), on the
   desired measurements of the committed trajectory (no noise: the cost does not depend on the values);
2. the time of fmi2Instantiate (reading and checking the resources; the bank's drift is formed there);
3. the FMU sizes (linux64 only here, and the bank's resource alone).

    python -m benchmarks.bench_native_lqg [--steps N] [--repeats N]

Builds what it needs into a temporary folder. Figures on a shared machine are noisy: take the best of repeats.
"""

from __future__ import annotations

import argparse
import ctypes
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

from flexarm.lqg import lqg_controller
from flexarm.lqg_bank import bank_controller
from fmu_build.native_build import build_native_fmus
from fmu_build.native_resources import bank_resource

MEASURED = ("q1_m", "q2_m", "qd1_m", "qd2_m", "eps1_m", "eps2_m", "eps3_m", "eps4_m", "eps5_m", "eps6_m")


def _slave(fmu: Path, folder: Path) -> tuple[FMU2Slave, dict, float]:
    """Unpack and instantiate; (slave, variables by name, seconds fmi2Instantiate took)."""
    if not folder.exists():
        with zipfile.ZipFile(fmu) as z:
            z.extractall(folder)
    md = read_model_description(str(fmu))
    s = FMU2Slave(guid=md.guid, unzipDirectory=str(folder), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="bench")
    t0 = time.perf_counter()
    s.instantiate()
    return s, {v.name: v for v in md.modelVariables}, time.perf_counter() - t0


def sample_cost(fmu: Path, folder: Path, measurements: np.ndarray, estimator: int, repeats: int) -> tuple[float,
                                                                                                          float]:
    """Best wall time per sample (s) of set measurements + get torques + doStep, and of fmi2Instantiate (s)."""
    s, var, t_inst = _slave(fmu, folder)
    # the ten measurements and the index the sensors send with them (plant sample k travels as k + 1: a
    # Gauss-Seidel loop, delay 0, so the controller has nothing to warn about)
    vr_in = (ctypes.c_uint * 11)(*(var[n].valueReference for n in (*MEASURED, "sample_index_m")))
    vr_out = (ctypes.c_uint * 2)(var["tau1"].valueReference, var["tau2"].valueReference)
    u, y = (ctypes.c_double * 11)(), (ctypes.c_double * 2)()
    set_real, do_step, get_real = (s._functions[f] for f in ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal"))
    best = float("inf")
    for _ in range(repeats):
        s.reset()
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.setInteger([var["estimator"].valueReference], [estimator])
        s.exitInitializationMode()
        t0 = time.perf_counter()
        for k, m in enumerate(measurements):
            u[:10] = m
            u[10] = k + 1.0
            set_real(s.component, vr_in, 11, u)
            get_real(s.component, vr_out, 2, y)
            do_step(s.component, k * 1e-3, 1e-3, 1)
        best = min(best, (time.perf_counter() - t0) / len(measurements))
    s.terminate()
    s.freeInstance()
    return best, t_inst


def library_cost(estimator: int, measurements: np.ndarray, repeats: int) -> float:
    """Best wall time per sample (s) of the library law (:mod:`flexarm.lqg`, :mod:`flexarm.lqg_bank`), warm."""
    law = (lqg_controller if estimator == 1 else bank_controller)()
    best = float("inf")
    for _ in range(repeats):
        state = law.initial_state()
        t0 = time.perf_counter()
        for k, m in enumerate(measurements):
            _, state = law.step(state, k, m)
        best = min(best, (time.perf_counter() - t0) / len(measurements))
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000, help="samples per timing")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    from fmu_build import build_all

    law = lqg_controller()
    y_d = law.z @ law.design.C.T
    measurements = y_d[np.minimum(np.arange(args.steps), len(y_d) - 1)]
    with tempfile.TemporaryDirectory(prefix="bench-native-lqg-") as tmp:
        tmp = Path(tmp)
        python = build_all(tmp / "python", only=["controller_lqg"])
        native = build_native_fmus(tmp / "native", python, platforms=("linux64",))["controller_lqg"]
        with zipfile.ZipFile(native) as z:
            bank = z.getinfo(f"resources/{bank_resource('200ms')}")
        print(f"native controller_lqg (linux64 only): {native.stat().st_size / 1024:.0f} KiB, of which the bank "
              f"resource {bank.compress_size / 1024:.0f} KiB compressed ({bank.file_size / 1024:.0f} KiB unpacked)")
        print("per 1 ms sample (set the 10 measurements and their index, get the torques, doStep; via ctypes; "
              f"best of {args.repeats}):")
        for estimator, name in ((1, "kalman"), (2, "payload_bank")):
            t_nat, t_inst = sample_cost(native, tmp / "native_u", measurements, estimator, args.repeats)
            t_py, _ = sample_cost(python["controller_lqg"], tmp / "python_u", measurements[:500], estimator, 2)
            t_lib = library_cost(estimator, measurements[:500], 2)
            print(f"  estimator = {estimator} ({name}):  native {t_nat * 1e6:8.1f} us   Python FMU {t_py * 1e6:8.1f} us"
                  f"   ({t_py / t_nat:.0f}x)   library law {t_lib * 1e6:8.1f} us")
        print(f"native fmi2Instantiate (resources read and checked, the bank's drift formed): {t_inst * 1e3:.0f} ms")


if __name__ == "__main__":
    main()
