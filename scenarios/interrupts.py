"""Signals during FMU code: Ctrl-C (SIGINT) and SIGTERM turned into a flag the master acts on between calls.

An FMU written in Python runs in this interpreter, so a KeyboardInterrupt or SystemExit raised in its code
would be caught there and returned as fmi2Error, i.e. reported as the FMU failing. While a
:class:`DeferSignals` is active the master checks the flag between steps, and a wait for an FMU running in a
process of its own (:mod:`scenarios.fmu_proxy`) checks it every few milliseconds and gives the call up.
"""

from __future__ import annotations

import signal
import threading


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
