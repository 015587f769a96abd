"""A fixed-step co-simulation master on fmpy's low-level FMI 2.0 API (FMU2Slave).

Stepping order at each communication point t_k (documented in
docs/fmu-interface.md, "Stepping convention"):

1. the FMUs are evaluated in the scenario's ``order``; before an FMU's outputs
   are read, every input whose source FMU comes *earlier* in the order is set
   from that source's current output (Gauss-Seidel: the sensors see the
   plant's state at t_k, the controller sees the sensors' sample at t_k);
2. inputs whose source comes *later* (feedback edges: the controller's
   torques into the plant) are then set, so the torque computed from the
   sample at t_k is held over [t_k, t_k+1) — zero-order hold, no extra delay;
3. the recorded signals are read (values at t_k);
4. every FMU steps from t_k to t_k + h.

Everything the master loads is freed, also when a step fails.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi1 import calloc, free
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)


class CoSimulationError(RuntimeError):
    """An FMU returned an error, or the run left the bounds of the physically sensible."""


@dataclass
class Connection:
    """output ``src_fmu.src_var`` drives input ``dst_fmu.dst_var``."""

    src_fmu: str
    src_var: str
    dst_fmu: str
    dst_var: str


@dataclass
class System:
    """What the master runs: FMU files, parameters, wiring, order, what to record."""

    fmus: dict[str, Path]
    order: list[str]
    connections: list[Connection]
    parameters: dict[str, dict[str, float | int | bool | str]] = field(default_factory=dict)
    record: list[tuple[str, str]] = field(default_factory=list)
    step_size: float = 1e-3
    n_steps: int = 2058
    #: |value| above which a recorded signal counts as numerically unbounded.
    divergence_limit: float = 1e4


def logging_callbacks(logger) -> fmi2CallbackFunctions:
    """FMI 2.0 callbacks routing the FMU's log to `logger(component, instance, status, category, message)`.

    Keep the returned object referenced as long as the instance lives (ctypes).
    """
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(logger)
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    return cb


class _Unit:
    """One loaded FMU: its slave and variable references by name."""

    def __init__(self, name: str, path: Path, messages: list[str]):
        self.name = name
        self.md = read_model_description(str(path))
        self.unzipdir = extract(str(path))
        self.vars = {v.name: v for v in self.md.modelVariables}

        def logger(component, instance_name, status, category, message):
            messages.append(f"[{name}] {message.decode(errors='replace') if isinstance(message, bytes) else message}")

        self.slave = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzipdir,
                               modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.instantiated = False
        self._callbacks = logging_callbacks(logger)
        self.slave.instantiate(callbacks=self._callbacks, loggingOn=True)
        self.instantiated = True

    def vr(self, var: str) -> int:
        if var not in self.vars:
            raise CoSimulationError(f"{self.name}: no variable '{var}' (has: {', '.join(sorted(self.vars))})")
        return self.vars[var].valueReference

    def set(self, var: str, value) -> None:
        v = self.vars.get(var)
        if v is None:
            self.vr(var)
        if v.type == "Real":
            self.slave.setReal([v.valueReference], [float(value)])
        elif v.type in ("Integer", "Enumeration"):
            self.slave.setInteger([v.valueReference], [int(value)])
        elif v.type == "Boolean":
            self.slave.setBoolean([v.valueReference], [bool(value)])
        else:
            self.slave.setString([v.valueReference], [str(value)])

    def free(self) -> None:
        try:
            if self.instantiated:
                try:
                    self.slave.terminate()
                except Exception:  # noqa: BLE001 - an FMU that failed may refuse; free it all the same
                    pass
                self.slave.freeInstance()
        finally:
            shutil.rmtree(self.unzipdir, ignore_errors=True)


def run(system: System, progress: Callable[[int, int], None] | None = None) -> dict:
    """Run the co-simulation.

    Returns
    -------
    dict
        ``time`` (n+1,), ``signals`` {"fmu.var": ndarray (n+1,)}, ``status``
        ("ok" or "unbounded"), ``message`` and the FMUs' ``log``. A run that
        diverges (non-finite or beyond `divergence_limit`, or an FMU error)
        returns what it recorded up to that point with status "unbounded".
    """
    messages: list[str] = []
    units: dict[str, _Unit] = {}
    n = system.n_steps
    h = system.step_size
    time = np.arange(n + 1) * h
    data = np.full((n + 1, len(system.record)), np.nan)
    status, message, k = "ok", "", 0
    stepping = False
    try:
        for name in system.order:
            units[name] = _Unit(name, system.fmus[name], messages)
        for name, unit in units.items():
            unit.slave.setupExperiment(startTime=0.0)
            for var, value in system.parameters.get(name, {}).items():
                unit.set(var, value)
            unit.slave.enterInitializationMode()
            unit.slave.exitInitializationMode()
        rank = {name: i for i, name in enumerate(system.order)}
        forward = {name: [] for name in system.order}
        feedback = []
        for c in system.connections:
            edge = (units[c.src_fmu], units[c.src_fmu].vr(c.src_var), units[c.dst_fmu], units[c.dst_fmu].vr(c.dst_var))
            (forward[c.dst_fmu] if rank[c.src_fmu] < rank[c.dst_fmu] else feedback).append(edge)
        rec = [(units[f], units[f].vr(v)) for f, v in system.record]

        def transfer(edges):
            for src, src_vr, dst, dst_vr in edges:
                dst.slave.setReal([dst_vr], src.slave.getReal([src_vr]))

        stepping = True
        for k in range(n + 1):
            for name in system.order:
                transfer(forward[name])
            transfer(feedback)
            row = [u.slave.getReal([vr])[0] for u, vr in rec]
            data[k] = row
            if not all(math.isfinite(x) and abs(x) < system.divergence_limit for x in row):
                status, message = "unbounded", f"signals left the bounds at t = {time[k]:.3f} s"
                break
            if k == n:
                break
            for name in system.order:
                units[name].slave.doStep(currentCommunicationPoint=time[k], communicationStepSize=h)
            if progress is not None:
                progress(k + 1, n)
    except Exception as exc:  # noqa: BLE001 - an FMU error while stepping ends this run, not the table
        if not stepping:
            raise CoSimulationError(f"could not set up the FMUs: {exc}; log: {messages[-5:]}") from exc
        status, message = "unbounded", f"step {k} (t = {k * h:.3f} s): {exc}"
    finally:
        for unit in units.values():
            unit.free()
    return {"time": time, "signals": {f"{f}.{v}": data[:, i] for i, (f, v) in enumerate(system.record)},
            "status": status, "message": message, "log": messages, "steps_done": k}
