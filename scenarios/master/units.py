"""One loaded FMU as the master drives it: its FMI calls, the failures they report (:class:`FMUError`) and
what FMI 2.0 still allows after one, and the preallocated buffers values move through (:class:`Port`, :class:`Link`).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2Real,
    fmi2ValueReference,
)

from scenarios.master.compat import fmu2_raw_functions
from scenarios.master.fmi_callbacks import logging_callbacks
from scenarios.master.fmu_files import read_description, unpack
from scenarios.master.fmu_proxy import DEFAULT_STEP_TIMEOUT_S, RemoteSlave
from scenarios.master.interrupts import DeferSignals
from scenarios.master.values import parse_choices

STATUS_NAMES = {0: "ok", 1: "warning", 2: "discard", 3: "error", 4: "fatal", 5: "pending"}
#: What can happen to an FMU run in a process of its own (scenarios.master.fmu_proxy) besides an FMI status.
PROCESS_FAILURES = ("timeout", "crashed", "interrupted")


class CoSimulationError(RuntimeError):
    """The master cannot run this system (wiring, names, a closed master); raised before anything runs."""


class FMUError(CoSimulationError):
    """An FMU function returned fmi2Discard or worse.

    Attributes: ``instance``, ``function`` (e.g. ``fmi2DoStep``), ``status`` (its name: discard, error,
    fatal) and ``fmu_message`` (the last message that FMU logged with a status of discard or worse, as the
    FMI logger callback received it; "" when it logged none).
    """

    def __init__(self, instance: str, function: str, status: int | str, fmu_message: str, what: str = ""):
        self.instance, self.function = instance, function
        self.status = STATUS_NAMES.get(status, str(status))
        self.fmu_message = fmu_message
        if what:  # a process failure (PROCESS_FAILURES): what happened, and the FMU's last word if any
            super().__init__(f"{instance}: {what}" + (f" (its last message: {fmu_message})" if fmu_message else ""))
            return
        super().__init__(f"{instance}: {function} returned {self.status}"
                         + (f": {fmu_message}" if fmu_message else " (the FMU logged no message)"))


#: In-process FMUs that returned fmi2Fatal, with their callbacks: FMI 2.0 allows no further call (not even
#: fmi2FreeInstance) and the library may still call back, so they are kept, never freed or unloaded.
ABANDONED: list = []


class Unit:
    """One loaded FMU: its slave, variable references by name, raw FMI functions.

    `isolated`: run it in a process of its own (:class:`scenarios.master.fmu_proxy.RemoteSlave`), each call bounded
    by `timeout` seconds. After a failure only what FMI 2.0 (2.0.5) allows is called: after fmi2Error or
    fmi2Discard, fmi2Reset or fmi2FreeInstance (never fmi2Terminate); after fmi2Fatal nothing at all (an
    in-process instance is abandoned and the FMU unpacked and loaded afresh for the next run; a process of
    its own is killed); a process that timed out, crashed or was interrupted is replaced by a new one.
    """

    def __init__(self, name: str, path: Path, messages: list[str], isolated: bool = False,
                 timeout: float = DEFAULT_STEP_TIMEOUT_S):
        self.name, self.path, self.isolated, self.timeout = name, Path(path), isolated, timeout
        self.md = read_description(path)
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.slave = None
        #: The last message this FMU logged with status discard or worse (reset by :meth:`Master.run`).
        self.last_error = ""
        #: The worst failure since the FMU was last (re)started: None, an fmi2Status name or a PROCESS_FAILURES.
        self.failed: str | None = None
        self.unzipdir = unpack(path)

        def log(status: int, text: str) -> None:
            label = STATUS_NAMES.get(status, str(status))
            messages.append(f"[{name}] {text}" if status == 0 else f"[{name}] {label}: {text}")
            if status >= 2:  # fmi2Discard, fmi2Error, fmi2Fatal: kept by status, never by searching the text
                self.last_error = text

        def logger(component, instance_name, status, category, message):
            log(status, message.decode(errors="replace") if isinstance(message, bytes) else str(message))

        self._log = log
        self._callbacks = logging_callbacks(logger)
        try:
            self.instantiate()
        except BaseException:
            shutil.rmtree(self.unzipdir, ignore_errors=True)
            raise

    def error(self, function: str, status: int | str, what: str = "") -> FMUError:
        """The :class:`FMUError` for `function` returning `status`, with this FMU's logged message (and what
        happened, for a process failure); records the failure for what may be called next."""
        exc = FMUError(self.name, function, status, self.last_error, what)
        rank = [*STATUS_NAMES.values(), *PROCESS_FAILURES]
        if self.failed is None or rank.index(exc.status) > rank.index(self.failed):
            self.failed = exc.status
        return exc

    def call(self, function: str, fn, *args, **kwargs):
        """Call one of fmpy's FMU2Slave methods; an fmi2 status of discard or worse becomes :class:`FMUError`."""
        try:
            return fn(*args, **kwargs)
        except FMUError:  # a process failure of an isolated FMU, already told as such
            raise
        except Exception as exc:  # fmpy raises FMICallException(function, status)
            status = getattr(exc, "status", None)
            if status is None:
                raise
            raise self.error(getattr(exc, "function", function), status) from exc

    def instantiate(self) -> None:
        self.failed = None
        args = dict(guid=self.md.guid, unzipDirectory=self.unzipdir,
                    modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=self.name)
        if self.isolated:
            self.slave = RemoteSlave(self.unzipdir, self.md.guid, args["modelIdentifier"], self.name,
                                     timeout=self.timeout, on_log=self._log,
                                     failure=lambda fn, status, what: self.error(fn, status, what),
                                     should_stop=DeferSignals.pending)
            self.slave.instantiate(loggingOn=True)
            self.get_real, self.set_real, self.do_step = self.slave.raw_functions()
            return
        self.slave = FMU2Slave(**args)
        self.slave.instantiate(callbacks=self._callbacks, loggingOn=True)
        # fmpy's getReal/setReal allocate arrays and log each call; the stepping loop calls the library
        # functions directly with preallocated buffers.
        self.get_real, self.set_real, self.do_step = fmu2_raw_functions(self.slave)

    def restart(self) -> None:
        """Ready the FMU for a new run: fmi2Reset, or after a failure only what FMI allows (class docstring)."""
        if self.failed in (None, "warning", "discard", "error"):
            try:
                self.slave.reset()
                self.failed = None
                return
            except Exception:  # noqa: BLE001 - it refuses fmi2Reset: free it (allowed) and start it afresh
                self.failed = self.failed or "error"
        fresh_library = self.failed == "fatal" and not self.isolated
        self._free_instance()
        if fresh_library:  # the abandoned library stays loaded: a new copy of the files is a new library image
            self.unzipdir = unpack(self.path)
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
            self.slave.setInteger([v.valueReference], [self.choice(var, value)])
        elif v.type == "Boolean":
            self.slave.setBoolean([v.valueReference], [bool(value)])
        else:
            self.slave.setString([v.valueReference], [str(value)])

    def choice(self, var: str, value) -> int:
        """The integer of a choice parameter's option, given by its name (as scenario files write it)."""
        items = parse_choices(self.vars[var].description or "")
        if isinstance(value, str):
            if value not in items:
                raise CoSimulationError(f"{self.name}: {var} = {value!r} is not one of its choices "
                                        f"{', '.join(items) or '(none: an Integer without named choices)'}")
            return items[value]
        if isinstance(value, bool) or int(value) != value or (items and int(value) not in items.values()):
            raise CoSimulationError(f"{self.name}: {var} = {value!r} is not one of its choices "
                                    + ", ".join(f"{n} ({v})" for n, v in items.items()))
        return int(value)

    def _free_instance(self) -> None:
        if self.slave is None:
            return
        slave, self.slave = self.slave, None
        if self.isolated and self.failed in ("fatal", *PROCESS_FAILURES):
            slave.kill(f"not called after {self.failed}")  # nothing may be called; its process goes with it
            return
        if self.failed == "fatal":
            ABANDONED.append((slave, self._callbacks))
            return
        try:
            if self.failed in (None, "warning"):  # fmi2Terminate only from a working instance
                try:
                    slave.terminate()
                except Exception:  # noqa: BLE001 - it refuses: free it all the same
                    pass
            slave.freeInstance()
        finally:
            if self.isolated:
                slave.close()

    def free(self) -> None:
        try:
            self._free_instance()
        finally:
            shutil.rmtree(self.unzipdir, ignore_errors=True)


