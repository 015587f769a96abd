"""A fixed-step co-simulation master on fmpy's low-level FMI 2.0 API (FMU2Slave).

Stepping order at each communication point t_k (documented in
docs/fmu-interface.md, "Stepping convention"), ``algorithm="gauss-seidel"``
(the default):

1. the FMUs are evaluated in the scenario's ``order``; before an FMU's outputs
   are read, every input whose source FMU comes *earlier* in the order is set
   from that source's current output (the sensors see the plant's state at
   t_k, the controller sees the sensors' sample at t_k);
2. inputs whose source comes *later* (feedback edges: the controller's
   torques into the plant) are then set, so the torque computed from the
   sample at t_k is held over [t_k, t_k+1) — zero-order hold, no extra delay;
3. the recorded signals are read (values at t_k);
4. every FMU steps from t_k to t_k + h.

``algorithm="jacobi"`` reads *every* connection's source and every recorded
signal first and only then sets the inputs, as masters that step all FMUs in
parallel do (libcosim's fixed-step algorithm, fmpy's ``simulate_ssp``): a
signal passing through a direct-feedthrough FMU (sensors, controller)
arrives one step later, and the recorded signals are the values exchanged.

A :class:`Master` loads its FMUs once and can run many times (``fmi2Reset``
between runs), which is what sweeps do; :func:`run` is the one-shot form.
Values move between FMUs through preallocated ctypes buffers, one
``fmi2GetReal``/``fmi2SetReal`` pair per connected FMU pair and step.
Everything the master loads is freed, also when a step fails.
"""

from __future__ import annotations

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
    fmi2Real,
    fmi2ValueReference,
)

ALGORITHMS = ("gauss-seidel", "jacobi")
_STATUS = {1: "warning", 2: "discard", 3: "error", 4: "fatal", 5: "pending"}


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
    #: "gauss-seidel" (the default, see the module docstring) or "jacobi".
    algorithm: str = "gauss-seidel"


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
    """One loaded FMU: its slave, variable references by name, raw FMI functions."""

    def __init__(self, name: str, path: Path, messages: list[str]):
        self.name = name
        self.path = Path(path)
        self.md = read_model_description(str(path))
        self.unzipdir = extract(str(path))
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.slave = None

        def logger(component, instance_name, status, category, message):
            text = message.decode(errors="replace") if isinstance(message, bytes) else str(message)
            messages.append(f"[{name}] {text}")

        self._callbacks = logging_callbacks(logger)
        self.instantiate()

    def instantiate(self) -> None:
        self.slave = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzipdir,
                               modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=self.name)
        self.slave.instantiate(callbacks=self._callbacks, loggingOn=True)
        # fmpy's getReal/setReal allocate arrays and log each call; the stepping
        # loop calls the library functions directly with preallocated buffers.
        self.get_real = self.slave._functions["fmi2GetReal"]
        self.set_real = self.slave._functions["fmi2SetReal"]
        self.do_step = self.slave._functions["fmi2DoStep"]

    def reinstantiate(self) -> None:
        """Free the instance and make a new one (after an FMU failed and refuses reset)."""
        self._free_instance()
        self.instantiate()

    def vr(self, var: str) -> int:
        if var not in self.vars:
            raise CoSimulationError(f"{self.name}: no variable '{var}' (has: {', '.join(sorted(self.vars))})")
        return self.vars[var].valueReference

    def set(self, var: str, value) -> None:
        self.vr(var)  # names the variable if it does not exist
        v = self.vars[var]
        if v.type == "Real":
            self.slave.setReal([v.valueReference], [float(value)])
        elif v.type in ("Integer", "Enumeration"):
            self.slave.setInteger([v.valueReference], [int(value)])
        elif v.type == "Boolean":
            self.slave.setBoolean([v.valueReference], [bool(value)])
        else:
            self.slave.setString([v.valueReference], [str(value)])

    def _free_instance(self) -> None:
        if self.slave is None:
            return
        slave, self.slave = self.slave, None
        try:
            slave.terminate()
        except Exception:  # noqa: BLE001 - an FMU that failed may refuse; free it all the same
            pass
        slave.freeInstance()

    def free(self) -> None:
        try:
            self._free_instance()
        finally:
            shutil.rmtree(self.unzipdir, ignore_errors=True)


