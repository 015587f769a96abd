"""An FMU run in a process of its own, behind the interface the master uses (as libcosim's proxy and FMPy's
remoting do).

A controller that is not ours can crash (``os._exit``, SIGSEGV), raise, or never return from ``fmi2DoStep``.
In our process any of these ends or hangs the master; in a process of its own it ends only that process,
and the master records the case as ``error``, naming the FMU, the call, the time and what happened
(docs/outcomes.md). :class:`RemoteSlave` offers what :class:`scenarios.master.units.Unit` calls on fmpy's
``FMU2Slave`` (the lifecycle methods, the setters, and the raw ``fmi2GetReal`` / ``fmi2SetReal`` /
``fmi2DoStep`` the stepping loop calls on ctypes buffers), forwarding each call over a socket pair to
``python -m scenarios.master.fmu_proxy`` (:func:`serve`), which loads the FMU with fmpy and calls it. Values
cross as Python floats (IEEE doubles, pickled exactly): a run gives the same numbers in either process.

Every wait for a reply is bounded by the step timeout (the master's ``step_timeout``, ``--step-timeout``) and
abandoned at once when a signal is pending (Ctrl-C, SIGTERM): the FMU's process is then killed, never waited
for. The child ignores SIGINT (the master decides what a Ctrl-C means) and dies with its parent (Linux
``PR_SET_PDEATHSIG``), so a hung FMU never outlives the run.
"""

from __future__ import annotations

import ctypes
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path

#: The longest a communication step (and a get or set) may take before its FMU's process is killed, s, unless
#: the run says otherwise (``--step-timeout``): a step of a 1 ms loop takes milliseconds, so this is a hang.
DEFAULT_STEP_TIMEOUT_S = 60.0
#: ... and the longest for what FMUs do lazily: loading, instantiating, initialising, resetting, freeing, and
#: the first step of a run (the Python plant compiles its Numba kernels there: about 20 s on an idle machine,
#: several times that on a loaded one), s, or the step timeout if longer.
START_TIMEOUT_S = 300.0
#: How often a wait for a reply looks for a pending signal, s (Ctrl-C and SIGTERM act within this).
_POLL_S = 0.05


class _Status(Exception):
    """An FMI function returned discard or worse (fmpy's FMICallException): ``function`` and ``status``."""

    def __init__(self, function: str, status: int):
        super().__init__(f"{function} returned {status}")
        self.function, self.status = function, status


