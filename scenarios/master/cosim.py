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
It follows libcosim exactly, so that the two masters can be compared bit for
bit: one exchange round per FMU during initialisation, and time points kept
in integer nanoseconds (t_k = k·h_ns / 1e9, step t_k+1 − t_k).

``algorithm="fmpy-ssp"`` steps as fmpy's ``simulate_ssp`` (fmpy 0.3.x,
``fmpy/ssp/simulation.py``) does, so that the two can be compared bit for bit:
Jacobi exchange as above, but no exchange during initialisation (every
connected input is 0 over the first step), and time accumulated in doubles
(t_k+1 = t_k + h, step h). Like ``simulate_ssp`` it reads nothing before
the first step (a controller that sees no read and its placeholder there
starts the slew a sample later: docs/control.md), so its result has no
sample at t = 0: n rows, the values after each step, at t_1 .. t_n
(``simulate_ssp`` labels its row k with the time the step started, t_k).

A :class:`Master` loads its FMUs once and can run many times (``fmi2Reset``
between runs), which is what sweeps do; :func:`run` is the one-shot form.

A run ends with one typed :class:`Outcome` (see docs/outcomes.md): ``ok``;
``unbounded`` (a recorded signal left the bounds: when and which);
``error`` (an FMU returned fmi2Error/fmi2Fatal: which FMU, which function,
the status and the FMU's own logged message, taken from the FMI status the
logger callback receives); or ``interrupted`` (Ctrl-C: :meth:`Master.run`
raises :class:`RunInterrupted` after the current step, or with the loop in C
at the next progress point, a hundredth of the run; never inside FMU code).
Values move between FMUs through preallocated ctypes buffers: per step one
``fmi2GetReal`` per FMU (connections and records together) and one
``fmi2SetReal`` per connected pair of FMUs. For FMUs in this process the loop
runs in C when a compiler is at hand (:mod:`scenarios.master.step_loop`: the
same calls in the same order, bit for bit the same run).
Everything the master loads is freed, also when a step fails.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scenarios.master.fmu_proxy import DEFAULT_STEP_TIMEOUT_S
from scenarios.master.interrupts import DeferSignals, RunInterrupted  # noqa: F401 - RunInterrupted: raised by Master.run, imported from here
from scenarios.master.units import CoSimulationError, FMUError, Link, Port, Unit, as_index

ALGORITHMS = ("gauss-seidel", "jacobi", "fmpy-ssp")
#: The outcomes of a run, in the order docs/outcomes.md explains them.
OUTCOMES = ("ok", "unbounded", "error", "interrupted")


