"""Scenario files: load, validate, expand into cases.

A scenario file (TOML) names the FMUs, their parameters, the wiring, the run
length and its cases; see ``scenarios/table2.toml`` for a commented example.
Every error names the field and what it allows.
"""

from __future__ import annotations

import copy
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

SCENARIO_DIR = Path(__file__).resolve().parent
_TOP_KEYS = {"scenario", "fmus", "connections", "parameters", "cases", "record", "ilc"}  # ilc: scenarios/ilc.py
_SCENARIO_KEYS = {"name", "description", "paper_table", "step_size_s", "samples", "order", "trajectory", "algorithm",
                  "kind"}
#: Master stepping algorithms a scenario may ask for (scenarios/master.py).
ALGORITHMS = ("gauss-seidel", "jacobi")
#: Kinds of FMU a scenario may run (FMU names resolve in build/fmus or build/fmus-native; docs/native-fmus.md).
KINDS = ("python", "native")


class ScenarioError(ValueError):
    """A scenario file is missing a field or has one outside its allowed values."""


@dataclass
class Case:
    key: str
    label: str
    parameters: dict[str, dict]
    #: FMU instance -> built FMU name or .fmu path for this case (the scenario's, with the case's overrides).
    fmus: dict[str, str] = field(default_factory=dict)


@dataclass
class Scenario:
    name: str
    description: str
    path: Path
    fmus: dict[str, str]
    order: list[str]
    connections: list[tuple[str, str]] | None  # None: connect by name
    parameters: dict[str, dict]
    cases: list[Case]
    step_size: float = 1e-3
    samples: int | str = "trajectory"
    paper_table: str | None = None
    record: list[str] = field(default_factory=list)
    #: Master stepping: "gauss-seidel" (default) or "jacobi" (see scenarios/master.py).
    algorithm: str = "gauss-seidel"
    #: Which kind of FMU the names in [fmus] mean: "python" (default) or "native" (plain C).
    kind: str = "python"


def _require(cond: bool, where: str, allowed: str, got) -> None:
    if not cond:
        raise ScenarioError(f"{where}: {allowed}, got {got!r}")


