"""The FMI 2.0 callback structure an instance is given, with its log routed to a Python function.

Below both the master (:mod:`scenarios.master.cosim`) and the process an FMU may run in
(:mod:`scenarios.master.fmu_proxy`), which each instantiate FMUs with it.
"""

from __future__ import annotations

from fmpy.fmi1 import calloc, free
from fmpy.fmi2 import (
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)


def logging_callbacks(logger) -> fmi2CallbackFunctions:
    """FMI 2.0 callbacks routing the FMU's log to `logger(component, instance, status, category, message)`.

    Keep the returned object referenced as long as the instance lives (ctypes).
    """
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(logger)
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    return cb
