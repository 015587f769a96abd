"""A sign of life for long steps: a line every few seconds while a block runs (issue 34: no silence over 10 s)."""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from collections.abc import Callable

#: Seconds between two heartbeat lines: well under the 10 s of silence a user may see (issue 34).
HEARTBEAT_S = 5.0


def say(message: str, prefix: str = "") -> None:
    """Print ``<prefix><message>`` on stderr at once (a log shows it while the step runs); an unwritable stderr
    (2>/dev/full) is no reason to stop the work."""
    try:
        print(f"{prefix}{message}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


@contextlib.contextmanager
def heartbeat(what: str, every: float = HEARTBEAT_S, emit: Callable[[str], None] | None = None):
    """While the block runs, ``<what>: still at it, 15 s`` every `every` seconds, through `emit` (default
    :func:`say`).

    For a step that prints nothing of its own for longer than a user should wait without a sign of life: a C
    compiler building its libraries for the first time, CasADi making and running a solver. The lines come from
    a daemon thread, which the block's own work lets run (compilers in other processes, CasADi and NumPy release
    the GIL); the thread ends with the block.
    """
    emit = say if emit is None else emit
    stop = threading.Event()
    start = time.monotonic()

    def beat() -> None:
        while not stop.wait(every):
            emit(f"{what}: still at it, {time.monotonic() - start:.0f} s")

    thread = threading.Thread(target=beat, name="heartbeat", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
