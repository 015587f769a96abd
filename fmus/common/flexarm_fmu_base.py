"""Shared FMI 2.0 co-simulation glue for every FMU of this project (plant, sensors, controller).

An FMU of this project is a thin wrapper over :mod:`flexarm`: a subclass of
:class:`FlexarmSlave` declares its interface in a table of :class:`Var`
rows and implements :meth:`FlexarmSlave.initialize` and
:meth:`FlexarmSlave.step`; everything FMI-specific lives here.

What the base class does
------------------------
* registers the variables of ``VARIABLES`` (name, causality, variability,
  unit, description, start, allowed range) with pythonfmu and writes units,
  ranges, ``<UnitDefinitions>``, ``<ModelStructure>/<Outputs>`` dependencies
  and ``<InitialUnknowns>`` into modelDescription.xml (:meth:`to_xml`), so
  that ``fmpy.validation.validate_fmu`` reports no problems;
* never lets a Python exception reach the pythonfmu binary (see below);
* rejects NaN/inf and out-of-range values at ``fmi2Set*`` with a log
  message naming the variable and its allowed range;
* supports ``fmi2Get/Set/(De)SerializeFMUstate``: the snapshot holds every
  variable value plus the subclass's own state
  (:meth:`get_internal_state` / :meth:`set_internal_state`), as JSON.

Error statuses: the glue and the shim
-------------------------------------
pythonfmu 0.7.0 alone cannot return ``fmi2Error``: a ``do_step`` returning
``False`` gives ``fmi2Discard``, and *any* uncaught Python exception gives
``fmi2Fatal`` and releases the Python object (later calls, even
``fmi2FreeInstance``, touch freed memory). Each FMU therefore carries a small
C front end, ``fmus/common/fmi2_shim.c``, compiled by ``build_fmus.py`` into
``binaries/linux64/<modelIdentifier>.so``; pythonfmu's binary sits beside it
as ``libpythonfmu-export.so`` and receives every call through it. The shim
tracks the FMI 2.0 co-simulation state machine and refuses calls made in the
wrong state (``fmi2Error``, logged with the call and the state), checks the
arguments pythonfmu does not, and passes pythonfmu its own logger callback.
It also imports the slave module before pythonfmu does (pythonfmu crashes
the host when that import fails) and starts Python in a native host.
The channel from Python to the shim is the log itself: pythonfmu delivers
the messages a call logged before the call returns, and the shim returns
the worst of pythonfmu's status and the statuses logged during the call.

This class keeps its side of that contract:

* it never lets an exception reach pythonfmu (that would be ``fmi2Fatal``);
* every failure is logged with status ``fmi2Error`` (:meth:`_error`), naming
  the variable and its allowed range, so the call returns ``fmi2Error``;
* a failing call changes nothing: a rejected ``fmi2Set*`` applies none of
  its values; a refused or failed ``fmi2DoStep`` leaves the state at the
  start of the step; a failed initialisation stays in initialisation mode;
* a rejected input, or a parameter rejected before the end of
  initialisation, also keeps ``fmi2ExitInitializationMode`` and
  ``fmi2DoStep`` refused (``fmi2Error``, the reason logged again) until a
  valid value is set, so a master that ignores the first error cannot run
  on with a value it did not ask for;
* only a step the subclass rejects with :class:`StepDiscarded` (e.g. the
  integrator's state became non-finite: a smaller step may succeed) is
  logged as a warning and returns ``fmi2Discard``, FMI's "step not done".

fmpy raises ``FMICallException`` for any status worse than ``fmi2Warning``.
Messages with status warning or worse always reach the host's logger;
the others only if the host instantiates with ``loggingOn``.

Loading several FMUs in one interpreter
---------------------------------------
pythonfmu puts each FMU's ``resources`` folder at the front of ``sys.path``
and imports the module named in ``resources/slavemodule.txt``; Python caches
modules by name in ``sys.modules``. The build therefore gives every module an
FMU bundles (its ``flexarm``, this glue, the slave) a name private to that FMU
build (``fmu_build/isolate.py``: ``_flexarm_<fmu>_<digest>``, imports
rewritten), recorded in ``resources/flexarm_bundle.json``: any number of FMUs,
of any builds, in any load order, share one interpreter and each runs its own
code on its own data.
"""

from __future__ import annotations

import json
import math
import sys
import traceback
from abc import abstractmethod
from pathlib import Path
from typing import Any, ClassVar
from xml.etree.ElementTree import Element