@dataclass
class Outcome:
    """How a run ended (see the module docstring and docs/outcomes.md)."""

    status: str  # one of OUTCOMES
    message: str = ""
    #: unbounded: the time (s) and the recorded signal ("fmu.var") that left the bounds first.
    time: float | None = None
    signal: str | None = None
    #: error: the FMU instance, the FMI function, its status name and the FMU's logged message.
    fmu: str | None = None
    function: str | None = None
    fmu_status: str | None = None
    fmu_message: str | None = None

    @classmethod
    def from_error(cls, exc: FMUError, where: str) -> Outcome:
        return cls("error", f"{where}: {exc}", fmu=exc.instance, function=exc.function, fmu_status=exc.status,
                   fmu_message=exc.fmu_message)

    def as_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if v is not None}


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
    #: Communication steps; no default: the run length comes from the trajectory (scenarios.run.setup.run_length).
    n_steps: int | None = None
    #: |value| above which a recorded signal counts as numerically unbounded.
    divergence_limit: float = 1e4
    #: "gauss-seidel" (the default, see the module docstring) or "jacobi".
    algorithm: str = "gauss-seidel"


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
    isolate : collection of str
        Instances run each in a process of their own (:mod:`scenarios.master.fmu_proxy`): a crash, a hang or an
        ``os._exit`` there ends only the run, as ``error``. The others run in this process, at full speed.
    step_timeout : float
        Seconds any call of an isolated FMU may take before its process is killed (the run then ends as
        ``error``, status ``timeout``).

    Use as a context manager, or call :meth:`close`. Between two runs every
    FMU is reset with ``fmi2Reset`` (an FMU that refuses is instantiated
    anew), so a run never sees the previous run's state.
    """

    def __init__(self, fmus: dict[str, Path], order: list[str], connections: list[Connection],
                 algorithm: str = "gauss-seidel", isolate=(), step_timeout: float = DEFAULT_STEP_TIMEOUT_S):
        if algorithm not in ALGORITHMS:
            raise CoSimulationError(f"algorithm: one of {ALGORITHMS}, got {algorithm!r}")
        if not step_timeout > 0:
            raise CoSimulationError(f"step timeout: a number of seconds > 0, got {step_timeout!r}")
        unknown = sorted(set(isolate) - set(fmus))
        if unknown:
            raise CoSimulationError(f"isolate: instances of this system {sorted(fmus)}, got {unknown}")
        missing = sorted(set(order) ^ set(fmus))
        if missing:
            raise CoSimulationError(f"order: must list every FMU instance exactly once (mismatch: {missing})")
        self.order, self.algorithm = list(order), algorithm
        self.messages: list[str] = []
        self.units: dict[str, Unit] = {}
        self._used = False
        with DeferSignals() as interrupted:  # FMU code runs while loading: Ctrl-C is acted on afterwards
            try:
                for name in self.order:
                    self.units[name] = Unit(name, fmus[name], self.messages, name in isolate, step_timeout)
                    if interrupted.is_set():
                        break
                self._wire(connections)
            except BaseException as exc:  # free what was loaded on every path, Ctrl-C included
                self.close()
                interrupted.raise_pending("while loading the FMUs")  # an isolated FMU's load given up for it
                if isinstance(exc, CoSimulationError) or not isinstance(exc, Exception):
                    raise
                raise CoSimulationError(f"could not load the FMUs: {exc}; log: {self.messages[-5:]}") from exc
            if interrupted.is_set():
                self.close()
                interrupted.raise_pending("while loading the FMUs")

    def _wire(self, connections: list[Connection]) -> None:
        self.groups: dict[tuple[str, str], list[tuple[int, int]]] = {}
        driver: dict[tuple[str, str], str] = {}
        for c in connections:
            edge = f"{c.src_fmu}.{c.src_var} -> {c.dst_fmu}.{c.dst_var}"
            for inst in (c.src_fmu, c.dst_fmu):
                if inst not in self.units:
                    raise CoSimulationError(f"connection {edge}: no FMU instance '{inst}' (have: {sorted(self.units)})")
            other = driver.setdefault((c.dst_fmu, c.dst_var), f"{c.src_fmu}.{c.src_var}")
            if other != f"{c.src_fmu}.{c.src_var}" or sum(
                    (d.dst_fmu, d.dst_var, d.src_fmu, d.src_var) == (c.dst_fmu, c.dst_var, c.src_fmu, c.src_var)
                    for d in connections) > 1:
                raise CoSimulationError(f"connection {edge}: input {c.dst_fmu}.{c.dst_var} is already driven by "
                                        f"{other}; one input takes one connection")
            src, dst = self.units[c.src_fmu], self.units[c.dst_fmu]
            self.groups.setdefault((c.src_fmu, c.dst_fmu), []).append((src.vr(c.src_var), dst.vr(c.dst_var)))

    def _plan(self, record: list[tuple[str, str]]) -> tuple[list, list]:
        """The per-step operations and, per recorded signal, (port, position) to read it from.

        Every FMU's needed outputs (connections and records) are read with one
        call at its turn. A recorded output that depends on an input set later
        in the step (a feedback edge, per the modelDescription's output
        dependencies) is read again at the end, so records are always the
        values at t_k after all inputs are set.
        """
        rank = {name: i for i, name in enumerate(self.order)}
        needed: dict[str, list[int]] = {name: [] for name in self.order}
        rec_vrs = []
        for inst, var in record:  # records first, in record order: they are then copied as slices
            if inst not in self.units:
                raise CoSimulationError(f"record: no FMU instance '{inst}' (have: {sorted(self.units)})")
            vr = self.units[inst].vr(var)
            rec_vrs.append(vr)
            if vr not in needed[inst]:
                needed[inst].append(vr)
        for (s, _d), pairs in self.groups.items():
            needed[s] += [vr for vr, _ in pairs if vr not in needed[s]]
        ports = {name: Port(self.units[name], vrs) for name, vrs in needed.items() if vrs}
        forward = {name: [] for name in self.order}
        feedback = []
        for (s, d), pairs in self.groups.items():
            link = Link(ports[s], [p[0] for p in pairs], self.units[d], [p[1] for p in pairs])
            (forward[d] if rank[s] < rank[d] else feedback).append(link)
        again: dict[str, Port] = {}
        if self.algorithm in ("jacobi", "fmpy-ssp"):  # every value as it was before any input changed, then all set
            ops = [port.read for port in ports.values()]
            ops += [link.write for name in self.order for link in forward[name]] + [link.write for link in feedback]
        else:
            ops = []
            for name in self.order:
                ops += [link.write for link in forward[name]]
                if name in ports:
                    ops.append(ports[name].read)
            ops += [link.write for link in feedback]
            late = {name: set() for name in self.order}
            for link in feedback:
                late[link.dst.name].update(link.dst_vrs)
            reread: dict[str, list[int]] = {}
            for (inst, var), vr in zip(record, rec_vrs):
                stale = late[inst] and self._depends_on(self.units[inst], var, late[inst])
                if stale and vr not in reread.get(inst, []):
                    reread.setdefault(inst, []).append(vr)
            again = {inst: Port(self.units[inst], vrs) for inst, vrs in reread.items()}
            ops += [port.read for port in again.values()]
        sources = []
        for (inst, _), vr in zip(record, rec_vrs):
            port = again[inst] if inst in again and vr in again[inst].position else ports[inst]
            sources.append((port, port.position[vr]))
        return ops, sources

    @staticmethod
    def _depends_on(unit: Unit, var: str, inputs: set[int]) -> bool:
        """Whether output `var` may depend on any of the input value references `inputs`."""
        for out in unit.md.outputs:
            if out.variable.name == var:
                if out.dependencies is None:  # not declared: assume it depends on every input
                    return True
                return any(d.valueReference in inputs for d in out.dependencies)
        return False  # not an output (a state or local): only changes when the FMU steps

    def __enter__(self) -> Master:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Terminate and free every FMU and delete the unpacked files."""
        units, self.units = self.units, {}
        failures = []
        with DeferSignals() as interrupted:  # fmi2Terminate/fmi2FreeInstance run FMU code: never cut them short
            for unit in units.values():
                try:
                    unit.free()
                except Exception as exc:  # noqa: BLE001 - free the others all the same, then say so
                    failures.append(f"{unit.name}: {exc}")
        interrupted.raise_pending("while freeing the FMUs (they were freed)")
        if failures:
            raise CoSimulationError("could not free every FMU: " + "; ".join(failures))

    def _initialise(self, parameters: dict[str, dict]) -> None:
        """Reset (after a first run), set the parameters and initialise every FMU; :class:`FMUError` on refusal."""
        for name, unit in self.units.items():
            unit.last_error = ""
            if self._used:
                unit.restart()
            unit.call("fmi2SetupExperiment", unit.slave.setupExperiment, startTime=0.0)
            for var, value in parameters.get(name, {}).items():
                unit.call(f"fmi2Set ({var} = {value!r})", unit.set, var, value)
            unit.call("fmi2EnterInitializationMode", unit.slave.enterInitializationMode)
        if self.algorithm == "jacobi":
            # As libcosim: one exchange round per FMU in initialisation mode, so that a
            # chain of feedthrough FMUs is consistent at the start time.
            ops, _ = self._plan([])
            for _ in range(len(self.units)):
                for op in ops:
                    op()
        for unit in self.units.values():
            unit.call("fmi2ExitInitializationMode", unit.slave.exitInitializationMode)
        self._used = True

    def run(self, parameters: dict[str, dict] | None, record: list[tuple[str, str]], n_steps: int,
            step_size: float = 1e-3, divergence_limit: float = 1e4,
            progress: Callable[[int, int], None] | None = None) -> dict:
        """Initialise every FMU with `parameters` and step `n_steps` times.

        Parameters
        ----------
        parameters : dict
            {instance: {variable: value}}, set before initialisation (values of the FMU variable's type:
            see :func:`scenarios.master.values.check_parameters`).
        record : list of (instance, variable)
            Real variables to record at every communication point.
        n_steps : int
            Number of communication steps; `n_steps` + 1 samples are recorded (fmpy-ssp: `n_steps`, none at
            t = 0). No default: the run
            length comes from the trajectory (:func:`scenarios.run.setup.run_length`).
        step_size : float
            Communication step, s.
        divergence_limit : float
            A recorded |value| above this (or non-finite) ends the run as "unbounded".
        progress : callable, optional
            ``progress(k, n_steps)``, called about a hundred times per run.

        Returns
        -------
        dict
            ``time`` (n+1,), ``signals`` {"fmu.var": ndarray (n+1,)}, ``outcome`` (:class:`Outcome`),
            its ``status`` and ``message``, the FMUs' ``log`` and ``steps_done``. An unbounded or
            error run returns what it recorded up to then (NaN after).

        Raises
        ------
        RunInterrupted
            On Ctrl-C (SIGINT, when called from the main thread): after the current step, with the FMUs
            left reusable; nothing of the run is returned.
        CoSimulationError
            Before anything runs: a closed master, an unknown record.
        """
        if not self.units:
            raise CoSimulationError("the master is closed")
        self.messages.clear()
        n, h = int(n_steps), float(step_size)
        if self.algorithm == "jacobi":  # libcosim's clock: integer nanoseconds, converted per point
            time = np.arange(n + 1) * round(h * 1e9) / 1e9
        elif self.algorithm == "fmpy-ssp":  # fmpy's simulate_ssp: time += h
            time = np.array(list(itertools.accumulate([0.0] + [h] * n)))
        else:
            time = np.arange(n + 1) * h
        steps = np.diff(time) if self.algorithm == "jacobi" else np.full(n, h)
        record = list(record)
        names = [f"{f}.{v}" for f, v in record]
        data = np.full((n + 1, len(record)), np.nan)
        ops, sources = self._plan(record)  # names unknown records before anything runs
        first_ops = ops
        fmpy = self.algorithm == "fmpy-ssp"
        if fmpy:  # the first step with every connected input at 0, and nothing read before it
            links = [op.__self__ for op in ops if getattr(op, "__func__", None) is Link.write]
            first_ops = [functools.partial(link.write, True) for link in links]
        # data[k] is gathered from the ports' buffers: one fancy-index per port.
        gathers = {}
        for col, (port, pos) in enumerate(sources):
            gathers.setdefault(id(port), (port, [], []))
            gathers[id(port)][1].append(col)
            gathers[id(port)][2].append(pos)
        gathers = [(port, as_index(cols), as_index(pos)) for port, cols, pos in gathers.values()]
        every_pct = max(1, n // 100)
        outcome, k, gathered = Outcome("ok"), 0, -1
        with DeferSignals() as interrupted:
            try:
                self._initialise(parameters or {})
            except FMUError as exc:
                self._used = True
                outcome = Outcome.from_error(exc, "initialisation (nothing ran)")
                n = -1  # skip the loop
            steppers = [(u.do_step, u.slave.component, u) for u in (self.units[name] for name in self.order)]
            compiled = self._compiled_loop(ops, gathers, data, time, steps, divergence_limit) if n > 0 else None
            try:
                for k in range(n + 1):
                    if compiled is not None and k:  # points k .. the next progress point in C, the same calls
                        k, gathered, stop, error = self._run_compiled(compiled, k, n, every_pct, names, time,
                                                                      progress, interrupted)
                        if error is not None:
                            raise error
                        outcome = stop or outcome
                        break
                    for op in (ops if k else first_ops):
                        op()
                    row = data[k]
                    for port, cols, pos in gathers if k or not fmpy else ():  # fmpy: no sample at t = 0
                        row[cols] = port.values[pos]
                    gathered = k
                    if (k or not fmpy) and not np.abs(row).max(initial=0.0) < divergence_limit:  # NaN, inf too
                        bad = names[int(np.argmax(~(np.abs(row) < divergence_limit)))]
                        outcome = Outcome("unbounded", f"{bad} = {row[names.index(bad)]:.6g} left the bounds "
                                          f"(|value| < {divergence_limit:g}) at t = {time[k]:.6g} s",
                                          time=float(time[k]), signal=bad)
                        break
                    if interrupted.is_set() or k == n:
                        break
                    tk, hk = time[k], steps[k]
                    for do_step, component, unit in steppers:
                        st = do_step(component, tk, hk, 1)
                        if st > 1:
                            raise unit.error("fmi2DoStep", st)
                    if progress is not None and ((k + 1) % every_pct == 0 or k + 1 == n):
                        progress(k + 1, n)
                for unit in self.units.values():  # an isolated FMU's fmi2SetReal status comes with its next call
                    if unit.isolated and unit.slave is not None:
                        unit.slave.sync()
            except FMUError as exc:
                data[gathered + 1:] = np.nan  # a partly gathered row is no sample
                outcome = Outcome.from_error(exc, f"step {k} (t = {time[k]:.3f} s)")
            interrupted.raise_pending(f"at step {k} (t = {time[max(k, 0)]:.6g} s)")
        first = 1 if fmpy else 0  # fmpy: the values after each step only
        return {"time": time[first:], "signals": {name: data[first:, i] for i, name in enumerate(names)},
                "outcome": outcome, "status": outcome.status, "message": outcome.message,
                "log": list(self.messages), "steps_done": max(k, 0)}

    def _compiled_loop(self, ops, gathers, data, time, steps, limit):
        """The C loop of this run's plan (:mod:`scenarios.master.step_loop`), or None: no compiler, turned off,
        or an FMU whose functions are not the library's (one in its own process, one wrapped in Python)."""
        from . import step_loop

        units = [self.units[name] for name in self.order]
        fn = None if not all(step_loop.calls_c(u) for u in units) else step_loop.loop_function()
        return None if fn is None else step_loop.CompiledLoop(fn, ops, units, gathers, data, time, steps, limit)

    @staticmethod
    def _run_compiled(compiled, k: int, n: int, every_pct: int, names, time, progress, interrupted):
        """Points k .. n in C, a progress point at a time (its callback and Ctrl-C between): (the last point,
        the last row gathered, an unbounded Outcome or None, the failing FMU's FMUError or None)."""
        from .step_loop import STEP_FAILED, STEP_UNBOUNDED

        while True:
            end = min(n + 1, (k // every_pct + 1) * every_pct)  # stepping after end - 1 makes end steps done
            status = compiled.run(k, end, n)
            last, gathered = int(compiled.out[0]), int(compiled.out[5])
            if status == STEP_FAILED:
                return last, gathered, None, compiled.failure()
            if status == STEP_UNBOUNDED:
                row = compiled.data[last]
                bad = names[int(compiled.out[1])]
                return last, gathered, Outcome(
                    "unbounded", f"{bad} = {row[names.index(bad)]:.6g} left the bounds (|value| < "
                    f"{compiled.limit:g}) at t = {time[last]:.6g} s", time=float(time[last]), signal=bad), None
            if end == n + 1:
                return n, gathered, None, None
            if progress is not None and (end % every_pct == 0 or end == n):
                progress(end, n)
            k = end
            if interrupted.is_set():
                return k, gathered, None, None

    def probe(self, parameters: dict[str, dict] | None, step_size: float) -> Outcome:
        """Initialise with `parameters` and take one communication step of `step_size`, recording nothing.

        Tells, before a long run, whether the FMUs accept the parameters and the step (an FMU that
        refuses a step returns fmi2Error from fmi2DoStep, with its reason in the log).
        """
        return self.run(parameters, [], 1, step_size)["outcome"]


def run(system: System, progress: Callable[[int, int], None] | None = None) -> dict:
    """Load the system's FMUs, run once, free everything (see :meth:`Master.run` for the result)."""
    if system.n_steps is None:
        raise CoSimulationError("System.n_steps: the number of communication steps (from the trajectory), got None")
    with Master(system.fmus, system.order, system.connections, system.algorithm) as m:
        return m.run(system.parameters, system.record, system.n_steps, system.step_size,
                     system.divergence_limit, progress)
