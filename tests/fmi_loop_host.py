"""A plain FMI 2.0 co-simulation loop over plant, sensors and controller FMUs, on fmpy's FMU2Slave only.

Run as a script in a fresh process (``python tests/fmi_loop_host.py SPEC.json OUT.npz``) it is a host
that has imported nothing of this project: no ``flexarm``, no ``pythonfmu``, the FMUs' own code only.
The spec (JSON) says:

* ``fmus``: {"plant": path, "sensors": path, "controller": path}, loaded (instantiated) in
  ``load_order``, any permutation of the three;
* ``stepping``: ``"gauss-seidel"`` (in ``order``: each FMU's inputs set from the outputs just read,
  the torques set last: our master's convention) or ``"jacobi"`` (every output read, then every input
  set);
* ``init_rounds``: exchange rounds in initialisation mode (default 0);
* ``n_steps``, ``step_size`` (s); ``parameters`` {instance: {name: value}} set before initialisation;
* ``extra``: {name: path} of other FMUs, loaded before the three, stepped alongside, not connected
  (their Real outputs are recorded as ``run<i>_<name>_<output>``);
* ``runs``: a list of such specs (each with its own ``load_order`` ...), run one after the other in
  this one process, each loading its FMUs afresh.

It writes, per run, the plant's ``theta1..11``, ``omega1..11`` and the torques at every communication
point (sample 0 after initialisation), and the status each ``fmi2DoStep`` returned (``run<i>_step_status``,
one row per step, the FMUs in the order stepped: extra, then ``order``) into OUT.npz, atomically.
"""

from __future__ import annotations

import json
import os
import sys

STATE = [f"theta{i}" for i in range(1, 12)] + [f"omega{i}" for i in range(1, 12)]


_KEEP = []  # the ctypes callbacks live as long as the process


def _callbacks(name: str):
    """FMI callbacks whose logger prints every message of status warning or worse to stderr."""
    from fmpy.fmi2 import fmi2CallbackFunctions, fmi2CallbackLoggerTYPE

    def log(env, instance, status, category, message):
        if status >= 1:
            print(f"[{name}] status {status}: {message.decode(errors='replace')}", file=sys.stderr, flush=True)

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(log)
    from fmpy import calloc, free
    from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE

    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    _KEEP.append(callbacks)
    return callbacks


def run_loop(spec: dict) -> dict:
    """One run (see the module docstring); returns {"theta", "omega", "tau"} as lists of rows."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    fmus = spec["fmus"]
    order = spec.get("order", ["plant", "sensors", "controller"])
    load_order = spec.get("load_order", order)
    stepping = spec.get("stepping", "gauss-seidel")
    h, n = float(spec.get("step_size", 1e-3)), int(spec["n_steps"])
    extra = spec.get("extra", {})  # other FMUs, loaded first, stepped alongside, not connected
    fmus = {**extra, **fmus}
    units, mds, dirs = {}, {}, {}
    for name in [*extra, *load_order]:
        md = read_model_description(fmus[name])
        dirs[name] = extract(fmus[name])
        slave = FMU2Slave(guid=md.guid, unzipDirectory=dirs[name], modelIdentifier=md.coSimulation.modelIdentifier,
                          instanceName=name)
        slave.instantiate(callbacks=_callbacks(name))
        units[name], mds[name] = slave, md
    vr = {name: {v.name: v.valueReference for v in mds[name].modelVariables} for name in units}
    outputs = {name: [v.name for v in mds[name].modelVariables if v.causality == "output"] for name in units}
    inputs = {name: [v.name for v in mds[name].modelVariables if v.causality == "input"] for name in units}
    # wiring by name: an input takes the output of the same name of another FMU
    source = {(d, var): s for d in units for var in inputs[d] for s in units if s != d and var in outputs[s]}
    values = {name: {} for name in units}

    def read(name):
        got = units[name].getReal([vr[name][v] for v in outputs[name]])
        values[name] = dict(zip(outputs[name], got))

    def write(name):
        pairs = [(var, values[s][var]) for (d, var), s in source.items() if d == name and var in values[s]]
        if pairs:
            units[name].setReal([vr[name][v] for v, _ in pairs], [x for _, x in pairs])

    def exchange():
        if stepping == "jacobi":
            for name in order:
                read(name)
            for name in order:
                write(name)
        else:
            for name in order:
                write(name)
                read(name)
            write(order[0])  # the feedback (torques) into the first FMU

    for name in extra:
        units[name].setupExperiment(startTime=0.0)
        units[name].enterInitializationMode()
        units[name].exitInitializationMode()
    for name in order:
        units[name].setupExperiment(startTime=0.0)
        for var, value in spec.get("parameters", {}).get(name, {}).items():
            ref = [vr[name][var]]
            if isinstance(value, bool):
                units[name].setBoolean(ref, [value])
            elif isinstance(value, int):
                units[name].setInteger(ref, [value])
            else:
                units[name].setReal(ref, [float(value)])
        units[name].enterInitializationMode()
    for _ in range(int(spec.get("init_rounds", 0))):
        exchange()
    for name in order:
        units[name].exitInitializationMode()
    plant, ctrl = order[0], order[-1]
    rows, taus, statuses = [], [], []
    others = {f"{name}_{v}": [] for name in extra for v in outputs[name]}
    t = 0.0
    for k in range(n + 1):
        exchange()
        rows.append(units[plant].getReal([vr[plant][v] for v in STATE]))
        taus.append([values[ctrl]["tau1"], values[ctrl]["tau2"]])
        for name in extra:
            for v, x in zip(outputs[name], units[name].getReal([vr[name][v] for v in outputs[name]])):
                others[f"{name}_{v}"].append(x)
        if k == n:
            break
        step_status = []
        for name in [*extra, *order]:  # the status itself (fmpy's doStep drops it; it raises above fmi2Warning)
            step_status.append(units[name].fmi2DoStep(units[name].component, t, h, 1))
        statuses.append(step_status)
        t = (k + 1) * h
    for name in units:
        units[name].terminate()
        units[name].freeInstance()
    import shutil

    for d in dirs.values():
        shutil.rmtree(d, ignore_errors=True)
    return {"theta": [r[:11] for r in rows], "omega": [r[11:] for r in rows], "tau": taus,
            "step_status": statuses, **others}


def main(argv: list[str]) -> int:
    import numpy as np

    spec = json.loads(open(argv[1]).read())
    out = {"modules": None}
    arrays = {}
    for i, run in enumerate(spec.get("runs", [spec])):
        result = run_loop(run)
        for key, rows in result.items():
            arrays[f"run{i}_{key}"] = np.asarray(rows, dtype=float)
    out["modules"] = sorted(n for n in sys.modules if "flexarm" in n.split(".")[0] or n.split(".")[0] == "pythonfmu")
    tmp = argv[2] + ".tmp.npz"
    np.savez(tmp, modules=np.array(out["modules"] or [""]), **arrays)
    os.replace(tmp, argv[2])
    return 0


if __name__ == "__main__":
    code = main(sys.argv)
    sys.stdout.flush()
    sys.stderr.flush()
    # The results are written: end here. pythonfmu 0.7.0's own binary (a user's pythonfmu FMU, which has no
    # front end of ours) frees its interpreter state twice in its exit handlers ("corrupted double-linked list").
    os._exit(code)
