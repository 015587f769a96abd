"""Work-arounds for pythonfmu 0.7.0 (pinned exactly in pyproject.toml; fmu_build checks it before building).

* :func:`pin_module_namespace`: pythonfmu drops a reference to a slave
  module's namespace at every instantiation;
* :class:`PythonfmuSlave`: messages logged while the slave is constructed are
  held until the next FMI call (logged inside the constructor, they made a
  later ``fmi2FreeInstance`` crash the host); one copy of the resources folder
  in ``sys.path`` (pythonfmu adds it at every instantiation); a state from
  ``fmi2DeSerializeFMUstate`` that does not parse becomes an invalid state
  instead of an exception (which pythonfmu turns into ``fmi2Fatal``).

Everything that relies on pythonfmu's internals is here; the C front end
(``fmi2_shim*.c``) handles what cannot be fixed from Python.
"""

from __future__ import annotations

import ctypes
import json
import sys

from pythonfmu import Fmi2Slave
from pythonfmu.enums import Fmi2Status

__all__ = ["PythonfmuSlave", "pin_module_namespace"]


class PythonfmuSlave(Fmi2Slave):
    """pythonfmu's slave with the work-arounds above (base of :class:`flexarm_fmu_base.FlexarmSlave`)."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._drop_repeated_resources_path()

    def _constructed(self) -> None:
        """Called at the end of the subclass's constructor. Messages logged while pythonfmu constructs the
        slave stay in pythonfmu's queue; the C front end delivers them within fmi2Instantiate/fmi2Reset
        (pythonfmu 0.7.0 would otherwise deliver them in fmi2FreeInstance through its deleted logger)."""

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> dict:
        # pythonfmu turns an exception here into fmi2Fatal; the shim only passes bytes it
        # serialized (header and checksum), so this is a second line of defence.
        try:
            out = json.loads(state.decode("utf-8"))
            return out if isinstance(out, dict) else {"invalid": True}
        except Exception:
            return {"invalid": True}

    def _drop_repeated_resources_path(self) -> None:
        """Keep one copy of this FMU's resources folder in sys.path.

        pythonfmu 0.7.0 inserts it at the front at every fmi2Instantiate, so a
        long-running host (a sweep instantiating thousands of times) would
        otherwise search an ever longer sys.path on every import.
        """
        try:
            path = sys.path
            if self.resources and path.count(self.resources) > 1:
                first = path.index(self.resources)
                path[first + 1:] = [p for p in path[first + 1:] if p != self.resources]
        except Exception as exc:  # a tidy-up only: never fail instantiation for it
            self.log(f"{self.instance_name}: sys.path clean-up skipped: {exc}", Fmi2Status.warning)

    # -- vendored-module check ---------------------------------------------------------

def pin_module_namespace(namespace: dict) -> None:
    """Add one reference to a slave module's namespace; call as ``pin_module_namespace(globals())``.

    Work-around for pythonfmu 0.7.0: its ``findClass`` (``PySlaveInstance.cpp``)
    imports the slave module, *re-executes* the module's code with the
    module's ``__dict__`` as globals, and then calls ``Py_DECREF`` on that
    ``__dict__``, a borrowed reference from ``PyModule_GetDict``. Every
    ``fmi2Instantiate`` thus removes one reference from the namespace. It
    survives only while other references (functions defined in the module,
    leaked along with the re-executed classes) outnumber the instantiations:
    a slave module that defines no function, like the controller variants,
    loses its namespace at the first instantiation, and the second one fails
    (``module has no attribute ...``) or crashes the host.

    Called at module level, this runs at the import *and* at every
    re-execution, i.e. once before each of pythonfmu's decrements, so the
    namespace never drops below the reference the module itself holds. (A
    builder or test import adds a reference too; a namespace that lives as
    long as the process anyway is the only thing leaked.)
    """
    ctypes.pythonapi.Py_IncRef(ctypes.py_object(namespace))


