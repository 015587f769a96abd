"""The LQG controller's cost per 1 ms sample: one Kalman filter against the payload bank, side by side.

Prints, in one run, for ``estimator = kalman`` and ``estimator = payload_bank`` (γ = 0.1, 200 ms schedule,
loop delay 2, integral action on):

1. the library law (:meth:`flexarm.lqg.LqgController.step`, :meth:`flexarm.lqg_bank.BankController.step`),
   warm;
2. ``controller_lqg`` as an FMU through fmpy's ctypes calls (set the ten measurements, get the two torques,
   doStep 1 ms): the Python FMU and the native one (both built first if out of date).

The measurements are the desired ones (z_d C^T) plus a fixed 1e-4 offset, so the filters work on non-zero
innovations. Best of ``--repeats`` over the slew's samples; figures on a shared machine are noisy.

    python -m benchmarks.bench_lqg [--repeats N] [--fmu-dir build/fmus] [--native-fmu-dir build/fmus-native]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

from flexarm.lqg import lqg_controller
from flexarm.lqg_bank import bank_controller
from fmu_build import build_all, build_native_all
from scenarios.master import logging_callbacks

ESTIMATORS = {"kalman": (1, lqg_controller), "payload_bank": (2, bank_controller)}
MEASURED = ("q1_m", "q2_m", "qd1_m", "qd2_m", "eps1_m", "eps2_m", "eps3_m", "eps4_m", "eps5_m", "eps6_m")
DELAY = 2


def measurements(law) -> np.ndarray:
    """(n_steps + 1, 10): the desired measurements plus a fixed offset (rad, rad/s)."""
    return law.z @ law.design.C.T + 1e-4


def library_cost(factory, repeats: int) -> float:
    """Best wall time per sample (s) of the library law over the slew."""
    law = factory("gamma0.1", "200ms", DELAY, True)
    y = measurements(law)
    best = np.inf
    for _ in range(repeats):
        state = law.initial_state()
        t0 = time.perf_counter()
        for k in range(len(y)):
            _, state = law.step(state, k, y[k])
        best = min(best, (time.perf_counter() - t0) / len(y))
    return best


def fmu_cost(fmu: Path, estimator: int, y: np.ndarray, repeats: int) -> float | str:
    """Best wall time per 1 ms step (s) of set + get + doStep, or the reason the FMU refused the setting."""
    md = read_model_description(str(fmu))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    with tempfile.TemporaryDirectory() as tmp:
        with zipfile.ZipFile(fmu) as z:
            z.extractall(tmp)
        messages = []
        s = FMU2Slave(guid=md.guid, unzipDirectory=tmp, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="bench")
        callbacks = logging_callbacks(lambda c, i, status, cat, msg: messages.append(msg.decode()))
        s.instantiate(callbacks=callbacks, loggingOn=True)
        refused = False
        try:
            best = np.inf
            for _ in range(repeats):
                s.reset()
                s.setupExperiment(startTime=0.0)
                s.enterInitializationMode()
                s.setInteger([refs["loop_delay_samples"], refs["estimator"]], [DELAY, estimator])
                s.setBoolean([refs["integral_action"]], [True])
                try:
                    s.exitInitializationMode()
                except Exception:  # noqa: BLE001 -- a refusal is a figure too: say why
                    refused = True  # fmi2Error: only fmi2FreeInstance is allowed now
                    return "refused: " + (messages[-1] if messages else "exitInitializationMode failed")
                meas, out = [refs[n] for n in MEASURED], [refs["tau1"], refs["tau2"]]
                t0 = time.perf_counter()
                for k in range(len(y)):
                    s.setReal(meas, list(y[k]))
                    s.getReal(out)
                    s.doStep(k * 1e-3, 1e-3)
                best = min(best, (time.perf_counter() - t0) / len(y))
            return best
        finally:
            if not refused:
                s.terminate()
            s.freeInstance()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bench_lqg", description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--fmu-dir", type=Path, default=Path("build") / "fmus")
    ap.add_argument("--native-fmu-dir", type=Path, default=Path("build") / "fmus-native")
    args = ap.parse_args(argv)
    built = build_all(args.fmu_dir, only="controller_lqg")  # both kinds, rebuilt when out of date
    python_fmu = built["controller_lqg"]
    native_fmu = build_native_all(built, args.native_fmu_dir, only="controller_lqg")["controller_lqg"]
    y = measurements(lqg_controller())
    print(f"controller_lqg, gamma0.1, 200 ms schedule, delay {DELAY}, integral action; best of {args.repeats} "
          f"over {len(y)} samples; microseconds per 1 ms sample")
    print(f"{'':34s}" + "".join(f"{e:>16s}" for e in ESTIMATORS), flush=True)
    rows = [("library law (Python/NumPy)", [library_cost(f, args.repeats) for _, f in ESTIMATORS.values()]),
            ("Python FMU via fmpy", [fmu_cost(python_fmu, v, y, args.repeats) for v, _ in ESTIMATORS.values()])]
    rows.append(("native FMU via fmpy", [fmu_cost(native_fmu, v, y, args.repeats) for v, _ in ESTIMATORS.values()]))
    refusals = []
    for label, cells in rows:
        text = []
        for c in cells:
            if isinstance(c, str):
                refusals.append(f"{label}: {c}")
                text.append("refused")
            else:
                text.append(f"{c * 1e6:.1f}")
        print(f"{label:34s}" + "".join(f"{t:>16s}" for t in text))
    for r in refusals:
        print(r)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