class RemoteSlave:
    """fmpy's ``FMU2Slave``, as the master uses it, for an FMU in a process of its own.

    Parameters
    ----------
    unzipdir, guid, model_identifier, instance_name
        As for ``FMU2Slave``.
    timeout : float
        Seconds a call may take (the step timeout) before the FMU's process is killed.
    on_log : callable
        ``on_log(status, text)`` for every message the FMU logs (as the master's logger callback).
    failure : callable
        ``failure(function, status, text)`` -> the exception to raise when the process fails (status one of
        ``timeout``, ``crashed``, ``interrupted``) or the child reports an exception (status ``error``).
    should_stop : callable
        True when a signal is pending: the call in progress is abandoned and the process killed.
    """

    component = None  # the master passes it back to the raw functions; the child holds the real one

    def __init__(self, unzipdir: str, guid: str, model_identifier: str, instance_name: str, *, timeout: float,
                 on_log: Callable[[int, str], None], failure: Callable[[str, str, str], Exception],
                 should_stop: Callable[[], bool]):
        self.timeout, self.on_log, self.failure, self.should_stop = float(timeout), on_log, failure, should_stop
        self.slow = max(self.timeout, START_TIMEOUT_S)  # the bound of lazy work (START_TIMEOUT_S)
        self._stepped = False  # a step since (re)start: the first one may be slow
        self.name = instance_name
        self.gone: str | None = None  # why the process is no more (then every call fails with it)
        ours, theirs = socket.socketpair()
        try:
            # PR_SET_PDEATHSIG follows the thread that started the child: asked for from the main thread only
            # (a Dask worker's task thread may end before its process); otherwise the child ends at the
            # socket's EOF when it next waits for a request
            die_with = "1" if threading.current_thread() is threading.main_thread() else "0"
            # the FMU's printing goes to our standard error, never into the table on standard output
            self.proc = subprocess.Popen([sys.executable, "-m", "scenarios.master.fmu_proxy", str(theirs.fileno()),
                                          die_with],
                                         pass_fds=[theirs.fileno()], stdin=subprocess.DEVNULL,
                                         stdout=_stderr_fd(), close_fds=True, env=_child_environment())
        finally:
            theirs.close()
        self.conn = Connection(ours.detach())
        self._vrs: dict[int, tuple] = {}
        self._unanswered: list[str] = []  # calls sent without waiting for their reply (fmi2SetReal)
        try:
            self._call("fmi2Instantiate (loading the FMU in its own process)",
                       ("load", unzipdir, guid, model_identifier, instance_name), self.slow)
        except BaseException:
            self.kill("not loaded")
            raise

    # ---------------------------------------------------------------- what Unit calls on an FMU2Slave

    def instantiate(self, callbacks=None, loggingOn: bool = True) -> None:  # noqa: N803 - fmpy's names
        self._lazy("fmi2Instantiate", ("method", "instantiate", (), {"loggingOn": loggingOn}))

    def __getattr__(self, name: str):
        if name in ("setupExperiment", "enterInitializationMode", "exitInitializationMode", "reset", "terminate",
                    "freeInstance", "setReal", "setInteger", "setBoolean", "setString"):
            function = "fmi2" + name[0].upper() + name[1:]
            if name in ("setReal", "setInteger", "setBoolean", "setString"):
                return lambda *args, **kwargs: self._call(function, ("method", name, args, kwargs))
            return lambda *args, **kwargs: self._lazy(function, ("method", name, args, kwargs))
        raise AttributeError(name)

    def raw_functions(self) -> tuple:
        """(fmi2GetReal, fmi2SetReal, fmi2DoStep) with the ctypes functions' signatures (see
        scenarios.master.compat)."""
        return self._get_real, self._set_real, self._do_step

    def _get_real(self, component, vrs, n, buffer) -> int:
        status, values = self._call("fmi2GetReal", ("get_real", self._refs(vrs)))
        if status <= 1:
            buffer[:n] = values
        return status

    def _set_real(self, component, vrs, n, buffer) -> int:
        """Sent without waiting: its status comes back ahead of the next call's reply (the child answers in
        order and, once a call failed, calls nothing more of the FMU until fmi2Reset), which saves a round trip
        per connection and step. A failure is raised, as fmi2SetReal's, by the next call or :meth:`sync`."""
        self._send("fmi2SetReal", ("set_real", self._refs(vrs), buffer[:n]))
        self._unanswered.append("fmi2SetReal")
        return 0

    def sync(self) -> None:
        """Collect the status of every call sent without waiting (raises its failure, if one failed)."""
        if self._unanswered:
            self._call("fmi2SetReal", ("ping",))

    def _do_step(self, component, t, h, no_set_prior) -> int:
        status = self._call("fmi2DoStep", ("do_step", float(t), float(h), int(no_set_prior)),
                            None if self._stepped else self.slow)
        self._stepped = True
        return status

    def _lazy(self, function: str, request: tuple):
        """A call of the FMU's lifecycle (bounded by :data:`START_TIMEOUT_S`); the next step is a first one."""
        self._stepped = False
        return self._call(function, request, self.slow)

    def _refs(self, vrs) -> list[int]:
        cached = self._vrs.get(id(vrs))
        if cached is None or cached[0] is not vrs:  # an id is unique only while its object lives: kept with it
            cached = self._vrs[id(vrs)] = (vrs, list(vrs))
        return cached[1]

    # ---------------------------------------------------------------- the process

    def _call(self, function: str, request: tuple, timeout: float | None = None):
        self._send(function, request)
        earlier = None  # the first failure of a call sent without waiting: it is the one to report
        while self._unanswered:
            sent = self._unanswered.pop(0)
            reply = self._receive(sent, timeout)
            if earlier is None and (reply[0] != "value" or reply[1] > 1):
                earlier = (sent, reply)
        reply = self._receive(function, timeout)
        if earlier is not None:
            function, reply = earlier
        kind, value = reply
        if kind == "value" and isinstance(value, int) and value > 1 and earlier is not None:
            raise self.failure(function, value, "")  # the raw call's status, as the master would raise it
        if kind == "status":  # fmpy raised FMICallException: the master turns it into FMUError
            raise _Status(function, value)
        if kind == "exception":
            raise self.failure(function, "error", value)
        if kind == "refused":  # a call after a failure the master has not seen cannot happen; said if it does
            raise self.failure(function, "error", f"{function} not called: the FMU failed before (status {value})")
        return value

    def _send(self, function: str, request: tuple) -> None:
        if self.gone is not None:
            raise self.failure(function, "crashed", f"{function} not called: {self.gone}")
        try:
            self.conn.send(request)
        except OSError:
            self.kill(None)
            raise self.failure(function, "crashed", f"{function} not called: {self.gone}") from None

    def _receive(self, function: str, timeout: float | None) -> tuple:
        """(kind, value) of the next reply, its log passed on; a process failure raised as such."""
        timeout = self.timeout if timeout is None else timeout
        try:
            deadline = time.monotonic() + timeout
            while not self.conn.poll(_POLL_S):
                if self.should_stop():
                    self.kill(f"a signal came while {function} ran; its process was killed")
                    raise self.failure(function, "interrupted", self.gone)
                if time.monotonic() > deadline:
                    bound = ("the step timeout, --step-timeout" if timeout == self.timeout else
                             "the bound on loading, initialising and a run's first step")
                    self.kill(f"{function} did not return within {timeout:g} s ({bound}); its process was killed")
                    raise self.failure(function, "timeout", self.gone)
            kind, value, logs = self.conn.recv()
        except (EOFError, OSError):
            self.kill(None)
            raise self.failure(function, "crashed", f"{function} did not return: {self.gone}") from None
        for status, text in logs:
            self.on_log(status, text)
        return kind, value

    def kill(self, why: str | None) -> None:
        """End the process (SIGKILL if it is still there) and record why (`why` None: it ended by itself)."""
        if self.proc.poll() is None and why is not None:
            self.proc.kill()
        try:
            code = self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:  # not even SIGKILL: nothing more we can do than to say so
            code = None
        if why is None:
            why = ("its process was lost" if code is None else
                   f"its process was killed by {_signal_name(-code)}" if code < 0 else
                   f"its process ended with exit code {code}")
        self.gone = self.gone or why
        self.conn.close()

    def close(self, timeout: float = 10.0) -> None:
        """Let the process exit (it frees nothing more: the master has called what FMI allows), else kill it."""
        if self.gone is not None:
            return
        try:
            self.conn.send(("exit",))
            self.proc.wait(timeout=timeout)
        except (OSError, subprocess.TimeoutExpired):
            pass
        self.kill("closed")