class Port:
    """Some Real outputs of one FMU, read with one ``fmi2GetReal`` into a preallocated buffer."""

    def __init__(self, unit: Unit, vrs: list[int]):
        n = len(vrs)
        self.unit, self.n = unit, n
        self.vrs = (fmi2ValueReference * n)(*vrs)
        self.buffer = (fmi2Real * n)()
        self.values = np.frombuffer(self.buffer, dtype=np.float64)
        self.position = {vr: i for i, vr in enumerate(vrs)}

    def read(self) -> None:
        status = self.unit.get_real(self.unit.slave.component, self.vrs, self.n, self.buffer)
        if status > 1:
            raise self.unit.error("fmi2GetReal", status)


class Link:
    """The connections from one FMU to another: values gathered from the source's port, one ``fmi2SetReal``."""

    def __init__(self, port: Port, src_vrs: list[int], dst: Unit, dst_vrs: list[int]):
        n = len(dst_vrs)
        self.port, self.dst, self.n = port, dst, n
        self.index = as_index([port.position[vr] for vr in src_vrs])
        self.dst_vrs = (fmi2ValueReference * n)(*dst_vrs)
        self.buffer = (fmi2Real * n)()
        self.values = np.frombuffer(self.buffer, dtype=np.float64)

    def write(self, zero: bool = False) -> None:
        self.values[:] = 0.0 if zero else self.port.values[self.index]
        status = self.dst.set_real(self.dst.slave.component, self.dst_vrs, self.n, self.buffer)
        if status > 1:
            raise self.dst.error("fmi2SetReal", status)


def as_index(positions: list[int]) -> slice | np.ndarray:
    """A slice where the positions are consecutive (a cheap copy), else an index array."""
    if positions == list(range(positions[0], positions[0] + len(positions))):
        return slice(positions[0], positions[0] + len(positions))
    return np.array(positions)
