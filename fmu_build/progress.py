"""One line per build step on stderr, before the step starts: what it does and about how long it takes; and a
heartbeat for a step that can stay silent longer (a first compile with empty caches). The machinery is
:mod:`flexarm.progress`'s; this adds the ``fmu_build:`` prefix."""

from __future__ import annotations

import functools

from flexarm import progress as _progress
from flexarm.progress import HEARTBEAT_S

__all__ = ["HEARTBEAT_S", "heartbeat", "say"]


def say(message: str, prefix: str = "fmu_build: ") -> None:
    """Print ``fmu_build: <message>`` on stderr at once (a log shows it while the step runs)."""
    _progress.say(message, prefix)


def heartbeat(what: str, every: float = HEARTBEAT_S, prefix: str = "fmu_build: "):
    """:func:`flexarm.progress.heartbeat` with lines ``<prefix><what>: still at it, 15 s`` on stderr."""
    return _progress.heartbeat(what, every, functools.partial(say, prefix=prefix))
