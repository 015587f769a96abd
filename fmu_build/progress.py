"""One line per build step on stderr, before the step starts: what it does and about how long it takes."""

from __future__ import annotations

import sys


def say(message: str) -> None:
    """Print ``fmu_build: <message>`` on stderr at once (a log shows it while the step runs)."""
    try:
        print(f"fmu_build: {message}", file=sys.stderr, flush=True)
    except (OSError, ValueError):  # standard error unwritable (2>/dev/full): no reason to stop a build
        pass