def _merge(base: dict, override: dict) -> dict:
    out = copy.deepcopy(base)
    for fmu, params in override.items():
        out.setdefault(fmu, {}).update(params)
    return out


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file; `path` may be a name in ``scenarios/``."""
    p = Path(path)
    if not p.suffix:
        p = SCENARIO_DIR / f"{p.name}.toml"
    if not p.is_file():
        known = ", ".join(sorted(x.stem for x in SCENARIO_DIR.glob("*.toml") if x.stem != "paper_tables"))
        raise ScenarioError(f"scenario '{path}': no such file (known scenarios: {known})")
    try:
        doc = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{p}: not valid TOML: {exc}") from exc
    unknown = set(doc) - _TOP_KEYS
    _require(not unknown, f"{p.name}", f"top-level tables allowed: {sorted(_TOP_KEYS)}", sorted(unknown))
    sc = doc.get("scenario", {})
    unknown = set(sc) - _SCENARIO_KEYS
    _require(not unknown, f"{p.name}: [scenario]", f"keys allowed: {sorted(_SCENARIO_KEYS)}", sorted(unknown))
    _require(isinstance(sc.get("name"), str) and sc["name"], f"{p.name}: scenario.name", "a non-empty string",
             sc.get("name"))
    step = sc.get("step_size_s", 1e-3)
    _require(isinstance(step, (int, float)) and math.isfinite(step) and 1e-6 <= step <= 0.1,
             f"{p.name}: scenario.step_size_s", "a number of seconds in [1e-6, 0.1]", step)
    samples = sc.get("samples", "trajectory")
    _require(samples == "trajectory" or (isinstance(samples, int) and not isinstance(samples, bool)
                                         and 1 <= samples <= 10_000_000),
             f"{p.name}: scenario.samples", "an integer in [1, 10000000] or \"trajectory\" (as long as the slew)",
             samples)
    algorithm = sc.get("algorithm", "gauss-seidel")
    _require(algorithm in ALGORITHMS, f"{p.name}: scenario.algorithm", f"one of {list(ALGORITHMS)}", algorithm)
    kind = sc.get("kind", "python")
    _require(kind in KINDS, f"{p.name}: scenario.kind", f"one of {list(KINDS)} (which FMUs the names mean)", kind)
    fmus = doc.get("fmus", {})
    _require(isinstance(fmus, dict) and fmus and all(isinstance(v, str) for v in fmus.values()),
             f"{p.name}: [fmus]", "a table of instance = \"built FMU name or path to a .fmu\"", fmus)
    order = sc.get("order", list(fmus))
    _require(isinstance(order, list) and sorted(order) == sorted(fmus), f"{p.name}: scenario.order",
             f"a list of every FMU instance in [fmus] ({sorted(fmus)})", order)
    conn = doc.get("connections", {})
    connections = None
    if "explicit" in conn:
        connections = []
        for item in conn["explicit"]:
            _require(isinstance(item, list) and len(item) == 2 and all(isinstance(s, str) and s.count(".") == 1
                                                                        for s in item),
                     f"{p.name}: connections.explicit", "pairs [\"fmu.output\", \"fmu.input\"]", item)
            for s in item:
                _require(s.split(".")[0] in fmus, f"{p.name}: connections.explicit", f"FMU names from {sorted(fmus)}",
                         s)
            connections.append((item[0], item[1]))
    params = doc.get("parameters", {})
    for fmu in params:
        _require(fmu in fmus, f"{p.name}: [parameters.{fmu}]", f"an FMU instance from {sorted(fmus)}", fmu)
    cases = []
    raw_cases = doc.get("cases", [{"key": "default", "label": "default"}])
    _require(isinstance(raw_cases, list) and raw_cases, f"{p.name}: [[cases]]", "at least one case", raw_cases)
    for i, c in enumerate(raw_cases):
        _require(isinstance(c.get("key"), str) and c["key"].isidentifier(), f"{p.name}: cases[{i}].key",
                 "an identifier (letters, digits, _)", c.get("key"))
        unknown = set(c) - {"key", "label", "parameters", "fmus"}
        _require(not unknown, f"{p.name}: cases[{i}]", "keys allowed: ['fmus', 'key', 'label', 'parameters']",
                 sorted(unknown))
        over = c.get("parameters", {})
        for fmu in over:
            _require(fmu in fmus, f"{p.name}: cases[{i}].parameters.{fmu}", f"an FMU instance from {sorted(fmus)}",
                     fmu)
        swap = c.get("fmus", {})
        for inst, name in swap.items():
            _require(inst in fmus and isinstance(name, str) and name, f"{p.name}: cases[{i}].fmus.{inst}",
                     f"an FMU instance from {sorted(fmus)} = \"built FMU name or .fmu path\"", name)
        cases.append(Case(c["key"], c.get("label", c["key"]), _merge(params, over), {**fmus, **swap}))
    keys = [c.key for c in cases]
    _require(len(set(keys)) == len(keys), f"{p.name}: cases", "unique keys", keys)
    record = doc.get("record", {}).get("signals", [])
    return Scenario(name=sc["name"], description=sc.get("description", ""), path=p, fmus=fmus, order=order,
                    connections=connections, parameters=params, cases=cases, step_size=float(step),
                    samples=samples, paper_table=sc.get("paper_table"), record=record, algorithm=algorithm,
                    kind=kind)


def list_scenarios() -> list[Scenario]:
    """Every scenario file shipped in ``scenarios/``."""
    return [load_scenario(p) for p in sorted(SCENARIO_DIR.glob("*.toml")) if p.stem != "paper_tables"]
