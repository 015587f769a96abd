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
modules by name in ``sys.modules``. Each FMU's slave module therefore has a
unique name (``flexarm_plant_fmu``, ...), whereas the bundled ``flexarm``
package and this module keep their names: the first FMU loaded provides them
to all later ones (or the host's own ``flexarm``, if it imported one).
``build_fmus.py`` writes the SHA-256 of the bundled ``flexarm`` into
``resources/flexarm_bundle.json``; on instantiation the base class hashes
the ``flexarm`` actually imported, if it is not this FMU's copy, and logs a
warning if it differs (FMUs built from different versions of the physics in
one process).
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import math
import sys
import traceback
from abc import abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Fmi2Slave
from pythonfmu.enums import Fmi2Causality, Fmi2Status, Fmi2Variability
from pythonfmu.variables import Boolean, Integer, Real, String

__all__ = ["BUNDLE_MANIFEST", "CHOICES_MARK", "START_VALUES", "UNITS", "FlexarmSlave", "StepDiscarded", "Var",
           "bundle_files", "complete_model_description", "pin_module_namespace", "slew", "slew_experiment",
           "tree_sha256", "variable_table"]

#: File (in an FMU's resources) describing the bundled sources.
BUNDLE_MANIFEST = "flexarm_bundle.json"
#: Optional file (in an FMU's resources): {variable: start value} of a case's copy of the FMU.
START_VALUES = "flexarm_start_values.json"

#: Known units: name -> SI base-unit exponents (FMI 2.0 <BaseUnit> attributes)
#: and optional display units {name: factor}. Extend per FMU via ``EXTRA_UNITS``.
UNITS: dict[str, dict[str, Any]] = {
    "1": {"base": {}},
    "s": {"base": {"s": 1}},
    "Hz": {"base": {"s": -1}},
    "m": {"base": {"m": 1}},
    "m/s": {"base": {"m": 1, "s": -1}},
    "m/s2": {"base": {"m": 1, "s": -2}},
    "kg": {"base": {"kg": 1}},
    "rad": {"base": {"rad": 1}, "display": {"deg": 180.0 / math.pi}},
    "rad/s": {"base": {"rad": 1, "s": -1}, "display": {"deg/s": 180.0 / math.pi}},
    "rad/s2": {"base": {"rad": 1, "s": -2}, "display": {"deg/s2": 180.0 / math.pi}},
    "N.m": {"base": {"kg": 1, "m": 2, "s": -2}},
    "V": {"base": {"kg": 1, "m": 2, "s": -3, "A": -1}},
}

_CAUSALITIES = {c.name: c for c in Fmi2Causality}
_VARIABILITIES = {v.name: v for v in Fmi2Variability}
_TYPES = {"Real": Real, "Integer": Integer, "Boolean": Boolean, "String": String}
#: How a choice parameter lists its choices in its description (docs/fmu-interface.md, "Choice parameters").
CHOICES_MARK = "choices: "

#: SHA-256 of the imported `flexarm` folder, by path (see FlexarmSlave._check_vendored_modules).
_LOADED_TREE_SHA256: dict[Path, str] = {}

# Lifecycle of an instance (FMI 2.0 co-simulation state machine, simplified).
_INSTANTIATED, _INITIALIZATION, _STEPPING, _TERMINATED = "instantiated", "initialization", "stepping", "terminated"


class StepDiscarded(Exception):
    """Raised by :meth:`FlexarmSlave.step` when a step could not be completed but a smaller one may.

    ``fmi2DoStep`` then returns ``fmi2Discard`` (not ``fmi2Error``) with the
    message logged as a warning; the state stays at the start of the step.
    """


@dataclass(frozen=True)
class Var:
    """One scalar variable of an FMU interface.

    Parameters
    ----------
    name : str
        FMI name (structured naming convention: letters, digits, '_').
    causality : {'parameter', 'input', 'output', 'local', 'calculatedParameter'}
    variability : {'constant', 'fixed', 'tunable', 'discrete', 'continuous'}
    unit : str or None
        Unit name; must be a key of :data:`UNITS` (or the class's
        ``EXTRA_UNITS``). Ignored in the XML for non-Real types, which FMI
        2.0 does not give a unit.
    description : str
        One line, written into modelDescription.xml.
    start : float, int, bool, str or None
        Start value; required for parameters and inputs, must be None for
        calculated outputs.
    min, max : float, optional
        Allowed range (inclusive), checked at every set and written to the
        XML. Real values must always be finite.
    type : {'Real', 'Integer', 'Boolean', 'String'}
    depends_on : tuple of str, optional
        Outputs only: the inputs an output depends on *directly* at a
        communication point (its ``<Outputs>`` dependencies). ``()`` means
        no direct feedthrough; None (default) writes no attribute, i.e.
        "may depend on every input".
    choices : tuple of (int, str, str)
        Integer parameters that select one of several named choices: (value,
        name, description) of each. The allowed values are exactly these;
        the description gets ``"; choices: 1 = name1, 2 = name2"`` appended
        (masters read it back, e.g. ``scenarios.master.parse_choices``). A choice is an Integer, not an
        FMI Enumeration, because libcosim 0.11 ignores Enumeration variables.
    """

    name: str
    causality: str
    variability: str
    unit: str | None
    description: str
    start: float | int | bool | str | None = None
    min: float | None = None
    max: float | None = None
    type: str = "Real"
    depends_on: tuple[str, ...] | None = None
    choices: tuple[tuple[int, str, str], ...] = ()

    def __post_init__(self):
        if self.causality not in _CAUSALITIES:
            raise ValueError(f"{self.name}: causality must be one of {sorted(_CAUSALITIES)}, got {self.causality!r}")
        if self.variability not in _VARIABILITIES:
            raise ValueError(f"{self.name}: variability must be one of {sorted(_VARIABILITIES)}, "
                             f"got {self.variability!r}")
        if self.type not in _TYPES:
            raise ValueError(f"{self.name}: type must be one of {sorted(_TYPES)}, got {self.type!r}")
        needs_start = self.causality in ("parameter", "input") or self.variability == "constant"
        if needs_start and self.start is None:
            raise ValueError(f"{self.name}: a {self.causality} needs a start value")
        if self.causality == "output" and self.start is not None:
            raise ValueError(f"{self.name}: outputs are calculated and take no start value")
        if self.depends_on is not None and self.causality != "output":
            raise ValueError(f"{self.name}: depends_on applies to outputs only")
        if self.choices:
            if self.type != "Integer":
                raise ValueError(f"{self.name}: only an Integer can have choices")
            values = [v for v, _, _ in self.choices]
            if self.start not in values or (self.min, self.max) != (min(values), max(values)):
                raise ValueError(f"{self.name}: start and range must lie among the choices {self.choices_text}")
            if CHOICES_MARK in self.description or any("," in n or "=" in n or " " in n for _, n, _ in self.choices):
                raise ValueError(f"{self.name}: choice names must be free of ',', '=' and spaces")

    @property
    def choices_text(self) -> str:
        """Choices as text, e.g. '1 (gamma1), 2 (gamma0.1)'."""
        return ", ".join(f"{v} ({n})" for v, n, _ in self.choices)

    @property
    def full_description(self) -> str:
        """The description written into modelDescription.xml (with the choices, if any)."""
        if not self.choices:
            return self.description
        return f"{self.description}; {CHOICES_MARK}" + ", ".join(f"{v} = {n}" for v, n, _ in self.choices)

    @property
    def range_text(self) -> str:
        """Allowed range as text, e.g. '[0, 10] kg' or 'any finite value'."""
        if self.choices:
            return f"one of {self.choices_text}"
        if self.min is None and self.max is None:
            body = "any finite value" if self.type == "Real" else "any value"
        else:
            lo = "-inf" if self.min is None else f"{self.min:g}"
            hi = "inf" if self.max is None else f"{self.max:g}"
            body = f"[{lo}, {hi}]"
        return f"{body} {self.unit}" if self.unit and self.unit != "1" else body


def variable_table(rows) -> tuple[Var, ...]:
    """Build :class:`Var` objects from compact rows.

    Each row is either a :class:`Var` or a tuple
    ``(name, causality, variability, unit, description, start[, (min, max)])``;
    the type is inferred from ``start`` (bool -> Boolean, int -> Integer,
    str -> String, otherwise Real).
    """
    out = []
    for row in rows:
        if isinstance(row, Var):
            out.append(row)
            continue
        name, causality, variability, unit, description, start, *rest = row
        lo, hi = rest[0] if rest else (None, None)
        if isinstance(start, bool):
            typ = "Boolean"
        elif isinstance(start, int):
            typ = "Integer"
        elif isinstance(start, str):
            typ = "String"
        else:
            typ = "Real"
        out.append(Var(name, causality, variability, unit, description, start, lo, hi, typ))
    names = [v.name for v in out]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ValueError(f"variable names must be unique, repeated: {sorted(dup)}")
    return tuple(out)


class FlexarmSlave(Fmi2Slave):
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
        self._drop_repeated_resources_path()
        self._check_vendored_modules()
        self._apply_start_values()

    # -- variable table --------------------------------------------------------
    def _register(self, var: Var) -> None:
        vr = len(self._vars)
        self._vars.append(var)
        self._vr[var.name] = vr
        self._values.append(var.start if var.start is not None else _blank(var.type))
        values = self._values
        sv = _TYPES[var.type](
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

    # -- getters and setters -------------------------------------------------------
    def _get(self, vrs, allowed: frozenset, typename: str, blank):
        try:
            if not allowed.issuperset(vrs):
                bad = [vr for vr in vrs if vr not in allowed]
                self._error(f"get{typename}: value references {bad} are not {typename} variables")
                return [blank] * len(vrs)
            if self._mode == _INITIALIZATION and self._needs_init:
                self._ensure_initialized()  # outputs read in initialisation mode must be consistent
            values = self._values
            return [values[vr] for vr in vrs]
        except Exception as exc:
            self._exception(f"get{typename}", exc)
            return [blank] * len(vrs)

    def get_real(self, vrs):
        return self._get(vrs, self._real_vrs, "Real", math.nan)

    def get_integer(self, vrs):
        return self._get(vrs, self._int_vrs, "Integer", 0)

    def get_boolean(self, vrs):
        return self._get(vrs, self._bool_vrs, "Boolean", False)

    def get_string(self, vrs):
        return self._get(vrs, self._str_vrs, "String", "")

    def _set(self, vrs, values, allowed: frozenset, typename: str, convert):
        # All or nothing: a call with one bad value applies none (the shim returns fmi2Error for it).
        try:
            accepted, rejected = [], []
            for vr, raw in zip(vrs, values):
                if vr not in allowed:
                    rejected.append((None, f"set{typename}: value reference {vr} is not a {typename} variable"))
                    continue
                var = self._vars[vr]
                problem = self._settable(var)
                if problem is None:
                    value = convert(raw)
                    problem = _check_value(var, value)
                if problem is None:
                    accepted.append((vr, var, value))
                else:
                    rejected.append((var, f"{problem}; value rejected, {var.name} stays {self._values[vr]!r}"))
            if rejected:
                for var, msg in rejected:
                    # Inputs and not-yet-used parameters keep stepping refused until a valid value is set.
                    block = var is not None and (var.causality == "input" or (
                        var.causality == "parameter" and self._mode in (_INSTANTIATED, _INITIALIZATION)))
                    self._error(msg, f"value:{var.name}" if block else None)
                if accepted:
                    self._error(f"set{typename}: nothing set ({len(accepted)} valid value(s) in the same call "
                                "not applied either)")
                return
            for vr, var, value in accepted:
                self._values[vr] = value
                self._errors.pop(f"value:{var.name}", None)
                if var.causality == "parameter" and self._mode in (_INSTANTIATED, _INITIALIZATION):
                    self._needs_init = True
                elif var.causality == "input" and self._mode == _INITIALIZATION:
                    self._needs_init = True
        except Exception as exc:
            self._exception(f"set{typename}(vr={list(vrs)})", exc)

    def _settable(self, var: Var) -> str | None:
        if var.causality == "input":
            return None
        if var.causality == "parameter":
            if var.variability == "tunable" or self._mode in (_INSTANTIATED, _INITIALIZATION):
                return None
            return (f"{var.name}: a fixed parameter can only be set before exitInitializationMode, and the FMU "
                    f"is in {self._mode} mode (allowed range {var.range_text})")
        return f"{var.name}: a variable with causality '{var.causality}' cannot be set"

    def set_real(self, vrs, values):
        # Fast path for what a master does every step: finite, in-range Real inputs while stepping.
        # Anything else (or any doubt) takes the checked path of _set, which logs and rejects.
        if self._mode == _STEPPING and self._real_input_vrs.issuperset(vrs):
            try:
                checked = []
                bounds = self._real_bounds
                for vr, raw in zip(vrs, values):
                    value = float(raw)
                    lo, hi = bounds[vr]
                    if not lo <= value <= hi:  # False for NaN too
                        break
                    checked.append((vr, value))
                else:
                    store = self._values
                    for vr, value in checked:
                        store[vr] = value
                    if self._errors:
                        for vr, _ in checked:
                            self._errors.pop(f"value:{self._vars[vr].name}", None)
                    return
            except Exception:  # noqa: BLE001 - the checked path below reports it
                pass
        self._set(vrs, values, self._real_vrs, "Real", float)

    def set_integer(self, vrs, values):
        self._set(vrs, values, self._int_vrs, "Integer", int)

    def set_boolean(self, vrs, values):
        self._set(vrs, values, self._bool_vrs, "Boolean", bool)

    def set_string(self, vrs, values):
        self._set(vrs, values, self._str_vrs, "String", str)

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

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> dict:
        # pythonfmu turns an exception here into fmi2Fatal; the shim only passes bytes it
        # serialized (header and checksum), so this is a second line of defence.
        try:
            out = json.loads(state.decode("utf-8"))
            return out if isinstance(out, dict) else {"invalid": True}
        except Exception:
            return {"invalid": True}

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
                problem = f"{name}: no such variable" if vr is None else _check_value(self._vars[vr], value)
                if problem is not None:
                    self._error(f"{START_VALUES}: {problem}", f"value:{name}")
                else:
                    self._values[vr] = value
        except Exception as exc:
            self._exception(f"reading {START_VALUES}", exc, "start_values")

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
    def _check_vendored_modules(self) -> None:
        """Warn if the imported `flexarm` differs from the copy bundled in this FMU."""
        try:
            if not self.resources:
                return
            manifest = Path(self.resources) / BUNDLE_MANIFEST
            flexarm = sys.modules.get("flexarm")
            if flexarm is None or not manifest.is_file():
                return
            loaded = Path(flexarm.__file__).resolve().parent
            if loaded == (Path(self.resources) / "flexarm").resolve():
                return
            expected = json.loads(manifest.read_text())["flexarm_sha256"]
            if loaded not in _LOADED_TREE_SHA256:  # hashed once per process, not per instantiation
                _LOADED_TREE_SHA256[loaded] = tree_sha256(loaded)
            if _LOADED_TREE_SHA256[loaded] != expected:
                self.log(f"{self.instance_name}: using 'flexarm' already imported from {loaded}, which differs "
                         f"from the copy bundled in this FMU (sha256 {expected[:12]}); results follow the "
                         "imported copy", Fmi2Status.warning)
        except Exception as exc:  # a diagnostic only: never fail instantiation for it
            self.log(f"{self.instance_name}: bundled-module check skipped: {exc}", Fmi2Status.warning)

    # -- modelDescription.xml ------------------------------------------------------
    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        """pythonfmu's model description plus units, ranges and a complete ModelStructure."""
        root = super().to_xml(model_options or {})
        complete_model_description(root, self._vars, {**UNITS, **self.EXTRA_UNITS})
        return root


def slew() -> dict[str, float]:
    """Facts of the committed trajectory (``flexarm/data/trajectory.npz``) every FMU's defaults come from.

    Returns ``duration`` (s, the slew's length, last sample time), ``dt`` (s,
    its sample time) and ``q1_0``, ``q2_0`` (rad, the joint angles of its first
    sample). Read with NumPy alone (no optimiser code).
    """
    import numpy as np

    from flexarm.model import joint_angles
    from flexarm.parameters import DATA_DIR

    with np.load(DATA_DIR / "trajectory.npz", allow_pickle=False) as data:
        t = data["t"]
        theta0 = np.array([float(data[f"theta{i}"][0]) for i in range(1, 12)])
    q = joint_angles(theta0)
    return {"duration": float(t[-1] - t[0]), "dt": float(t[1] - t[0]), "q1_0": float(q[0]), "q2_0": float(q[1])}


def slew_experiment():
    """pythonfmu's DefaultExperiment of every FMU: from 0 over the whole slew, 1 ms steps."""
    from pythonfmu.default_experiment import DefaultExperiment

    return DefaultExperiment(start_time=0.0, stop_time=slew()["duration"], step_size=1e-3)


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


def complete_model_description(root: Element, variables: list[Var], units: dict[str, dict]) -> None:
    """Add what pythonfmu 0.7.0 leaves out of modelDescription.xml (in place).

    * ``unit``, ``min``, ``max`` on each ``<Real>``; ``min``/``max`` on ``<Integer>``;
    * ``<UnitDefinitions>`` for every unit used;
    * ``<ModelStructure>``: ``<Outputs>`` with the declared dependencies and
      ``<InitialUnknowns>`` (every output, whose ``initial`` defaults to
      "calculated" in co-simulation, and every calculated parameter).

    Parameters
    ----------
    root : Element
        ``<fmiModelDescription>``; its ``<ModelVariables>`` must list
        `variables` in order (value reference = index).
    variables : list of Var
    units : dict
        Unit table as :data:`UNITS`.
    """
    mv = root.find("ModelVariables")
    scalars = list(mv)
    if len(scalars) != len(variables):
        raise ValueError(f"ModelVariables has {len(scalars)} entries, the table {len(variables)}")
    used = []
    for sv, var in zip(scalars, variables):
        if sv.get("name") != var.name:
            raise ValueError(f"ModelVariables order differs from the table at {var.name!r}")
        typed = sv[0]
        if var.type == "Real" and var.unit is not None:
            if var.unit not in units:
                raise ValueError(f"{var.name}: unit {var.unit!r} is not defined; known units: {sorted(units)} "
                                 "(add it to EXTRA_UNITS)")
            typed.set("unit", var.unit)
            if var.unit not in used:
                used.append(var.unit)
        if var.type == "Real" and var.start is not None:
            typed.set("start", repr(float(var.start)))  # reads back as the same double (pythonfmu rounds)
        if var.type in ("Real", "Integer"):
            fmt = (lambda x: f"{float(x):.16g}") if var.type == "Real" else (lambda x: str(int(x)))
            if var.min is not None:
                typed.set("min", fmt(var.min))
            if var.max is not None:
                typed.set("max", fmt(var.max))

    # <UnitDefinitions> goes right after <CoSimulation> (schema order).
    for old in root.findall("UnitDefinitions"):
        root.remove(old)
    if used:
        unit_defs = Element("UnitDefinitions")
        for name in used:
            u = SubElement(unit_defs, "Unit", name=name)
            SubElement(u, "BaseUnit", {k: str(v) for k, v in units[name].get("base", {}).items()})
            for disp, factor in units[name].get("display", {}).items():
                SubElement(u, "DisplayUnit", name=disp, factor=f"{factor:.16g}")
        children = list(root)
        root.insert(children.index(root.find("CoSimulation")) + 1, unit_defs)

    structure = root.find("ModelStructure")
    for child in list(structure):
        structure.remove(child)
    index = {v.name: i + 1 for i, v in enumerate(variables)}
    outputs = [v for v in variables if v.causality == "output"]
    if outputs:
        node = SubElement(structure, "Outputs")
        for v in outputs:
            attrib = {"index": str(index[v.name])}
            if v.depends_on is not None:
                for dep in v.depends_on:
                    if dep not in index:
                        raise ValueError(f"{v.name}: depends_on names unknown variable {dep!r}")
                attrib["dependencies"] = " ".join(str(index[d]) for d in v.depends_on)
            SubElement(node, "Unknown", attrib)
    initial = [v for v in variables if v.causality in ("output", "calculatedParameter")]
    if initial:
        node = SubElement(structure, "InitialUnknowns")
        for v in initial:  # table order = value-reference order, as FMI 2.0 requires
            SubElement(node, "Unknown", index=str(index[v.name]))


def bundle_files(package_dir: Path) -> list[Path]:
    """Files of a package that go into an FMU: no caches, compiled files or hidden files."""
    out = []
    for p in sorted(Path(package_dir).rglob("*")):
        rel = p.relative_to(package_dir).parts
        if p.is_file() and "__pycache__" not in rel and not any(s.startswith(".") for s in rel) \
                and p.suffix not in (".pyc", ".pyo", ".tmp"):
            out.append(p)
    return out


def tree_sha256(package_dir: Path) -> str:
    """SHA-256 over :func:`bundle_files` (relative path and content): identifies a copy of a package."""
    h = hashlib.sha256()
    for f in bundle_files(package_dir):
        h.update(f.relative_to(package_dir).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def _blank(typ: str):
    return {"Real": math.nan, "Integer": 0, "Boolean": False, "String": ""}[typ]


def _check_value(var: Var, value) -> str | None:
    """None if `value` is allowed for `var`, else a message naming the variable and range."""
    if var.type == "Real" and not math.isfinite(value):
        where = "" if var.min is None and var.max is None else f" in {var.range_text}"
        unit = f" ({var.unit})" if not where and var.unit not in (None, "1") else ""
        return f"{var.name}: must be a finite number{where}{unit}, got {value!r}"
    if var.choices and value not in [v for v, _, _ in var.choices]:
        return f"{var.name}: {value!r} is not one of the allowed values {var.choices_text}"
    if var.type in ("Real", "Integer"):
        if (var.min is not None and value < var.min) or (var.max is not None and value > var.max):
            return f"{var.name}: {value!r} is outside the allowed range {var.range_text}"
    return None
