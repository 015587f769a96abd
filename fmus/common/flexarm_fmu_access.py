"""fmi2Get*/fmi2Set* of a FlexarmSlave's variables: type and causality checks, NaN and range rejection.

:class:`VariableAccess` is a mixin of :class:`flexarm_fmu_base.FlexarmSlave` (which holds the values, the
variable table and the instance's mode): a set call is all or nothing (one bad value applies none, each
rejection logged with the variable's allowed range), and a get in initialisation mode first brings the
outputs up to date. Also the lifecycle modes of an instance, which both modules read.
"""

from __future__ import annotations

import math

from flexarm_fmu_interface import Var, check_value

# Lifecycle of an instance (FMI 2.0 co-simulation state machine, simplified).
_INSTANTIATED, _INITIALIZATION, _STEPPING, _TERMINATED = "instantiated", "initialization", "stepping", "terminated"


class VariableAccess:
    """The getters and setters of :class:`flexarm_fmu_base.FlexarmSlave` (pythonfmu's get_*/set_* methods)."""

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
                    problem = check_value(var, value)
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