class _Transfer:
    """Reals from one FMU's outputs to another's inputs through one shared buffer."""

    def __init__(self, src: _Unit, src_vrs: list[int], dst: _Unit | None, dst_vrs: list[int]):
        n = len(src_vrs)
        self.src, self.dst, self.n = src, dst, n
        self.src_vrs = (fmi2ValueReference * n)(*src_vrs)
        self.dst_vrs = (fmi2ValueReference * n)(*dst_vrs)
        self.buffer = (fmi2Real * n)()
        self.values = np.frombuffer(self.buffer, dtype=np.float64)

    def read(self) -> None:
        status = self.src.get_real(self.src.slave.component, self.src_vrs, self.n, self.buffer)
        if status > 1:
            raise CoSimulationError(f"{self.src.name}: fmi2GetReal returned {_STATUS.get(status, status)}")

    def write(self) -> None:
        status = self.dst.set_real(self.dst.slave.component, self.dst_vrs, self.n, self.buffer)
        if status > 1:
            raise CoSimulationError(f"{self.dst.name}: fmi2SetReal returned {_STATUS.get(status, status)}")


class Master:
    """FMUs loaded once, wired, and run as often as asked.

    Parameters
    ----------
    fmus : dict of str to Path
        FMU instance name -> .fmu file.
    order : list of str
        Evaluation order of the instances (see the module docstring).
    connections : list of Connection
        Real-valued output -> input wiring.
    algorithm : {"gauss-seidel", "jacobi"}
        How values are exchanged at a communication point.

    Use as a context manager, or call :meth:`close`. Between two runs every
    FMU is reset with ``fmi2Reset`` (an FMU that refuses is instantiated
    anew), so a run never sees the previous run's state.
    """

    def __init__(self, fmus: dict[str, Path], order: list[str], connections: list[Connection],
                 algorithm: str = "gauss-seidel"):
        if algorithm not in ALGORITHMS:
            raise CoSimulationError(f"algorithm: one of {ALGORITHMS}, got {algorithm!r}")
        missing = sorted(set(order) ^ set(fmus))
        if missing:
            raise CoSimulationError(f"order: must list every FMU instance exactly once (mismatch: {missing})")
        self.order, self.algorithm = list(order), algorithm
        self.messages: list[str] = []
        self.units: dict[str, _Unit] = {}
        self._used = False
        try:
            for name in self.order:
                self.units[name] = _Unit(name, fmus[name], self.messages)
            self._wire(connections)
        except Exception as exc:
            self.close()
            if isinstance(exc, CoSimulationError):
                raise
            raise CoSimulationError(f"could not load the FMUs: {exc}; log: {self.messages[-5:]}") from exc

    def _wire(self, connections: list[Connection]) -> None:
        rank = {name: i for i, name in enumerate(self.order)}
        groups: dict[tuple[str, str], list[tuple[int, int]]] = {}
        for c in connections:
            for inst in (c.src_fmu, c.dst_fmu):
                if inst not in self.units:
                    raise CoSimulationError(f"connection {c.src_fmu}.{c.src_var} -> {c.dst_fmu}.{c.dst_var}: "
                                            f"no FMU instance '{inst}' (have: {sorted(self.units)})")
            src, dst = self.units[c.src_fmu], self.units[c.dst_fmu]
            groups.setdefault((c.src_fmu, c.dst_fmu), []).append((src.vr(c.src_var), dst.vr(c.dst_var)))
        # forward[name]: transfers into `name` from FMUs earlier in the order; feedback: the rest.
        self.forward: dict[str, list[_Transfer]] = {name: [] for name in self.order}
        self.feedback: list[_Transfer] = []
        for (s, d), pairs in groups.items():
            t = _Transfer(self.units[s], [p[0] for p in pairs], self.units[d], [p[1] for p in pairs])
            (self.forward[d] if rank[s] < rank[d] else self.feedback).append(t)

    def __enter__(self) -> Master:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Terminate and free every FMU and delete the unpacked files."""
        units, self.units = self.units, {}
        for unit in units.values():
            unit.free()

    def _initialise(self, parameters: dict[str, dict]) -> None:
        for name, unit in self.units.items():
            if self._used:
                try:
                    unit.slave.reset()
                except Exception:  # noqa: BLE001 - a failed FMU may refuse fmi2Reset; start it afresh
                    unit.reinstantiate()
            unit.slave.setupExperiment(startTime=0.0)
            for var, value in parameters.get(name, {}).items():
                unit.set(var, value)
            unit.slave.enterInitializationMode()
            unit.slave.exitInitializationMode()
        self._used = True

    def run(self, parameters: dict[str, dict] | None = None, record: list[tuple[str, str]] = (),
            n_steps: int = 2058, step_size: float = 1e-3, divergence_limit: float = 1e4,
            progress: Callable[[int, int], None] | None = None) -> dict:
        """Initialise every FMU with `parameters` and step `n_steps` times.

        Parameters
        ----------
        parameters : dict
            {instance: {variable: value}}, set before initialisation.
        record : list of (instance, variable)
            Real variables to record at every communication point.
        n_steps : int
            Number of communication steps; `n_steps` + 1 samples are recorded.
        step_size : float
            Communication step, s.
        divergence_limit : float
            A recorded |value| above this (or non-finite) ends the run as "unbounded".
        progress : callable, optional
            ``progress(k, n_steps)``, called about a hundred times per run.

        Returns
        -------
        dict
            ``time`` (n+1,), ``signals`` {"fmu.var": ndarray (n+1,)}, ``status``
            ("ok" or "unbounded"), ``message``, the FMUs' ``log`` and
            ``steps_done``. A run that diverges or meets an FMU error returns
            what it recorded up to then, with status "unbounded".
        """
        if not self.units:
            raise CoSimulationError("the master is closed")
        self.messages.clear()
        n, h = int(n_steps), float(step_size)
        time = np.arange(n + 1) * h
        record = list(record)
        data = np.full((n + 1, len(record)), np.nan)
        try:
            self._initialise(parameters or {})
        except Exception as exc:
            self._used = True
            raise CoSimulationError(f"could not initialise the FMUs: {exc}; log: {self.messages[-5:]}") from exc
        # One read per recorded FMU: columns of `data` filled from its buffer.
        readers, columns = [], []
        by_unit: dict[str, list[int]] = {}
        for i, (inst, _var) in enumerate(record):
            if inst not in self.units:
                raise CoSimulationError(f"record: no FMU instance '{inst}' (have: {sorted(self.units)})")
            by_unit.setdefault(inst, []).append(i)
        for inst, cols in by_unit.items():
            unit = self.units[inst]
            readers.append(_Transfer(unit, [unit.vr(record[i][1]) for i in cols], None, [0] * len(cols)))
            columns.append(np.array(cols))
        # (read?, write?, transfer) in the order of the algorithm; records are read at "record".
        if self.algorithm == "gauss-seidel":
            schedule = [(True, True, t) for name in self.order for t in self.forward[name]]
            schedule += [(True, True, t) for t in self.feedback] + [(False, False, "record")]
        else:  # every value (records too) as it was before any input changed, then all inputs set
            every = [t for name in self.order for t in self.forward[name]] + self.feedback
            schedule = [(True, False, t) for t in every] + [(False, False, "record")]
            schedule += [(False, True, t) for t in every]
        steppers = [(u.do_step, u.slave.component, u.name) for u in (self.units[name] for name in self.order)]
        every_pct = max(1, n // 100)
        status, message, k = "ok", "", 0
        try:
            for k in range(n + 1):
                for read, write, t in schedule:
                    if t == "record":
                        for reader, cols in zip(readers, columns):
                            reader.read()
                            data[k, cols] = reader.values
                        continue
                    if read:
                        t.read()
                    if write:
                        t.write()
                row = data[k]
                if not (np.isfinite(row).all() and (np.abs(row) < divergence_limit).all()):
                    status, message = "unbounded", f"signals left the bounds at t = {time[k]:.3f} s"
                    break
                if k == n:
                    break
                tk = time[k]
                for do_step, component, name in steppers:
                    st = do_step(component, tk, h, 1)
                    if st > 1:
                        raise CoSimulationError(f"{name}: fmi2DoStep returned {_STATUS.get(st, st)}; "
                                                f"log: {self.messages[-3:]}")
                if progress is not None and ((k + 1) % every_pct == 0 or k + 1 == n):
                    progress(k + 1, n)
        except Exception as exc:  # noqa: BLE001 - an FMU error while stepping ends this run, not the table
            status, message = "unbounded", f"step {k} (t = {k * h:.3f} s): {exc}"
        return {"time": time, "signals": {f"{f}.{v}": data[:, i] for i, (f, v) in enumerate(record)},
                "status": status, "message": message, "log": list(self.messages), "steps_done": k}


def run(system: System, progress: Callable[[int, int], None] | None = None) -> dict:
    """Load the system's FMUs, run once, free everything (see :meth:`Master.run` for the result)."""
    with Master(system.fmus, system.order, system.connections, system.algorithm) as m:
        return m.run(system.parameters, system.record, system.n_steps, system.step_size,
                     system.divergence_limit, progress)
