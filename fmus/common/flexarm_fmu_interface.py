"""Interface declaration of this project's FMUs: variables, units, choices, model-description completion.

A slave module declares its FMI interface as a table of :class:`Var` rows
(:func:`variable_table`); :func:`complete_model_description` writes what
pythonfmu 0.7.0 leaves out of modelDescription.xml (units, ranges, structure).
The defaults every FMU shares come from the committed trajectory
(:func:`slew`, :func:`slew_experiment`). No pythonfmu run-time code here:
the runtime is :mod:`flexarm_fmu_base`, the pythonfmu work-arounds
:mod:`flexarm_fmu_pythonfmu`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.etree.ElementTree import Element, SubElement

from flexarm_fmu_preflight import BUNDLE_MANIFEST

__all__ = ["CHOICES_MARK", "TYPES", "UNITS", "Var", "blank_value", "check_value", "complete_model_description",
           "own_data_dir", "slew", "slew_experiment", "variable_table"]

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
_CAUSALITIES = ("parameter", "calculatedParameter", "input", "output", "local", "independent")
_VARIABILITIES = ("constant", "fixed", "tunable", "discrete", "continuous")
#: FMI 2.0 types a variable may have.
TYPES = ("Real", "Integer", "Boolean", "String")
#: How a choice parameter lists its choices in its description (docs/fmu-interface.md, "Choice parameters").
CHOICES_MARK = "choices: "


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
    initial_depends_on : tuple of str, optional
        Outputs only: the inputs an output depends on at initialisation (its ``<InitialUnknowns>``
        dependencies, with every parameter). None (default): `depends_on` when it names inputs, else no
        attribute ("may depend on every known"). A master that solves initialisation as one system
        (OMSimulator) sees an algebraic loop through every output left without a list.
    choices : tuple of (int, str, str)
        Integer parameters that select one of several named choices: (value,
        name, description) of each. The allowed values are exactly these;
        the description gets ``"; choices: 1 = name1, 2 = name2"`` appended
        (masters read it back, e.g. ``scenarios.master.values.parse_choices``). A choice is an Integer, not an
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
    initial_depends_on: tuple[str, ...] | None = None

    def __post_init__(self):
        if self.causality not in _CAUSALITIES:
            raise ValueError(f"{self.name}: causality must be one of {sorted(_CAUSALITIES)}, got {self.causality!r}")
        if self.variability not in _VARIABILITIES:
            raise ValueError(f"{self.name}: variability must be one of {sorted(_VARIABILITIES)}, "
                             f"got {self.variability!r}")
        if self.type not in TYPES:
            raise ValueError(f"{self.name}: type must be one of {sorted(TYPES)}, got {self.type!r}")
        needs_start = self.causality in ("parameter", "input") or self.variability == "constant"
        if needs_start and self.start is None:
            raise ValueError(f"{self.name}: a {self.causality} needs a start value")
        if self.causality == "output" and self.start is not None:
            raise ValueError(f"{self.name}: outputs are calculated and take no start value")
        if (self.depends_on is not None or self.initial_depends_on is not None) and self.causality != "output":
            raise ValueError(f"{self.name}: depends_on and initial_depends_on apply to outputs only")
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


def own_data_dir(resources) -> str | None:
    """An FMU's own data folder (as text), or None outside a built FMU.

    Inside a built FMU that is ``resources/<package>/data``, where ``<package>`` is the private name
    of its bundled ``flexarm`` (``flexarm_bundle.json``, see fmu_build/isolate.py), the same folder
    as ``flexarm.parameters.DATA_DIR`` of the FMU's own copy.
    """
    if not resources:
        return None
    manifest = Path(resources) / BUNDLE_MANIFEST
    try:
        package = json.loads(manifest.read_text()).get("package", "flexarm") if manifest.is_file() else "flexarm"
    except (OSError, ValueError):
        package = "flexarm"
    folder = Path(resources) / package / "data"
    return str(folder) if folder.is_dir() else None


def slew() -> dict[str, float]:
    """Facts of the committed trajectory (``flexarm/data/trajectory.npz``) every FMU's defaults come from.

    Returns ``duration`` (s, the slew's length, last sample time), ``dt`` (s,
    its sample time) and ``q1_0``, ``q2_0`` (rad, the joint angles of its first
    sample). Read from the data file when the FMU is built; inside a built FMU,
    from the ``slew`` entry the build wrote into ``flexarm_bundle.json`` (so an
    FMU that does not track the trajectory need not carry it).
    """
    manifest = Path(__file__).resolve().parent / BUNDLE_MANIFEST
    if manifest.is_file():
        recorded = json.loads(manifest.read_text()).get("slew")
        if recorded:
            return dict(recorded)
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


def complete_model_description(root: Element, variables: list[Var], units: dict[str, dict]) -> None:
    """Add what pythonfmu 0.7.0 leaves out of modelDescription.xml (in place).

    * ``unit``, ``min``, ``max`` on each ``<Real>``; ``min``/``max`` on ``<Integer>``;
    * ``<UnitDefinitions>`` for every unit used;
    * ``<ModelStructure>``: ``<Outputs>`` with the declared dependencies and
      ``<InitialUnknowns>`` (every output, whose ``initial`` defaults to
      "calculated" in co-simulation, and every calculated parameter). An
      output depends at initialisation on the inputs of its
      ``initial_depends_on`` (else of a non-empty ``depends_on``) and the
      parameters; the others declare no list, i.e. every known.

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
        knowns = [v.name for v in variables if v.causality == "parameter"]
        for v in initial:  # table order = value-reference order, as FMI 2.0 requires
            attrib = {"index": str(index[v.name])}
            deps = v.initial_depends_on if v.initial_depends_on is not None else (v.depends_on or None)
            if v.causality == "output" and deps is not None:  # its inputs and the parameters (sorted indices)
                for dep in deps:
                    if dep not in index:
                        raise ValueError(f"{v.name}: initial_depends_on names unknown variable {dep!r}")
                attrib["dependencies"] = " ".join(str(i) for i in sorted(index[d] for d in {*deps, *knowns}))
            SubElement(node, "Unknown", attrib)


def blank_value(typ: str):
    return {"Real": math.nan, "Integer": 0, "Boolean": False, "String": ""}[typ]


def check_value(var: Var, value) -> str | None:
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