from flexarm_fmu_access import _INITIALIZATION, _INSTANTIATED, _STEPPING, _TERMINATED, VariableAccess
from flexarm_fmu_interface import (
    CHOICES_MARK,
    UNITS,
    Var,
    blank_value,
    check_value,
    complete_model_description,
    own_data_dir,
    slew,
    slew_experiment,
    variable_table,
)
from flexarm_fmu_preflight import BUNDLE_MANIFEST, bundle_files, tree_sha256
from flexarm_fmu_pythonfmu import PythonfmuSlave, pin_module_namespace
from pythonfmu.enums import Fmi2Causality, Fmi2Status, Fmi2Variability
from pythonfmu.variables import Boolean, Integer, Real, String

__all__ = ["BUNDLE_MANIFEST", "CHOICES_MARK", "MAX_STEP_SIZE", "START_VALUES", "UNITS", "FlexarmSlave",
           "StepDiscarded", "Var", "bundle_files", "complete_model_description", "own_data_dir",
           "pin_module_namespace", "slew", "slew_experiment", "tree_sha256", "variable_table"]

#: Optional file (in an FMU's resources): {variable: start value} of a case's copy of the FMU.
START_VALUES = "flexarm_start_values.json"
#: The longest communication step any FMU of this project takes, s; a longer one is refused with fmi2Error naming
#: step_size. Why a bound: a step must return in bounded time (10 000 plant steps of 1 ms, well under a second
#: natively) so that a master keeps control of its run; 10 s is the longest run of any scenario (Table 3). The native
#: glue has the same bound (GLUE_MAX_STEP_SIZE in fmus/native/common/fmi2_glue.h; tests/test_fmu_robustness.py checks
#: that they agree and that both kinds refuse a longer step).
MAX_STEP_SIZE = 10.0



class StepDiscarded(Exception):
    """Raised by :meth:`FlexarmSlave.step` when a step could not be completed but a smaller one may.

    ``fmi2DoStep`` then returns ``fmi2Discard`` (not ``fmi2Error``) with the
    message logged as a warning; the state stays at the start of the step.
    """


#: pythonfmu's variable class of each FMI type.
_PYTHONFMU_TYPES = {"Real": Real, "Integer": Integer, "Boolean": Boolean, "String": String}
_CAUSALITIES = {c.name: c for c in Fmi2Causality}
_VARIABILITIES = {v.name: v for v in Fmi2Variability}


