"""Parameter values checked against an FMU's model description: type, range, enumeration items.

Scenario and sweep files write values as TOML gives them (numbers, booleans, strings). Before anything
runs, each value is checked against the variable the FMU declares and converted to what the master sets:

======================  =========================================  ===============
FMU variable type       allowed in a file                          set as
======================  =========================================  ===============
Real                    a finite number, inside [min, max]         float
Integer                 an integer (not 1.7, not true), in range   int
Boolean                 true or false (not "false", not 0)         bool
String                  a string                                   str
Enumeration             one of the type's item names ("gamma0.1")  the item's int
Integer with choices    one of the names its description lists     the choice's int
======================  =========================================  ===============

Choice names come from the model description only: an Enumeration's items, or (as libcosim cannot set
an Enumeration, docs/fmu-interface.md "Choice parameters") an Integer whose description ends with
``choices: 1 = gamma1, 2 = gamma0.1``. Files write the names; an integer is refused, listing them.

An error names the field, the allowed values and what was given.
"""

from __future__ import annotations

import math

from scenarios.config import ScenarioError

#: Causalities a scenario or sweep may set.
SETTABLE = ("parameter",)


def is_int(v) -> bool:
    """An integer, not a boolean (TOML's true is no 1)."""
    return isinstance(v, int) and not isinstance(v, bool)


def is_number(v) -> bool:
    """A finite int or float, not a boolean."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def settable(md) -> dict:
    """Variable name -> fmpy ModelVariable of the variables a scenario may set (the parameters)."""
    return {v.name: v for v in md.modelVariables if v.causality in SETTABLE}


#: How an Integer choice parameter lists its options at the end of its description (docs/fmu-interface.md).
CHOICES_MARK = "choices: "


def parse_choices(description: str) -> dict[str, int]:
    """{name: value} of a choice parameter, from its description (``...; choices: 1 = a, 2 = b``); {} if none.

    The format is the one the FMU glue writes (``fmus/common/flexarm_fmu_interface.py``, docs/fmu-interface.md).
    """
    if CHOICES_MARK not in description:
        return {}
    items = {}
    for part in description.rsplit(CHOICES_MARK, 1)[1].split(", "):
        value, _, name = part.partition(" = ")
        items[name.strip()] = int(value)
    return items


def choice_items(variable) -> dict[str, int]:
    """Choice name -> integer of an Enumeration (its declared type's items) or of an Integer whose description
    ends with ``choices: 1 = name1, 2 = name2``; {} for any other variable."""
    declared = getattr(variable, "declaredType", None)
    if variable.type == "Enumeration" and declared is not None:
        return {item.name: int(item.value) for item in declared.items}
    return parse_choices(getattr(variable, "description", None) or "") if variable.type == "Integer" else {}


def check_value(where: str, variable, value, error: type[Exception] = ScenarioError):
    """`value` converted to what the master sets for `variable`, or `error` naming `where` and the allowed values.

    Parameters
    ----------
    where : str
        The field, e.g. ``"table2.toml: parameters.sensors.noise_enabled"``.
    variable : fmpy.model_description.ModelVariable
    value : bool, int, float or str
        As read from the file.
    """
    name, kind = variable.name, variable.type
    unit = f" {variable.unit}" if getattr(variable, "unit", None) else ""
    items = choice_items(variable)
    if items:
        declared = getattr(variable, "declaredType", None)
        what = f"Enumeration {getattr(declared, 'name', '')}".rstrip() if kind == "Enumeration" else "Integer choice"
        if not (isinstance(value, str) and value in items):
            raise error(f"{where}: one of {sorted(items, key=items.get)} ({name} is {what}), got {value!r}")
        return items[value]
    if kind == "Real":
        ok, allowed = is_number(value), f"a finite number ({name} is Real{unit})"
    elif kind == "Integer":
        ok, allowed = is_int(value), f"an integer ({name} is Integer)"
    elif kind == "Boolean":
        ok, allowed = isinstance(value, bool), f"true or false ({name} is Boolean)"
    elif kind == "String":
        ok, allowed = isinstance(value, str), f"a string ({name} is String)"
    else:
        raise error(f"{where}: {name} has type {kind}, which scenarios cannot set")
    if not ok:
        raise error(f"{where}: {allowed}, got {value!r}")
    if kind in ("Real", "Integer"):
        lo = None if variable.min in (None, "") else float(variable.min)
        hi = None if variable.max in (None, "") else float(variable.max)
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            bounds = f"[{'-inf' if lo is None else variable.min}, {'inf' if hi is None else variable.max}]"
            raise error(f"{where}: a value in the FMU's range {bounds}{unit}, got {value!r}")
        return float(value) if kind == "Real" else int(value)
    return value


def check_variable(where: str, md, instance: str, var: str, fmu_name: str = "",
                   error: type[Exception] = ScenarioError):
    """The settable ModelVariable `var` of `md`, or `error` listing the FMU's settable variables."""
    params = settable(md)
    if var not in params:
        fmu = f" of FMU {fmu_name}" if fmu_name else ""
        raise error(f"{where}: a parameter{fmu} ({sorted(params)}), got {var!r}")
    return params[var]


def check_parameters(where: str, descriptions: dict, parameters: dict[str, dict],
                     error: type[Exception] = ScenarioError) -> dict[str, dict]:
    """Every {instance: {variable: value}} checked and converted (see the module docstring).

    Parameters
    ----------
    where : str
        The file and table the values come from, e.g. ``"table2.toml: cases[noise].parameters"``.
    descriptions : dict
        Instance -> fmpy ModelDescription.
    parameters : dict
        As read from the file.
    """
    out: dict[str, dict] = {}
    for inst, values in parameters.items():
        if inst not in descriptions:
            raise error(f"{where}.{inst}: an FMU instance from {sorted(descriptions)}, got {inst!r}")
        md = descriptions[inst]
        for var, value in values.items():
            field = f"{where}.{inst}.{var}"
            variable = check_variable(field, md, inst, var, md.modelName, error)
            out.setdefault(inst, {})[var] = check_value(field, variable, value, error)
    return out
