"""Sweep files: read, validate and expand the axes (no FMU needed; see :mod:`.plan` for the FMU checks).

A sweep file (TOML; shipped ones in ``scenarios/sweeps/``) names a base scenario, one of its cases as the
base point, and the axes to vary; see :mod:`scenarios.sweep` for the format.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from flexarm.provenance import sha256_bytes
from scenarios.master.values import is_int as _is_int
from scenarios.master.values import is_number as _is_number

from ..config import MAX_SAMPLES, NAME_FORM, NAME_PATTERN, SCENARIO_DIR, Case, Scenario, ScenarioError, load_scenario

SWEEP_DIR = SCENARIO_DIR / "sweeps"
MAX_POINTS = 1_000_000
_TOP_KEYS = {"sweep", "axes"}
_SWEEP_KEYS = {"name", "description", "scenario", "case", "samples"}
_SPEC_FORMS = ("[v1, v2, ...]", "{ values = [...] }", "{ range = [first, last], step = 1 }",
               "{ uniform = [low, high], count = N, seed = S }")


class SweepError(ScenarioError):
    """A sweep file is missing a field or has one outside its allowed values."""


@dataclass
class Axis:
    """One axis of a sweep: a parameter (``instance.variable``) or an FMU swap (``fmus.instance``)."""

    field: str
    instance: str
    variable: str | None
    kind: str  # "values", "range", "uniform" or "fmu"
    values: list
    #: The FMU variable's unit (filled in by :func:`plan_sweep`).
    unit: str = ""

    @property
    def is_fmu(self) -> bool:
        return self.variable is None

    @property
    def is_replicate(self) -> bool:
        """A seed axis: its points are repetitions (the plots aggregate over it)."""
        return self.variable is not None and self.variable.endswith("seed")


@dataclass
class Sweep:
    """A loaded, validated sweep file."""

    name: str
    description: str
    path: Path
    #: SHA-256 of the file's bytes (provenance) and of its parsed content (comments and layout do not count).
    sha256: str
    scenario: Scenario
    case: Case
    axes: list[Axis]
    content_sha256: str = ""

    @property
    def n_points(self) -> int:
        return math.prod(len(a.values) for a in self.axes)


def _require(cond: bool, where: str, allowed: str, got) -> None:
    if not cond:
        raise SweepError(f"{where}: {allowed}, got {got!r}")


def _is_scalar(v) -> bool:
    return isinstance(v, (bool, int, float, str)) and not (isinstance(v, float) and not math.isfinite(v))


def _axis_values(where: str, spec) -> tuple[str, list]:
    """Expand one axis spec into (kind, values)."""
    forms = "one of " + ", ".join(_SPEC_FORMS)
    if isinstance(spec, list):
        spec = {"values": spec}
    _require(isinstance(spec, dict), where, forms, spec)
    kinds = [k for k in ("values", "range", "uniform") if k in spec]
    _require(len(kinds) == 1, where, forms + " (exactly one of values, range, uniform)", spec)
    kind = kinds[0]
    allowed = {"values": {"values"}, "range": {"range", "step"}, "uniform": {"uniform", "count", "seed"}}[kind]
    unknown = sorted(set(spec) - allowed)
    _require(not unknown, where, f"keys allowed with {kind}: {sorted(allowed)}", unknown)
    if kind == "values":
        values = spec["values"]
        _require(isinstance(values, list) and values, f"{where}", "a non-empty list of values", values)
        for v in values:
            _require(_is_scalar(v), where, "values that are numbers, booleans or strings", v)
        _require(len({json.dumps(v) for v in values}) == len(values), where, "unique values", values)
    elif kind == "range":
        r, step = spec["range"], spec.get("step", 1)
        _require(isinstance(r, list) and len(r) == 2 and all(_is_int(x) for x in r) and r[0] <= r[1],
                 f"{where}.range", "[first, last], integers with first <= last (both included)", r)
        _require(_is_int(step) and step >= 1, f"{where}.step", "an integer >= 1", step)
        values = list(range(r[0], r[1] + 1, step))
    else:
        u, count, seed = spec["uniform"], spec.get("count"), spec.get("seed")
        _require(isinstance(u, list) and len(u) == 2 and all(_is_number(x) for x in u) and u[0] < u[1],
                 f"{where}.uniform", "[low, high], finite numbers with low < high", u)
        _require(_is_int(count) and 1 <= count <= MAX_POINTS, f"{where}.count",
                 f"an integer in [1, {MAX_POINTS}] (how many samples)", count)
        _require(_is_int(seed) and 0 <= seed < 2**63, f"{where}.seed",
                 "an integer >= 0 (the samples' own seed, required for reproducibility)", seed)
        rng = np.random.Generator(np.random.PCG64(seed))
        values = [float(x) for x in rng.uniform(u[0], u[1], count)]
    return kind, values


def sweep_path(name_or_path: str | Path) -> Path:
    """The sweep file for a name in ``scenarios/sweeps/`` or a path."""
    p = Path(name_or_path)
    if not p.suffix:
        p = SWEEP_DIR / f"{p.name}.toml"
    if not p.is_file():
        known = ", ".join(sorted(x.stem for x in SWEEP_DIR.glob("*.toml")))
        raise SweepError(f"sweep '{name_or_path}': no such file (known sweeps: {known})")
    return p


def load_sweep(name_or_path: str | Path, allow_large: bool = False) -> Sweep:
    """Read and validate a sweep file (structure, base scenario and case, axis values).

    Parameters
    ----------
    name_or_path : str or Path
        A sweep name in ``scenarios/sweeps/`` or a path to a sweep file.
    allow_large : bool
        Accept more than :data:`MAX_SAMPLES` samples per point and :data:`MAX_POINTS` points
        (``python -m scenarios sweep --allow-large``; never from the file itself).

    Returns
    -------
    Sweep
        With the base scenario loaded (its ``samples`` replaced by the sweep's
        override, if any) and every axis expanded into its values.

    Raises
    ------
    SweepError
        Naming the field and its allowed values. Variable names, types and
        ranges are checked against the FMUs by :func:`plan_sweep`.
    """
    p = sweep_path(name_or_path)
    raw = p.read_bytes()
    try:
        doc = tomllib.loads(raw.decode())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SweepError(f"{p}: not valid TOML: {exc}") from exc
    except RecursionError:
        raise SweepError(f"{p}: not a sweep file: arrays or tables nested too deeply to read") from None
    unknown = sorted(set(doc) - _TOP_KEYS)
    _require(not unknown, p.name, f"top-level tables allowed: {sorted(_TOP_KEYS)}", unknown)
    sw = doc.get("sweep")
    _require(isinstance(sw, dict), f"{p.name}: [sweep]", "a table with name, scenario, [case], [samples]", sw)
    unknown = sorted(set(sw) - _SWEEP_KEYS)
    _require(not unknown, f"{p.name}: [sweep]", f"keys allowed: {sorted(_SWEEP_KEYS)}", unknown)
    name = sw.get("name")
    _require(isinstance(name, str) and NAME_PATTERN.fullmatch(name) is not None, f"{p.name}: sweep.name",
             f"{NAME_FORM}; it names the output folder", name)
    _require(isinstance(sw.get("description", ""), str), f"{p.name}: sweep.description", "a string",
             sw.get("description"))
    scen = sw.get("scenario")
    _require(isinstance(scen, str) and scen, f"{p.name}: sweep.scenario",
             "a scenario name in scenarios/ or a path to a scenario file (relative to the sweep file)", scen)
    if Path(scen).suffix and not Path(scen).is_absolute() and (p.parent / scen).is_file():
        scen = str(p.parent / scen)
    try:
        scenario = load_scenario(scen)
    except ScenarioError as exc:
        raise SweepError(f"{p.name}: sweep.scenario: {exc}") from exc
    keys = [c.key for c in scenario.cases]
    case_key = sw.get("case", keys[0])
    _require(case_key in keys, f"{p.name}: sweep.case", f"one of the scenario's cases {keys}", case_key)
    case = scenario.cases[keys.index(case_key)]
    if "samples" in sw:
        samples = sw["samples"]
        _require(samples == "trajectory" or (_is_int(samples) and 1 <= samples
                                              and (allow_large or samples <= MAX_SAMPLES)),
                 f"{p.name}: sweep.samples",
                 f"an integer in [1, {MAX_SAMPLES}] or \"trajectory\" (as long as the slew; every point's record is "
                 f"kept in memory, so a sweep stays under the cap of a scenario run; --allow-large goes past it)",
                 samples)
        scenario = replace(scenario, samples=samples)
    axes_doc = doc.get("axes")
    instances = sorted(scenario.fmus)
    _require(isinstance(axes_doc, dict) and axes_doc, f"{p.name}: [axes]",
             f"a table of at least one axis: INSTANCE.VARIABLE = ... (instances {instances}) or fmus.INSTANCE = [...]",
             axes_doc)
    flat: list[tuple[str, str, object]] = []
    for top, sub in axes_doc.items():
        if "." in top:  # a quoted key: "plant.payload_mass" = [...]
            inst, _, var = top.partition(".")
            flat.append((inst, var, sub))
            continue
        _require(top in scenario.fmus or top == "fmus", f"{p.name}: axes.{top}",
                 f"an FMU instance of the scenario {instances} or 'fmus' (FMU swaps)", top)
        _require(isinstance(sub, dict) and sub, f"{p.name}: axes.{top}",
                 f"a table of {top}.VARIABLE = values (write {top}.VARIABLE = [...])", sub)
        flat.extend((top, var, spec) for var, spec in sub.items())
    axes: list[Axis] = []
    for inst, var, spec in flat:
        where = f"{p.name}: axes.{inst}.{var}"
        if inst == "fmus":
            _require(var in scenario.fmus, where, f"an FMU instance of the scenario {instances}", var)
            kind, values = _axis_values(where, spec)
            _require(kind == "values" and all(isinstance(v, str) and v for v in values), where,
                     "a list of FMU names (built into the FMU folder) or paths to .fmu files", spec)
            values = [str((p.parent / v).resolve()) if v.endswith(".fmu") and not Path(v).is_absolute() else v
                      for v in values]
            axes.append(Axis(f"fmus.{var}", var, None, "fmu", values))
        else:
            _require(inst in scenario.fmus, f"{p.name}: axes.{inst}",
                     f"an FMU instance of the scenario {instances} or 'fmus' (FMU swaps)", inst)
            _require(bool(var) and "." not in var, where, "INSTANCE.VARIABLE with one dot", f"{inst}.{var}")
            kind, values = _axis_values(where, spec)
            axes.append(Axis(f"{inst}.{var}", inst, var, kind, values))
    fields = [a.field for a in axes]
    _require(len(set(fields)) == len(fields), f"{p.name}: [axes]", "each parameter at most once", fields)
    sweep = Sweep(name, sw.get("description", ""), p, sha256_bytes(raw), scenario, case, axes,
                  content_sha256(doc))
    _require(allow_large or sweep.n_points <= MAX_POINTS, f"{p.name}: [axes]",
             f"at most {MAX_POINTS} points in all (--allow-large goes past the cap)", sweep.n_points)
    return sweep


def content_sha256(doc) -> str:
    """SHA-256 of a parsed TOML document (canonical JSON): equal for files that differ only in comments or layout."""
    return sha256_bytes(json.dumps(doc, sort_keys=True, separators=(",", ":"), default=str).encode())


def toml_content_sha256(path: Path) -> str:
    """:func:`content_sha256` of the TOML file at `path`."""
    return content_sha256(tomllib.loads(Path(path).read_text()))
