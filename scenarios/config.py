"""Scenario files: load, validate, expand into cases.

A scenario file (TOML) names the FMUs, their parameters, the wiring, the run
length and its cases; see ``scenarios/table2.toml`` for a commented example.
Every error names the field and what it allows.
"""

from __future__ import annotations

import copy
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

SCENARIO_DIR = Path(__file__).resolve().parent
_TOP_KEYS = {"scenario", "fmus", "connections", "parameters", "cases", "record", "ilc"}  # ilc: scenarios/ilc/
_SCENARIO_KEYS = {"name", "description", "paper_table", "step_size_s", "samples", "order", "trajectory", "algorithm",
                  "kind"}
#: Master stepping algorithms a scenario may ask for (scenarios/master/cosim.py).
ALGORITHMS = ("gauss-seidel", "jacobi")
#: Kinds of FMU a scenario may run (FMU names resolve in build/fmus or build/fmus-native; docs/native-fmus.md).
KINDS = ("python", "native")


class ScenarioError(ValueError):
    """A scenario file is missing a field or has one outside its allowed values."""


#: A scenario, case or sweep name: it becomes a file or folder name under --out, so a plain identifier.
NAME_PATTERN = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}")
NAME_FORM = "a plain identifier: an ASCII letter, then letters, digits or _ (at most 64 characters)"
#: Folder names the results tree uses for itself (``--out``'s default sweep folder is ``results/sweeps``).
RESERVED_NAMES = ("sweeps",)
#: Caps a run may pass only with --allow-large: communication steps per case and cases per scenario (a 1 ms
#: run of 200000 steps records about 40 signals, 64 MB per case, and keeps every case in memory for the plots).
MAX_SAMPLES = 200_000
MAX_CASES = 1_000


def check_name(value, where: str, reserved: tuple[str, ...] = ()) -> str:
    """``value`` if it is a plain identifier (:data:`NAME_PATTERN`) and not in `reserved`; else ScenarioError
    naming `where` and the allowed form (a name becomes a file or folder under the results folder)."""
    if not isinstance(value, str) or NAME_PATTERN.fullmatch(value) is None:
        raise ScenarioError(f"{where}: {NAME_FORM}, got {value!r} (a name becomes a file or folder name under "
                            f"the results folder)")
    if value.lower() in reserved:
        raise ScenarioError(f"{where}: {value!r} is a folder the results tree uses itself ({', '.join(reserved)}); "
                            f"choose another name")
    return value


def check_size(scenario: Scenario, n_steps: int | None = None) -> None:
    """Refuse more than :data:`MAX_CASES` cases or :data:`MAX_SAMPLES` steps per case unless the scenario
    allows it (``scenario.allow_large``, from ``python -m scenarios run --allow-large``)."""
    if scenario.allow_large:
        return
    if n_steps is None and isinstance(scenario.samples, int):
        n_steps = scenario.samples  # known from the file; "trajectory" is checked once the trajectory is read
    name = scenario.path.name
    if len(scenario.cases) > MAX_CASES:
        raise ScenarioError(f"{name}: [[cases]]: {len(scenario.cases)} cases, more than the {MAX_CASES} a run takes "
                            f"without --allow-large (every case is kept in memory); split the scenario, or pass "
                            f"--allow-large to run them all")
    if n_steps is not None and n_steps > MAX_SAMPLES:
        raise ScenarioError(f"{name}: scenario.samples / step_size_s: {n_steps} communication steps per case, more "
                            f"than the {MAX_SAMPLES} a run takes without --allow-large (about "
                            f"{n_steps * 40 * 8 / 1e9:.1f} GB recorded per case); shorten the run, or pass "
                            f"--allow-large to go past the cap")