class FlexarmSlave(VariableAccess, PythonfmuSlave):
    """Base class of this project's FMUs (FMI 2.0 co-simulation via pythonfmu).

    Subclasses set ``VARIABLES`` (see :func:`variable_table`) and implement
    :meth:`initialize`, :meth:`step`, :meth:`get_internal_state` and
    :meth:`set_internal_state`. They read variables with :meth:`value` and
    publish outputs with :meth:`set_outputs` (all outputs, in table order)
    or :meth:`set_value`.

    Stepping convention: ``fmi2DoStep(t, h)`` advances from t to t + h with
    every input held at the value set before the call; afterwards the
    outputs describe the state at t + h. After ``fmi2ExitInitializationMode``
    the outputs describe the state at the start time.
    """

    #: Interface table; set by subclasses.
    VARIABLES: ClassVar[tuple[Var, ...]] = ()
    #: Additional units for this FMU: name -> {"base": {...}, "display": {...}}.
    EXTRA_UNITS: ClassVar[dict[str, dict[str, Any]]] = {}
    author = "flexarm-fmi"
    license = "MIT"
    version = "0.1.0"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._values: list = []
        self._vars: list[Var] = []
        self._vr: dict[str, int] = {}
        self._errors: dict[str, str] = {}  # pending problems that block do_step, by key
        self._mode = _INSTANTIATED
        self._needs_init = True
        self.start_time = 0.0
        self.time = 0.0
        for var in self.VARIABLES:
            self._register(var)
        self._real_vrs = frozenset(i for i, v in enumerate(self._vars) if v.type == "Real")
        # For the stepping fast path of set_real: Real inputs and their closed bounds (finite, so NaN/inf fail).
        self._real_input_vrs = frozenset(i for i, v in enumerate(self._vars)
                                         if v.type == "Real" and v.causality == "input")
        self._real_bounds = {i: (-sys.float_info.max if v.min is None else v.min,
                                 sys.float_info.max if v.max is None else v.max)
                             for i, v in enumerate(self._vars) if i in self._real_input_vrs}
        self._int_vrs = frozenset(i for i, v in enumerate(self._vars) if v.type == "Integer")
        self._bool_vrs = frozenset(i for i, v in enumerate(self._vars) if v.type == "Boolean")
        self._str_vrs = frozenset(i for i, v in enumerate(self._vars) if v.type == "String")
        self._output_vrs = [i for i, v in enumerate(self._vars) if v.causality == "output"]
        contiguous = self._output_vrs == list(range(self._output_vrs[0], self._output_vrs[-1] + 1)) \
            if self._output_vrs else False
        self._output_slice = slice(self._output_vrs[0], self._output_vrs[-1] + 1) if contiguous else None
        self._apply_start_values()
        self._constructed()

    # -- variable table --------------------------------------------------------
    def _register(self, var: Var) -> None:
        vr = len(self._vars)
        self._vars.append(var)
        self._vr[var.name] = vr
        self._values.append(var.start if var.start is not None else blank_value(var.type))
        values = self._values
        sv = _PYTHONFMU_TYPES[var.type](
            var.name, start=var.start, causality=_CAUSALITIES[var.causality],
            variability=_VARIABILITIES[var.variability], description=var.full_description,
            getter=lambda: values[vr], setter=lambda v: values.__setitem__(vr, v),
        )
        self.register_variable(sv, nested=False)
        if sv.value_reference != vr:  # our list index must equal pythonfmu's value reference
            raise RuntimeError(f"{var.name}: value reference {sv.value_reference} != {vr}; "
                               "register every variable through VARIABLES only")

    def value(self, name: str):
        """Current value of variable `name` (in its declared unit)."""
        return self._values[self._vr[name]]

    def set_value(self, name: str, value) -> None:
        """Set variable `name` from inside the FMU (no checks; for outputs and locals)."""
        self._values[self._vr[name]] = value

    def set_outputs(self, values) -> None:
        """Publish all outputs at once, in the order of ``VARIABLES`` (floats).

        Raises ValueError if the count differs from the number of outputs.
        """
        tolist = getattr(values, "tolist", None)  # NumPy arrays: one C call instead of a float() per element
        values = tolist() if tolist is not None else [float(v) for v in values]
        if len(values) != len(self._output_vrs):
            raise ValueError(f"set_outputs: expected {len(self._output_vrs)} values, got {len(values)}")
        if self._output_slice is not None:
            self._values[self._output_slice] = values
        else:
            for vr, v in zip(self._output_vrs, values):
                self._values[vr] = v

    @property
    def output_names(self) -> list[str]:
        """Output names in table (and :meth:`set_outputs`) order."""
        return [self._vars[vr].name for vr in self._output_vrs]

    # -- hooks for subclasses ------------------------------------------------------
    @abstractmethod
    def initialize(self) -> None:
        """Build the model from the parameters and publish the outputs at the start time.

        Called at the end of initialisation (and earlier if the master reads
        outputs in initialisation mode). Raise to signal a problem.
        """

    @abstractmethod
    def step(self, t: float, h: float) -> None:
        """Advance from t to t + h (s) with the inputs held; publish the outputs at t + h.

        Must leave the internal state unchanged if it raises.
        """

    def get_internal_state(self) -> dict:
        """JSON-serialisable snapshot of the subclass's state (beyond variable values)."""
        return {}

    def set_internal_state(self, state: dict) -> None:
        """Restore a snapshot made by :meth:`get_internal_state`."""

    # -- error reporting -------------------------------------------------------
    def _error(self, msg: str, key: str | None = None) -> None:
        """Log `msg` at fmi2Error; if `key` is given, block do_step until the key is cleared."""
        self.log(f"{self.instance_name}: {msg}", Fmi2Status.error)
        if key is not None:
            self._errors[key] = msg

    def _exception(self, where: str, exc: BaseException, key: str | None = None) -> None:
        tb = traceback.extract_tb(exc.__traceback__)
        origin = f" (at {Path(tb[-1].filename).name}:{tb[-1].lineno})" if tb else ""
        self._error(f"{where} failed: {type(exc).__name__}: {exc}{origin}", key)

    # -- FMI entry points: none of them may raise ---------------------------------
    def setup_experiment(self, start_time: float, *args):
        try:
            if not math.isfinite(start_time):
                self._error(f"setupExperiment: start time must be finite, got {start_time!r}", "start_time")
                return
            self.start_time = float(start_time)
            self.time = self.start_time
        except Exception as exc:
            self._exception("setupExperiment", exc, "setup")

    def enter_initialization_mode(self, *args):
        try:
            self._mode = _INITIALIZATION
            self._needs_init = True
        except Exception as exc:
            self._exception("enterInitializationMode", exc, "initialization")

    def exit_initialization_mode(self):
        try:
            self._ensure_initialized()
            if self._errors:  # stay in initialisation mode: the master may set a valid value and retry
                for msg in self._errors.values():
                    self._error(f"exitInitializationMode refused: {msg}")
                return
            self._mode = _STEPPING
        except Exception as exc:
            self._exception("exitInitializationMode", exc, "initialization")

    def _ensure_initialized(self) -> None:
        if not self._needs_init:
            return
        self._needs_init = False
        self.time = self.start_time
        try:
            self.initialize()
            self._errors.pop("initialization", None)
        except Exception as exc:
            self._exception("initialisation", exc, "initialization")

    def do_step(self, current_time: float, step_size: float) -> bool:
        try:
            if self._mode != _STEPPING:
                self._error(f"doStep called in mode '{self._mode}'; call exitInitializationMode first")
                return False
            if self._errors:
                for msg in self._errors.values():
                    self._error(f"doStep refused: {msg}")
                return False
            if not (math.isfinite(step_size) and step_size > 0.0):
                self._error(f"step_size: must be a finite communication step > 0 s, got {step_size!r}")
                return False
            if step_size > MAX_STEP_SIZE:
                self._error(f"step_size: {step_size!r} s is longer than the longest communication step these FMUs "
                            f"take, {MAX_STEP_SIZE:g} s (allowed: 0 < step_size <= {MAX_STEP_SIZE:g} s; split it)")
                return False
            if not math.isfinite(current_time):
                self._error(f"current_time: must be finite, got {current_time!r}")
                return False
            if abs(current_time - self.time) > 1e-9 * max(1.0, abs(current_time)):
                # The models are time-invariant: a jump in time is legal (e.g. after
                # fmi2SetFMUstate elsewhere) but usually a master bug, so say so.
                self.log(f"{self.instance_name}: doStep at t = {current_time!r} s but the FMU is at "
                         f"t = {self.time!r} s", Fmi2Status.warning)
            try:
                self.step(float(current_time), float(step_size))
            except StepDiscarded as exc:
                self.log(f"{self.instance_name}: doStep(t={current_time!r}, h={step_size!r}) discarded: {exc}; "
                         f"the FMU stays at t = {self.time!r} s (a smaller step may succeed)", Fmi2Status.warning)
                return False
            self.time = current_time + step_size
            return True
        except Exception as exc:
            self._exception(f"doStep(t={current_time!r}, h={step_size!r})", exc)
            return False

    def terminate(self):
        try:
            self._mode = _TERMINATED
        except Exception as exc:
            self._exception("terminate", exc)

    # -- FMU state -----------------------------------------------------------------
    def _get_fmu_state(self) -> dict:
        # A fresh, JSON-serialisable dict: pythonfmu keeps the object as the
        # fmi2FMUstate and json-encodes it for fmi2SerializeFMUstate.
        try:
            return {
                "model": self.modelName,
                "values": list(self._values),
                "errors": dict(self._errors),
                "mode": self._mode,
                "needs_init": self._needs_init,
                "start_time": self.start_time,
                "time": self.time,
                "internal": self.get_internal_state(),
            }
        except Exception as exc:
            self._exception("getFMUstate", exc)
            return {"invalid": True}

    def _set_fmu_state(self, state: dict):
        try:
            if state.get("invalid") or state.get("model") != self.modelName:
                self._error(f"setFMUstate: not a valid state of {self.modelName}")
                return
            values = list(state["values"])
            if len(values) != len(self._values):
                self._error(f"setFMUstate: state has {len(values)} variables, this FMU {len(self._values)}")
                return
            self._values[:] = values
            self._errors = dict(state["errors"])
            self._mode = state["mode"]
            self._needs_init = bool(state["needs_init"])
            self.start_time = float(state["start_time"])
            self.time = float(state["time"])
            self.set_internal_state(state["internal"])
        except Exception as exc:
            self._exception("setFMUstate", exc, "state")

    def _apply_start_values(self) -> None:
        """Start values of a case's copy of this FMU (:data:`START_VALUES`, written by the SSP export).

        The export also writes them as the ``start`` attributes of modelDescription.xml, so the copy
        runs its case in any master, with nothing set. A value that does not fit its variable is an
        error that keeps initialisation refused.
        """
        try:
            path = Path(self.resources) / START_VALUES if self.resources else None
            if path is None or not path.is_file():
                return
            for name, value in json.loads(path.read_text()).items():
                vr = self._vr.get(name)
                if vr is not None and self._vars[vr].type in ("Real", "Integer") \
                        and not isinstance(value, bool) and isinstance(value, int | float):
                    value = float(value) if self._vars[vr].type == "Real" else value
                problem = f"{name}: no such variable" if vr is None else check_value(self._vars[vr], value)
                if problem is not None:
                    self._error(f"{START_VALUES}: {problem}", f"value:{name}")
                else:
                    self._values[vr] = value
        except Exception as exc:
            self._exception(f"reading {START_VALUES}", exc, "start_values")

    # -- modelDescription.xml ------------------------------------------------------
    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        """pythonfmu's model description plus units, ranges and a complete ModelStructure."""
        root = super().to_xml(model_options or {})
        complete_model_description(root, self._vars, {**UNITS, **self.EXTRA_UNITS})
        return root


