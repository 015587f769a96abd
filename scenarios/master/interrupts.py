"""Signals during FMU code: Ctrl-C (SIGINT) and SIGTERM turned into a flag the master acts on between calls.

An FMU written in Python runs in this interpreter, so a KeyboardInterrupt or SystemExit raised in its code
would be caught there and returned as fmi2Error, i.e. reported as the FMU failing. While a
:class:`DeferSignals` is active the master checks the flag between steps, and a wait for an FMU running in a
process of its own (:mod:`scenarios.master.fmu_proxy`) checks it every few milliseconds and gives the call up.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

#: Seconds a deferred Ctrl-C or SIGTERM waits for the master to act on it (it does between two FMU calls)
#: before the process ends anyway, with the signal's exit code: an FMU call in this process that never returns
#: (a hang in C, or Python code that never gives control back) cannot be cut short any other way.
GRACE_S = 3.0


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C during a run: the run stopped after its current step and its values are no result."""


class DeferSignals:
    """While active (main thread only), Ctrl-C (and SIGTERM, when Python handles it) sets a flag instead of
    raising inside FMU code.

    An FMU written in Python runs in this interpreter: a KeyboardInterrupt or SystemExit raised in its code
    would be caught there and returned as fmi2Error, i.e. reported as the FMU failing. The flag is checked
    between steps (:meth:`raise_pending`); a second signal while the flag is set raises at once. A wait for
    an FMU in a process of its own asks :meth:`pending` and gives up the call at once.
    """

    _active: list[DeferSignals] = []

    @classmethod
    def pending(cls) -> bool:
        """Whether a signal is waiting to be acted on (in any active deferral of this process)."""
        return any(d.signum is not None for d in cls._active)

    def __enter__(self) -> DeferSignals:
        self.signum = None
        self.previous = {}
        DeferSignals._active.append(self)
        if threading.current_thread() is threading.main_thread():
            _Watchdog.start()
            def handler(signum, frame):
                if self.signum is not None:
                    self._raise(signum, "twice")
                self.signum = signum

            for sig in (signal.SIGINT, signal.SIGTERM):
                if sig == signal.SIGINT or callable(signal.getsignal(sig)):  # never replace SIGTERM's default kill
                    self.previous[sig] = signal.signal(sig, handler)
        return self

    def is_set(self) -> bool:
        return self.signum is not None

    def raise_pending(self, where: str) -> None:
        """Raise what the deferred signal would have raised (RunInterrupted for Ctrl-C), if one came."""
        if self.signum is not None:
            self._raise(self.signum, where)

    def _raise(self, signum: int, where: str) -> None:
        previous = self.previous.get(signum)
        if signum != signal.SIGINT and callable(previous):
            previous(signum, None)  # e.g. the command line's SIGTERM handler: SystemExit(143)
        raise RunInterrupted(f"interrupted {where}")

    def __exit__(self, *exc) -> None:
        DeferSignals._active.remove(self)
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)


class _Watchdog:
    """A thread that sees every signal Python handles (``signal.set_wakeup_fd``: written by the C-level
    handler, even while the main thread is stuck in C code and no Python handler can run). A Ctrl-C or
    SIGTERM that arrives while the main thread is inside a :class:`DeferSignals`, and finds it still inside the
    same one :data:`GRACE_S` later, ends the process: this process's unpacked FMUs are removed (FMUs in
    processes of their own die with it) and it exits 130 (SIGINT) or 143 (SIGTERM), as docs/outcomes.md says.
    """

    started = False

    @classmethod
    def start(cls) -> None:
        if cls.started:
            return
        cls.started = True
        read, write = os.pipe()
        os.set_blocking(write, False)
        try:
            forward = signal.set_wakeup_fd(write, warn_on_full_buffer=False)
        except ValueError:  # not the main thread of the main interpreter
            os.close(read)
            os.close(write)
            return
        threading.Thread(target=cls._watch, args=(read, forward), daemon=True, name="signal-watchdog").start()

    @staticmethod
    def _watch(read: int, forward: int) -> None:
        while True:
            data = os.read(read, 64)
            if not data:
                return
            if forward >= 0:  # whoever had the wakeup fd before (an asyncio loop) still gets its bytes
                try:
                    os.write(forward, data)
                except OSError:
                    pass
            for signum in data:
                if signum not in (signal.SIGINT, signal.SIGTERM):
                    continue
                waiting = [d for d in DeferSignals._active if d.previous]  # the main thread's deferrals
                if not waiting:
                    continue
                time.sleep(GRACE_S)
                if any(d in DeferSignals._active for d in waiting):
                    _end_now(signum)


def _end_now(signum: int) -> None:
    code = 130 if signum == signal.SIGINT else 143
    try:
        os.write(sys.stderr.fileno(), f"interrupted: an FMU call did not return within {GRACE_S:g} s of the "
                                      f"{signal.Signals(signum).name}; ending the process now (exit {code})\n"
                                      .encode())
    except (OSError, ValueError):
        pass
    try:
        from scenarios.master.fmu_files import _remove_own

        _remove_own(os.getpid())
    finally:
        os._exit(code)