def _check_strings(doc, where: str) -> None:
    """Refuse NUL and other control characters in any string of the file (keys and values; iteratively)."""
    stack = [(doc, where)]
    while stack:
        node, at = stack.pop()
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for k, v in items:
            here = f"{at}.{k}" if isinstance(node, dict) else f"{at}[{k}]"
            for text in (k, v):
                if isinstance(text, str) and any(ord(ch) < 32 and ch not in "\t\n\r" for ch in text):
                    raise ScenarioError(f"{here}: contains a control character (NUL or similar), got {text!r}; "
                                        f"names and values must be printable text")
            if isinstance(v, (dict, list)):
                stack.append((v, here))


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
    #: Master stepping: "gauss-seidel" (default) or "jacobi" (see scenarios/master/cosim.py).
    algorithm: str = "gauss-seidel"
    #: Which kind of FMU the names in [fmus] mean: "python" (default) or "native" (plain C).
    kind: str = "python"
    #: Past :data:`MAX_SAMPLES` and :data:`MAX_CASES` (``--allow-large``; never from the file itself).
    allow_large: bool = False


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
        doc = tomllib.loads(p.read_bytes().decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{p}: not valid TOML: {exc}") from exc
    except RecursionError:
        raise ScenarioError(f"{p}: not a scenario file: arrays or tables nested too deeply to read") from None
    except OSError as exc:
        raise ScenarioError(f"{p}: cannot be read: {exc.strerror or exc}") from exc
    _check_strings(doc, p.name)
    unknown = set(doc) - _TOP_KEYS
    _require(not unknown, f"{p.name}", f"top-level tables allowed: {sorted(_TOP_KEYS)}", sorted(unknown))
    for key in ("scenario", "fmus", "connections", "parameters", "record"):
        _require(isinstance(doc.get(key, {}), dict), f"{p.name}: [{key}]", "a table", doc.get(key))
    for fmu, table in doc.get("parameters", {}).items():
        _require(isinstance(table, dict), f"{p.name}: [parameters.{fmu}]", "a table of name = value", table)
    sc = doc.get("scenario", {})
    unknown = set(sc) - _SCENARIO_KEYS
    _require(not unknown, f"{p.name}: [scenario]", f"keys allowed: {sorted(_SCENARIO_KEYS)}", sorted(unknown))
    check_name(sc.get("name"), f"{p.name}: scenario.name", RESERVED_NAMES)
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
        _require(isinstance(conn["explicit"], list), f"{p.name}: connections.explicit",
                 "a list of pairs [\"fmu.output\", \"fmu.input\"]", conn["explicit"])
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
        _require(isinstance(c, dict), f"{p.name}: cases[{i}]", "a table (key, label, parameters, fmus)", c)
        check_name(c.get("key"), f"{p.name}: cases[{i}].key")
        unknown = set(c) - {"key", "label", "parameters", "fmus"}
        _require(not unknown, f"{p.name}: cases[{i}]", "keys allowed: ['fmus', 'key', 'label', 'parameters']",
                 sorted(unknown))
        over = c.get("parameters", {})
        _require(isinstance(over, dict) and all(isinstance(v, dict) for v in over.values()),
                 f"{p.name}: cases[{i}].parameters", "a table of FMU instance = {name = value}", over)
        _require(isinstance(c.get("fmus", {}), dict), f"{p.name}: cases[{i}].fmus", "a table", c.get("fmus"))
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
    _require(isinstance(record, list) and all(isinstance(r, str) and r.count(".") == 1 for r in record),
             f"{p.name}: record.signals", "a list of \"fmu.variable\" names", record)
    return Scenario(name=sc["name"], description=sc.get("description", ""), path=p, fmus=fmus, order=order,
                    connections=connections, parameters=params, cases=cases, step_size=float(step),
                    samples=samples, paper_table=sc.get("paper_table"), record=record, algorithm=algorithm,
                    kind=kind)


def select_cases(scenario: Scenario, keys: list[str] | None) -> Scenario:
    """`scenario` with only the cases named in `keys` (in the file's order); all of them when `keys` is empty.

    Raises
    ------
    ScenarioError
        Naming a key the scenario does not have and listing its cases.
    """
    if not keys:
        return scenario
    have = [c.key for c in scenario.cases]
    unknown = [k for k in keys if k not in have]
    if unknown:
        raise ScenarioError(f"--case: one of the cases of {scenario.name} ({', '.join(have)}), got {unknown[0]!r}")
    from dataclasses import replace

    return replace(scenario, cases=[c for c in scenario.cases if c.key in keys])


def parse_assignment(text: str) -> tuple[str, str, object]:
    """``instance.variable=value`` (the CLI's ``--set``) -> (instance, variable, value).

    The value is read as a TOML value (``40``, ``0.5``, ``true``, ``"gamma1"``); anything TOML does not read
    is taken as a string (``gamma1``). It is typed later by the FMU's model description
    (:mod:`scenarios.master.values`), like a scenario file's values.
    """
    target, sep, raw = text.partition("=")
    inst, dot, var = target.strip().partition(".")
    if not sep or not dot or not inst or not var.isidentifier() or not inst.isidentifier():
        raise ScenarioError(f"--set: instance.variable=value (e.g. controller.kp1=40), got {text!r}")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return inst, var, value


def list_scenarios() -> list[Scenario]:
    """Every scenario file shipped in ``scenarios/``."""
    return [load_scenario(p) for p in sorted(SCENARIO_DIR.glob("*.toml")) if p.stem != "paper_tables"]


def check_inputs_given(scenario: Scenario, inputs: dict[str, list[str]], driven: set[tuple[str, str]]) -> None:
    """With explicit wiring, every FMU input is connected or given a value by the scenario (in
    ``[parameters.<fmu>]`` or in every case); otherwise ScenarioError naming the input. (Wired by name, an
    input without a same-named output keeps its start value, as documented.)

    Parameters
    ----------
    scenario : Scenario
    inputs : dict
        FMU instance -> names of its inputs (from the model descriptions).
    driven : set of (instance, input)
        The inputs the connections drive.
    """
    if scenario.connections is None:
        return
    for inst, names in inputs.items():
        for var in names:
            if (inst, var) in driven or var in scenario.parameters.get(inst, {}):
                continue
            if scenario.cases and all(var in c.parameters.get(inst, {}) for c in scenario.cases):
                continue
            raise ScenarioError(f"{scenario.path.name}: connections.explicit: input {inst}.{var} is not connected "
                                f"and the scenario gives it no value, so it would stay at its start value all run; "
                                f"add a connection [\"<fmu>.<output>\", \"{inst}.{var}\"]")
