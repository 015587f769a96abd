"""One line per build step on stderr, before the step starts: what it does and about how long it takes; and a
heartbeat for a step that can stay silent longer (a first compile with empty caches)."""

from __future__ import annotations

import contextlib
import sys
import threading
import time

#: Seconds between two heartbeat lines: well under the 10 s of silence a user may see (issue 34).
HEARTBEAT_S = 5.0


def say(message: str, prefix: str = "fmu_build: ") -> None:
    """Print ``fmu_build: <message>`` on stderr at once (a log shows it while the step runs)."""
    try:
        print(f"{prefix}{message}", file=sys.stderr, flush=True)
    except (OSError, ValueError):  # standard error unwritable (2>/dev/full): no reason to stop a build
        pass


@contextlib.contextmanager
def heartbeat(what: str, every: float = HEARTBEAT_S, prefix: str = "fmu_build: "):
    """While the block runs, a line on stderr every `every` seconds, ``<prefix><what>: still at it, 15 s``.

    For a step that prints nothing of its own for longer than a user should wait without a sign of life: a C
    compiler building its libraries for the first time, Numba compiling kernels on a first run. The lines come
    from a daemon thread, which the block's own work lets run (compilers in other processes, or code that
    releases the GIL between Python bytecodes); the thread ends with the block.
    """
    stop = threading.Event()
    start = time.monotonic()

    def beat() -> None:
        while not stop.wait(every):
            say(f"{what}: still at it, {time.monotonic() - start:.0f} s", prefix)

    thread = threading.Thread(target=beat, name="heartbeat", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