def _signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def _child_environment() -> dict[str, str]:
    """Our environment, with the folder this package was imported from first on the child's path: the child
    runs the same code as the master, whatever the current directory (another checkout, an editable install)."""
    home = Path(__file__).resolve().parents[2]
    if {"site-packages", "dist-packages"} & set(home.parts):  # an installed copy: the child finds it as we did
        return dict(os.environ)
    path = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(home), *path])}


def _stderr_fd() -> int:
    """Standard error's descriptor (2 when sys.stderr is no file, e.g. captured by a test)."""
    try:
        return sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        return 2


def serve(fd: int, die_with_parent: bool = True) -> None:
    """The child: load the FMU named by the first request, then answer requests until ``exit`` or EOF."""
    from fmpy.fmi2 import FMU2Slave

    from scenarios.master.compat import fmu2_raw_functions
    from scenarios.master.fmi_callbacks import logging_callbacks

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C is the master's to act on; it kills us if need be
    if die_with_parent:  # die with the master, even when it is killed (SIGKILL) while we hang
        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except (AttributeError, OSError):
            pass
        if os.getppid() == 1:
            return
    conn = Connection(fd)
    logs: list[tuple[int, str]] = []

    def logger(component, instance_name, status, category, message):
        logs.append((status, message.decode(errors="replace") if isinstance(message, bytes) else str(message)))

    callbacks = logging_callbacks(logger)
    slave = get_real = set_real = do_step = None
    failed = None  # the status of a call that failed: nothing more of the FMU is called until fmi2Reset
    from fmpy.fmi2 import fmi2Real, fmi2ValueReference

    while True:
        try:
            request = conn.recv()
        except EOFError:
            return
        op = request[0]
        try:
            if op == "exit":
                return
            if failed is not None and not (op == "method" and request[1] in ("reset", "freeInstance")):
                reply = ("refused", failed)
            elif op == "ping":
                reply = ("value", 0)
            elif op == "load":
                _, unzipdir, guid, model_identifier, instance_name = request
                slave = FMU2Slave(guid=guid, unzipDirectory=unzipdir, modelIdentifier=model_identifier,
                                  instanceName=instance_name)
                reply = ("value", None)
            elif op == "method":
                _, name, args, kwargs = request
                if name == "instantiate":
                    slave.instantiate(callbacks=callbacks, **kwargs)
                    get_real, set_real, do_step = fmu2_raw_functions(slave)
                    reply = ("value", None)
                else:
                    reply = ("value", getattr(slave, name)(*args, **kwargs))
                    failed = None if name == "reset" else failed
            elif op == "do_step":
                reply = ("value", do_step(slave.component, *request[1:]))
            elif op == "get_real":
                n = len(request[1])
                buffer = (fmi2Real * n)()
                status = get_real(slave.component, (fmi2ValueReference * n)(*request[1]), n, buffer)
                reply = ("value", (status, list(buffer)))
            elif op == "set_real":
                n = len(request[1])
                reply = ("value", set_real(slave.component, (fmi2ValueReference * n)(*request[1]), n,
                                           (fmi2Real * n)(*request[2])))
            else:
                reply = ("exception", f"unknown request {op!r}")
        except Exception as exc:  # noqa: BLE001 - fmpy's FMICallException carries the status; the rest is text
            status = getattr(exc, "status", None)
            reply = ("status", status) if status is not None else ("exception", f"{type(exc).__name__}: {exc}")
        if failed is None and (reply[0] in ("status", "exception") or (
                op in ("do_step", "set_real") and reply[1] > 1) or (op == "get_real" and reply[1][0] > 1)):
            failed = reply[1] if reply[0] == "status" else 3
        conn.send((*reply, list(logs)))
        logs.clear()


if __name__ == "__main__":
    serve(int(sys.argv[1]), sys.argv[2:] != ["0"])
