"""Sweeps and Monte Carlo over a scenario, run on Dask (or in-process).

A sweep file (TOML; shipped ones in ``scenarios/sweeps/``) names a base
scenario, one of its cases as the base point, and the axes to vary::

    [sweep]
    name = "robustness"
    scenario = "table2"            # a scenario name in scenarios/, or a path relative to this file
    case = "noise"                 # the base point (default: the scenario's first case)
    samples = 200                  # optional: override the run length (communication steps)

    [axes]
    plant.payload_mass = [0.0, 0.1, 0.2]                          # grid values
    controller.gain_set = ["gamma0", "gamma0.1"]                  # grid values (strings, booleans too)
    sensors.noise_seed = { range = [1, 20] }                      # integers 1..20 (optional step)
    fmus.controller = ["controller", "controller_fb"]             # FMU swap
    # or random samples: plant.payload_mass = { uniform = [0.0, 0.5], count = 50, seed = 7 }

Every point of the cartesian product of the axes (in file order, the last
axis fastest) is one co-simulation. Each result is appended, as it arrives,
to a JSON-lines journal in the output folder (flushed and fsynced per point;
key: a hash of the point's parameters, FMUs, the sweep file's and the
scenario file's SHA-256); a rerun skips the points the journal holds as
``ok`` or ``unbounded`` and reruns ``failed`` ones. The table (CSV, and
Parquet when pyarrow is importable) is written atomically from the journal.

Statuses: ``ok``; ``unbounded`` (the run diverged or an FMU gave up while
stepping; metrics empty); ``failed`` (nothing ran: an FMU refused its
parameters at the start, an exception, or the worker died).

Execution: a :class:`distributed.LocalCluster` (one process per core, one
thread each: the FMUs run Python and share the GIL), an existing Dask
cluster (``scheduler="tcp://host:8786"``), or in-process (``serial=True``).
The client reads the FMU files once and a worker plugin (:class:`ShipFmus`)
writes their bytes into a content-addressed folder on every worker (also
on workers that join or restart later); each process keeps one loaded
:class:`~scenarios.master.Master` per FMU set (reset between runs by
``fmi2Reset``). So remote workers need the project installed (same
version) but no FMU files of their own, and the SHA-256 recorded with a
point is that of the bytes that ran it.
"""

from __future__ import annotations

import copy
import csv
import hashlib
import importlib.util
import io
import itertools
import json
import math
import os
import socket
import sys
import tempfile
import time
import tomllib
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from distributed import WorkerPlugin
from fmpy import read_model_description

from .config import SCENARIO_DIR, Case, Scenario, ScenarioError, load_scenario
from .master import CoSimulationError, parse_choices
from .metrics import METRICS
from .results import git_commit, sha256_file, write_atomic, write_json
from .runner import DEFAULT_FMU_DIR, REPO, prepare, resolve_fmus, simulate_case

SWEEP_DIR = SCENARIO_DIR / "sweeps"
DEFAULT_OUT_DIR = REPO / "results" / "sweeps"
STATUSES = ("ok", "unbounded", "failed")
#: Statuses a rerun does not repeat (a ``failed`` point is tried again).
DONE = ("ok", "unbounded")
#: Environment variable of the test-only hook: a Dask worker given the point with this key exits at once.
CRASH_ENV = "FLEXARM_SWEEP_TEST_CRASH_KEY"
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
    sha256: str
    scenario: Scenario
    case: Case
    axes: list[Axis]

    @property
    def n_points(self) -> int:
        return math.prod(len(a.values) for a in self.axes)


@dataclass
class Point:
    """One co-simulation of a sweep."""

    index: int
    key: str
    values: dict  # axis field -> value
    fmus: dict[str, str]  # instance -> FMU name or .fmu path
    parameters: dict[str, dict]


@dataclass
class FmuSet:
    """The FMU files of one combination of the FMU-swap axes, read once by the client."""

    names: dict[str, str]
    paths: dict[str, Path]
    sha256: dict[str, str]
    blobs: dict[str, bytes] = field(repr=False)

    @property
    def key(self) -> str:
        return hashlib.sha256(json.dumps(self.sha256, sort_keys=True).encode()).hexdigest()[:16]


@dataclass
class Plan:
    """Everything a sweep runs: points, FMU sets, and the tasks sent to the workers."""

    sweep: Sweep
    points: list[Point]
    fmu_sets: dict[str, FmuSet]  # FmuSet.key -> set
    point_set: dict[str, str]  # point key -> FmuSet.key
    scenario_sha256: str

    def task(self, point: Point) -> dict:
        """The picklable description of one point that :func:`run_point` runs."""
        fs = self.fmu_sets[self.point_set[point.key]]
        return {"key": point.key, "index": point.index, "scenario": self.sweep.scenario, "fmu_names": fs.names,
                "fmu_sha256": fs.sha256, "parameters": point.parameters,
                "setup_key": f"{self.scenario_sha256[:16]}-{self.sweep.scenario.samples}-{fs.key}"}


# ----------------------------------------------------------------------------------------------- sweep files


def _require(cond: bool, where: str, allowed: str, got) -> None:
    if not cond:
        raise SweepError(f"{where}: {allowed}, got {got!r}")


def _is_scalar(v) -> bool:
    return isinstance(v, (bool, int, float, str)) and not (isinstance(v, float) and not math.isfinite(v))


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


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


def load_sweep(name_or_path: str | Path) -> Sweep:
    """Read and validate a sweep file (structure, base scenario and case, axis values).

    Parameters
    ----------
    name_or_path : str or Path
        A sweep name in ``scenarios/sweeps/`` or a path to a sweep file.

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
    unknown = sorted(set(doc) - _TOP_KEYS)
    _require(not unknown, p.name, f"top-level tables allowed: {sorted(_TOP_KEYS)}", unknown)
    sw = doc.get("sweep")
    _require(isinstance(sw, dict), f"{p.name}: [sweep]", "a table with name, scenario, [case], [samples]", sw)
    unknown = sorted(set(sw) - _SWEEP_KEYS)
    _require(not unknown, f"{p.name}: [sweep]", f"keys allowed: {sorted(_SWEEP_KEYS)}", unknown)
    name = sw.get("name")
    _require(isinstance(name, str) and name.isidentifier(), f"{p.name}: sweep.name",
             "an identifier (letters, digits, _; it names the output folder)", name)
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
        _require(samples == "trajectory" or (_is_int(samples) and 1 <= samples <= 10_000_000),
                 f"{p.name}: sweep.samples",
                 "an integer in [1, 10000000] or \"trajectory\" (as long as the slew)", samples)
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
    sweep = Sweep(name, sw.get("description", ""), p, hashlib.sha256(raw).hexdigest(), scenario, case, axes)
    _require(sweep.n_points <= MAX_POINTS, f"{p.name}: [axes]", f"at most {MAX_POINTS} points in all",
             sweep.n_points)
    return sweep


def _check_axis_against_fmu(sweep: Sweep, axis: Axis, fmu_path: Path) -> None:
    """Variable exists, is a parameter, and every value fits its type and range in the model description."""
    where = f"{sweep.path.name}: axes.{axis.field}"
    md = read_model_description(str(fmu_path))
    params = {v.name: v for v in md.modelVariables if v.causality == "parameter"}
    v = params.get(axis.variable)
    _require(v is not None, where, f"a parameter of FMU {fmu_path.name} ({sorted(params)})", axis.variable)
    lo = None if v.min in (None, "") else float(v.min)
    hi = None if v.max in (None, "") else float(v.max)
    bounds = f"[{'-inf' if lo is None else v.min}, {'inf' if hi is None else v.max}]"
    axis.unit = getattr(v, "unit", None) or ""
    unit = f" {axis.unit}" if axis.unit else ""
    if axis.kind == "uniform":
        _require(v.type == "Real", where, f"uniform samples only for a Real parameter ({axis.variable} is {v.type})",
                 axis.kind)
    for x in axis.values:
        if v.type == "Real":
            _require(_is_number(x), where, f"numbers ({axis.variable} is Real{unit})", x)
        elif v.type == "Integer" and parse_choices(v.description or ""):  # names, mapped by the master
            _require(isinstance(x, str), where, f"choice names ({axis.variable}: "
                     f"{', '.join(parse_choices(v.description))})", x)
        elif v.type in ("Integer", "Enumeration"):
            _require(_is_int(x), where, f"integers ({axis.variable} is {v.type})", x)
        elif v.type == "Boolean":
            _require(isinstance(x, bool), where, f"true or false ({axis.variable} is Boolean)", x)
        else:
            _require(isinstance(x, str), where, f"strings ({axis.variable} is {v.type})", x)
        if v.type == "Real" or (v.type == "Integer" and not isinstance(x, str)):
            _require((lo is None or x >= lo) and (hi is None or x <= hi), where,
                     f"values in the FMU's range {bounds}{unit}", x)


def _point_key(sweep_sha: str, scenario_sha: str, fmus: dict, parameters: dict) -> str:
    blob = json.dumps({"sweep_sha256": sweep_sha, "scenario_sha256": scenario_sha, "fmus": fmus,
                       "parameters": parameters}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _known_fmu_names() -> list[str]:
    try:
        import fmu_build

        return sorted(fmu_build.FMUS)
    except Exception:  # noqa: BLE001 - only for the error message
        return []


def plan_sweep(sweep: Sweep, fmu_dir: Path = DEFAULT_FMU_DIR, build: bool = True) -> Plan:
    """Resolve (and build) the FMUs of every FMU set, check the axes against them, list the points.

    Parameters
    ----------
    sweep : Sweep
        From :func:`load_sweep`.
    fmu_dir : Path
        Where built FMUs live (``build/fmus``); FMU names are built there when stale.
    build : bool
        Build stale FMUs (False: use the files as they are).

    Returns
    -------
    Plan
        The points in product order, each FMU set's bytes and SHA-256.
    """
    scenario, case = sweep.scenario, sweep.case
    scenario_sha = sha256_file(scenario.path)
    fmu_axes = [a for a in sweep.axes if a.is_fmu]
    fmu_sets: dict[str, FmuSet] = {}
    by_combo: dict[tuple, str] = {}
    known = _known_fmu_names()
    for a in fmu_axes:
        for v in a.values:
            where = f"{sweep.path.name}: axes.{a.field}"
            if v.endswith(".fmu"):
                _require(Path(v).is_file(), where, "paths to existing .fmu files", v)
            elif known:
                _require(v in known, where, f"FMU names of this project {known} or paths to .fmu files", v)
    for combo in itertools.product(*(a.values for a in fmu_axes)):
        names = {**case.fmus, **{a.instance: v for a, v in zip(fmu_axes, combo)}}
        try:
            paths = resolve_fmus(scenario, fmu_dir, None, build, names)
        except Exception as exc:
            raise SweepError(f"{sweep.path.name}: FMUs {names}: could not resolve or build them: {exc}") from exc
        blobs = {inst: p.read_bytes() for inst, p in paths.items()}
        shas = {inst: hashlib.sha256(b).hexdigest() for inst, b in blobs.items()}
        fs = FmuSet(names, paths, shas, blobs)
        fmu_sets.setdefault(fs.key, fs)
        by_combo[combo] = fs.key
    for axis in sweep.axes:
        if not axis.is_fmu:
            for fs in {k: fmu_sets[k] for k in by_combo.values()}.values():
                _check_axis_against_fmu(sweep, axis, fs.paths[axis.instance])
    points, point_set = [], {}
    for index, combo in enumerate(itertools.product(*(a.values for a in sweep.axes))):
        values = {a.field: v for a, v in zip(sweep.axes, combo)}
        params = copy.deepcopy(case.parameters)
        for a, v in zip(sweep.axes, combo):
            if not a.is_fmu:
                params.setdefault(a.instance, {})[a.variable] = v
        fs_key = by_combo[tuple(values[a.field] for a in fmu_axes)]
        names = fmu_sets[fs_key].names
        key = _point_key(sweep.sha256, scenario_sha, names, params)
        points.append(Point(index, key, values, names, params))
        point_set[key] = fs_key
    return Plan(sweep, points, fmu_sets, point_set, scenario_sha)


# ------------------------------------------------------------------------------------------- on the worker

#: Per process: setup key -> (Setup, open Master), least recently used first.
_LOADED: OrderedDict[str, tuple] = OrderedDict()
#: How many FMU sets a process keeps loaded.
CACHE_SIZE = 4
_TRAJECTORY_SHA: list[str] = []
_ERROR_WORDS = ("fail", "error", "outside", "rejected", "not ready", "not a ")


def _fmu_cache_dir() -> Path:
    return Path(os.environ.get("FLEXARM_SWEEP_FMU_CACHE", Path(tempfile.gettempdir()) / "flexarm-sweep-fmus"))


def _fmu_file(name: str, sha: str) -> Path:
    """Where the FMU with this SHA-256 lives in this machine's content-addressed cache."""
    return _fmu_cache_dir() / sha[:32] / f"{Path(name).stem}.fmu"


def store_fmus(names: dict[str, str], blobs: dict[str, bytes]) -> dict[str, str]:
    """Write FMU bytes into the content-addressed cache (once); instance -> SHA-256."""
    shas = {}
    for inst, data in blobs.items():
        sha = hashlib.sha256(data).hexdigest()
        p = _fmu_file(names[inst], sha)
        if not (p.is_file() and p.stat().st_size == len(data)):
            write_atomic(p, data)
        shas[inst] = sha
    return shas


class ShipFmus(WorkerPlugin):
    """Dask worker plugin: writes one FMU set's files into every worker's cache, also on workers that
    join or restart later (registered with ``Client.register_plugin``)."""

    idempotent = True

    def __init__(self, names: dict[str, str], blobs: dict[str, bytes]):
        self.names, self.blobs = names, blobs

    def setup(self, worker=None) -> None:
        store_fmus(self.names, self.blobs)

    def teardown(self, worker=None) -> None:
        pass


def _loaded(task: dict):
    key = task["setup_key"]
    if key in _LOADED:
        _LOADED.move_to_end(key)
        return _LOADED[key]
    while len(_LOADED) >= CACHE_SIZE:
        _, (_, old) = _LOADED.popitem(last=False)
        old.close()
    paths = {}
    for inst, sha in task["fmu_sha256"].items():
        p = _fmu_file(task["fmu_names"][inst], sha)
        if not p.is_file():
            raise CoSimulationError(f"fmus.{inst}: {p} missing on this worker (the client ships FMUs with a "
                                    "worker plugin: was the sweep started through scenarios.sweep?)")
        paths[inst] = str(p)
    setup = prepare(task["scenario"], names=paths, build=False)
    m = setup.open_master()
    _LOADED[key] = (setup, m)
    return setup, m


def close_loaded() -> int:
    """Close every FMU set this process keeps loaded; returns how many."""
    n = len(_LOADED)
    while _LOADED:
        _, (_, m) = _LOADED.popitem(last=False)
        m.close()
    return n


def _crash_hook(key: str) -> None:
    """Test-only: a Dask worker exits at once on the point named in $FLEXARM_SWEEP_TEST_CRASH_KEY."""
    if os.environ.get(CRASH_ENV) != key:
        return
    try:
        from distributed import get_worker

        get_worker()
    except (ImportError, ValueError):
        return  # never in-process
    os._exit(13)


def run_point(task: dict) -> dict:
    """Run one point (on a worker or in-process) and return its journal record; never raises.

    Parameters
    ----------
    task : dict
        From :meth:`Plan.task`. The FMU files must be in this machine's cache
        (:func:`store_fmus`, done on Dask workers by :class:`ShipFmus`).

    Returns
    -------
    dict
        ``key``, ``index``, ``status`` (see the module docstring), ``message``,
        ``metrics`` (None unless ok), ``wall_time_s`` (the run), ``setup_time_s``
        (loading the FMUs, 0 when they were loaded), ``steps_done``, ``worker``
        (host:pid), ``fmu_sha256``, ``trajectory_sha256``.
    """
    t0 = time.perf_counter()
    rec = {"key": task["key"], "index": task["index"], "status": "failed", "message": "", "metrics": None,
           "wall_time_s": 0.0, "setup_time_s": 0.0, "steps_done": 0, "worker": f"{socket.gethostname()}:{os.getpid()}",
           "fmu_sha256": task["fmu_sha256"]}
    try:
        _crash_hook(task["key"])
        fresh = task["setup_key"] not in _LOADED
        setup, m = _loaded(task)
        t1 = time.perf_counter()
        rec["setup_time_s"] = t1 - t0 if fresh else 0.0
        if not _TRAJECTORY_SHA:
            from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE

            _TRAJECTORY_SHA.append(sha256_file(DEFAULT_TRAJECTORY_FILE))
        out, metrics = simulate_case(setup, m, task["parameters"])
        rec["wall_time_s"] = time.perf_counter() - t1
        status, message = out["status"], out["message"]
        if status != "ok" and out["steps_done"] == 0:
            status = "failed"  # the FMUs refused to start: a configuration error, not a divergence
            errors = [line for line in out["log"] if any(w in line for w in _ERROR_WORDS)]
            message += "; FMU log: " + " | ".join((errors or out["log"])[:2])
        rec.update(status=status, message=message, metrics=metrics, steps_done=out["steps_done"])
    except Exception as exc:  # noqa: BLE001 - recorded against the point, never fatal to the sweep
        rec.update(status="failed", message=f"{type(exc).__name__}: {exc}", wall_time_s=time.perf_counter() - t0)
        if not isinstance(exc, CoSimulationError) and task["setup_key"] in _LOADED:
            _LOADED.pop(task["setup_key"])[1].close()
    rec["trajectory_sha256"] = _TRAJECTORY_SHA[0] if _TRAJECTORY_SHA else None
    return rec


# ------------------------------------------------------------------------------------------- executors


def iter_serial(plan: Plan, points: list[Point]) -> Iterator[dict]:
    """Run `points` one after the other in this process (FMUs loaded once per FMU set)."""
    for k in {plan.point_set[p.key] for p in points}:
        store_fmus(plan.fmu_sets[k].names, plan.fmu_sets[k].blobs)
    for p in points:
        yield run_point(plan.task(p))


def local_cluster(n_workers: int | None = None, allowed_failures: int = 1):
    """A :class:`distributed.LocalCluster` for sweeps: processes, one thread each.

    Parameters
    ----------
    n_workers : int, optional
        Worker processes (default: the machine's cores).
    allowed_failures : int
        How often the scheduler retries a point whose worker died before it
        marks it lost (recorded as ``failed``).

    Notes
    -----
    ``worker-saturation`` 1.0 keeps exactly one point per worker in flight,
    so a worker that dies takes only its own point with it; the workers'
    statistical profiler is off (it interrupts the co-simulation's thread).
    """
    import dask
    from distributed import LocalCluster

    with dask.config.set({"distributed.scheduler.allowed-failures": allowed_failures,
                          "distributed.scheduler.worker-saturation": 1.0,
                          # the statistical profiler takes the GIL every 10 ms from the running co-simulation
                          "distributed.worker.profile.enabled": False}):
        return LocalCluster(n_workers=n_workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                            dashboard_address=None)


def iter_dask(client, plan: Plan, points: list[Point]) -> Iterator[dict]:
    """Submit `points` to a Dask cluster and yield their records as they complete.

    The FMU files go to every worker through a worker plugin (:class:`ShipFmus`),
    so the tasks carry no data and the scheduler queues them (one point in
    flight per worker thread on our local cluster: a worker that dies takes
    only its own point with it). A point whose worker died, or any other
    error outside :func:`run_point`, comes back as a ``failed`` record naming it.
    """
    from distributed import as_completed

    needed = sorted({plan.point_set[p.key] for p in points})
    plugins = []
    for k in needed:
        name = f"flexarm-sweep-fmus-{k}"
        client.register_plugin(ShipFmus(plan.fmu_sets[k].names, plan.fmu_sets[k].blobs), name=name)
        plugins.append(name)
    # Points of one FMU set together (Dask runs earlier tasks first): workers rarely switch FMU sets.
    order = sorted(points, key=lambda p: (plan.point_set[p.key], p.index))
    stamp = time.time_ns()
    # One batch (client.map): the scheduler sees the whole group and queues it instead of spreading it.
    futures = client.map(run_point, [plan.task(p) for p in order], pure=False,
                         key=[f"sweep-point-{p.key}-{stamp}" for p in order])
    point_of = {fut.key: p for fut, p in zip(futures, order)}
    try:
        for fut in as_completed(futures):
            p = point_of[fut.key]
            if fut.status == "finished":
                rec = fut.result()
            else:
                try:
                    exc = fut.exception()
                except Exception as e:  # noqa: BLE001 - e.g. cancelled
                    exc = e
                rec = {"key": p.key, "index": p.index, "status": "failed",
                       "message": f"{type(exc).__name__}: {exc}", "metrics": None, "wall_time_s": 0.0,
                       "setup_time_s": 0.0, "steps_done": 0, "worker": None,
                       "fmu_sha256": plan.fmu_sets[plan.point_set[p.key]].sha256, "trajectory_sha256": None}
            fut.release()
            yield rec
    finally:
        pending = [f for f in futures if not f.done()]
        if pending:
            client.cancel(pending, force=True)
        for name in plugins:
            try:
                client.unregister_worker_plugin(name)
            except Exception:  # noqa: BLE001 - the cluster may be gone
                pass


# ------------------------------------------------------------------------------------------- journal, table


class Journal:
    """Append-only JSON lines: one record per finished point, flushed and fsynced as it comes."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.bad_lines = 0
        self._f = None

    def read(self) -> dict[str, dict]:
        """Latest record per point key (lines that do not parse, e.g. cut by a crash, are skipped)."""
        records: dict[str, dict] = {}
        self.bad_lines = 0
        if not self.path.is_file():
            return records
        for line in self.path.read_text(errors="replace").splitlines():
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
                records[rec["key"]] = rec
            except (json.JSONDecodeError, KeyError, TypeError):
                self.bad_lines += 1
        return records

    def append(self, record: dict) -> None:
        if self._f is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f = open(self.path, "a+b")  # noqa: SIM115 - kept open for the sweep, closed by close()
            self._f.seek(0, os.SEEK_END)
            if self._f.tell() > 0:
                self._f.seek(-1, os.SEEK_END)
                if self._f.read(1) != b"\n":  # a line cut by a crash: never glue the next one to it
                    self._f.write(b"\n")
        self._f.write((json.dumps(record, default=_jsonable, allow_nan=True) + "\n").encode())
        self._f.flush()
        os.fsync(self._f.fileno())

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None


def _jsonable(x):
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON serialisable: {type(x)}")


def table_columns(plan: Plan) -> list[str]:
    insts = sorted(plan.sweep.scenario.fmus)
    return (["index", "key"] + [a.field for a in plan.sweep.axes] + ["status", *METRICS]
            + ["wall_time_s", "setup_time_s", "steps_done", "worker", "message", "commit", "finished_at"]
            + [f"fmu_sha256.{i}" for i in insts])


def table_rows(plan: Plan, records: dict[str, dict]) -> list[dict]:
    """One row per point the journal holds, in point order (the table's content)."""
    rows = []
    for p in plan.points:
        rec = records.get(p.key)
        if rec is None:
            continue
        row = {"index": p.index, "key": p.key, **p.values, "status": rec["status"]}
        metrics = rec.get("metrics") or {}
        row.update({m: metrics.get(m) for m in METRICS})
        for k in ("wall_time_s", "setup_time_s", "steps_done", "worker", "message", "commit", "finished_at"):
            row[k] = rec.get(k)
        row.update({f"fmu_sha256.{i}": s for i, s in (rec.get("fmu_sha256") or {}).items()})
        rows.append(row)
    return rows


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def write_table(path: Path, columns: list[str], rows: list[dict]) -> list[Path]:
    """CSV (full float precision; empty cell = no value) and, when pyarrow is importable, Parquet."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        w.writerow([_cell(r.get(c)) for c in columns])
    write_atomic(path, buf.getvalue())
    written = [path]
    if importlib.util.find_spec("pyarrow") is not None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        data = {c: [r.get(c) for r in rows] for c in columns}
        out = io.BytesIO()
        pq.write_table(pa.table(data), out)
        write_atomic(path.with_suffix(".parquet"), out.getvalue())
        written.append(path.with_suffix(".parquet"))
    return written


def read_table(path: Path) -> list[dict[str, str]]:
    """The CSV table back as rows of strings."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


# ------------------------------------------------------------------------------------------- progress, plots


class Progress:
    """A text progress bar with an estimate of the time left, on stderr."""

    def __init__(self, label: str, total: int, already: int, enabled: bool = True, stream=None):
        self.label, self.total, self.done, self.enabled = label, total, already, enabled
        self.stream = stream or sys.stderr
        self.counts = dict.fromkeys(STATUSES, 0)
        self.t0 = time.perf_counter()
        self.t_first = None
        self.n_run = 0
        self._last = 0.0
        self._tty = hasattr(self.stream, "isatty") and self.stream.isatty()

    def update(self, record: dict) -> None:
        self.done += 1
        self.n_run += 1
        self.counts[record["status"]] = self.counts.get(record["status"], 0) + 1
        now = time.perf_counter()
        if self.t_first is None:
            self.t_first = now
        if not self.enabled:
            return
        if self._tty or now - self._last > 10 or self.done == self.total:
            self._last = now
            self.stream.write(("\r" if self._tty else "") + self.line(now) + ("" if self._tty else "\n"))
            if self._tty and self.done == self.total:
                self.stream.write("\n")
            self.stream.flush()

    def eta(self, now: float) -> float | None:
        """Seconds left: the rate since the first completion (excluding start-up), else None."""
        if self.n_run >= 2 and now > self.t_first:
            rate = (self.n_run - 1) / (now - self.t_first)
            return (self.total - self.done) / rate
        return None

    def line(self, now: float) -> str:
        frac = self.done / self.total if self.total else 1.0
        bar = "#" * int(25 * frac)
        eta = self.eta(now)
        left = "?" if eta is None else _hms(eta)
        c = self.counts
        return (f"{self.label} [{bar:25s}] {self.done}/{self.total} {100 * frac:3.0f}%  "
                f"{_hms(now - self.t0)} elapsed, ~{left} left  "
                f"(ok {c['ok']}, unbounded {c['unbounded']}, failed {c['failed']})")


def _hms(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def _short(field: str, v) -> str:
    name = field.split(".", 1)[1]
    return f"{name}={_cell(v)}"


def summary_plots(plan: Plan, rows: list[dict], folder: Path) -> list[Path]:
    """PNG summaries: each metric against the main numeric axis (payload by default), one line per
    combination of the other axes (mean over seeds, min-max band); and box plots of the rms errors'
    spread over the seeds. Written atomically; returns the paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .metrics import LABELS
    from .plots import _save

    axes = plan.sweep.axes
    ok = [r for r in rows if r["status"] == "ok"]
    n_bad = len(rows) - len(ok)
    if not ok:
        return []
    reps = [a for a in axes if a.is_replicate and len(a.values) > 1]
    numeric = [a for a in axes if not a.is_fmu and not a.is_replicate and len(a.values) > 1
               and all(_is_number(v) for v in a.values)]
    x_axis = next((a for a in numeric if a.field == "plant.payload_mass"), numeric[0] if numeric else None)
    groups_axes = [a for a in axes if a not in reps and a is not x_axis and len(a.values) > 1]
    gain = next((a for a in groups_axes if a.field == "controller.gain_set"), None)
    if gain is not None:  # gain set first in the labels
        groups_axes = [gain] + [a for a in groups_axes if a is not gain]

    def group_label(r):
        return ", ".join(_short(a.field, r[a.field]) for a in groups_axes) or "all"

    out = []
    note = f" ({n_bad} unbounded/failed points left out)" if n_bad else ""
    if x_axis is not None:
        fig, subs = plt.subplots(2, 3, figsize=(14, 7.5), sharex=True)
        labels = list(dict.fromkeys(group_label(r) for r in ok))
        for ax, m in zip(subs.flat, METRICS):
            for lab in labels:
                xs = sorted({r[x_axis.field] for r in ok if group_label(r) == lab})
                vals = [[r[m] for r in ok if group_label(r) == lab and r[x_axis.field] == x] for x in xs]
                mean = [float(np.mean(v)) for v in vals]
                line, = ax.plot(xs, mean, "o-", ms=3, lw=1.2, label=lab)
                if reps:
                    ax.fill_between(xs, [min(v) for v in vals], [max(v) for v in vals], color=line.get_color(),
                                    alpha=0.15, lw=0)
            positive = [r[m] for r in ok if r[m] > 0]
            if positive and max(positive) / min(positive) > 100:
                ax.set_yscale("log")
            ax.set(title=LABELS[m], xlabel=x_axis.field + (f", {x_axis.unit}" if x_axis.unit else ""))
            ax.grid(alpha=0.3)
        subs.flat[0].legend(fontsize=7)
        what = " (mean over " + ", ".join(a.field for a in reps) + "; band: min-max)" if reps else ""
        fig.suptitle(f"sweep {plan.sweep.name}: metrics against {x_axis.field}{what}{note}", fontsize=10)
        fig.tight_layout()
        path = folder / f"metrics_vs_{x_axis.variable}.png"
        _save(fig, path)
        out.append(path)
    if reps:
        box_axes = [a for a in axes if a not in reps and len(a.values) > 1]
        if gain is not None:
            box_axes = [gain] + [a for a in box_axes if a is not gain]

        def box_label(r):
            return "\n".join(_short(a.field, r[a.field]) for a in box_axes) or "all"

        labels = list(dict.fromkeys(box_label(r) for r in sorted(ok, key=lambda r: [
            str(r[a.field]) if not _is_number(r[a.field]) else f"{r[a.field]:020.9f}" for a in box_axes])))
        fig, subs = plt.subplots(2, 1, figsize=(max(8, 0.55 * len(labels) + 2), 8), sharex=True)
        for ax, m in zip(subs, ("rms_position_error", "rms_velocity_error")):
            data = [[r[m] for r in ok if box_label(r) == lab] for lab in labels]
            ax.boxplot(data, showmeans=True)
            positive = [x for d in data for x in d if x > 0]
            if positive and max(positive) / min(positive) > 100:
                ax.set_yscale("log")
            ax.set(ylabel=LABELS[m])
            ax.grid(alpha=0.3, axis="y")
        subs[1].set_xticks(range(1, len(labels) + 1), labels, fontsize=6, rotation=90)
        fig.suptitle(f"sweep {plan.sweep.name}: spread of the rms errors over "
                     + ", ".join(f"{a.field} ({len(a.values)})" for a in reps) + note, fontsize=10)
        fig.tight_layout()
        path = folder / "rms_spread_over_seeds.png"
        _save(fig, path)
        out.append(path)
    return out


def format_summary(plan: Plan, rows: list[dict], max_rows: int = 60) -> str:
    """A text table: one line per point, or (with seed axes) per combination of the other axes, mean over seeds."""
    reps = [a for a in plan.sweep.axes if a.is_replicate and len(a.values) > 1]
    keys = [a for a in plan.sweep.axes if a not in reps]
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[a.field] for a in keys), []).append(r)
    short = {"peak_tau1": "pk_tau1", "peak_tau2": "pk_tau2", "peak_position_error": "pk_pos",
             "peak_velocity_error": "pk_vel", "rms_position_error": "rms_pos", "rms_velocity_error": "rms_vel"}
    widths = [max(len(a.field), *(len(_cell(v)) for v in a.values)) for a in keys]
    head = "  ".join(f"{a.field:>{w}s}" for a, w in zip(keys, widths))
    head += f"  {'ok/n':>7s}" + "".join(f"{short[m]:>10s}" for m in METRICS)
    lines = [("mean over " + ", ".join(a.field for a in reps) + " (ok points)") if reps else "", head]
    for i, (vals, rs) in enumerate(groups.items()):
        if i == max_rows:
            lines.append(f"... {len(groups) - max_rows} more (see the CSV)")
            break
        ok = [r for r in rs if r["status"] == "ok"]
        line = "  ".join(f"{_cell(v):>{w}s}" for v, w in zip(vals, widths))
        line += f"  {len(ok):>3d}/{len(rs):<3d}"
        for m in METRICS:
            line += f"{np.mean([r[m] for r in ok]):10.4g}" if ok else f"{'-':>10s}"
        if not ok:
            line += "  " + ", ".join(sorted({r["status"] for r in rs}))
        lines.append(line)
    return "\n".join(x for x in lines if x)


# ------------------------------------------------------------------------------------------- the sweep


@dataclass
class SweepResult:
    plan: Plan
    folder: Path
    rows: list[dict]
    ran: int  # points run by this call
    skipped: int  # points found done in the journal
    tables: list[Path]
    plots: list[Path]
    wall_time_s: float


def run_sweep(sweep: Sweep | str | Path, out_dir: Path = DEFAULT_OUT_DIR, fmu_dir: Path = DEFAULT_FMU_DIR, *,
              scheduler: str | None = None, workers: int | None = None, serial: bool = False,
              plots: bool = True, progress: bool = True, build: bool = True, allowed_failures: int = 1,
              on_record: Callable[[dict], None] | None = None) -> SweepResult:
    """Run every point of a sweep not yet in its journal; write the table and plots.

    Parameters
    ----------
    sweep : Sweep, str or Path
        A loaded sweep, a sweep name in ``scenarios/sweeps/`` or a path.
    out_dir : Path
        Results go to ``out_dir/<sweep name>/``: ``journal.jsonl``,
        ``<name>.csv`` (and ``.parquet``), ``sweep.json`` (provenance), PNGs.
    fmu_dir : Path
        Where built FMUs live.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); the workers
        need this project installed. Default: a local cluster.
    workers : int, optional
        Worker processes of the local cluster (default: the machine's cores).
    serial : bool
        Run in this process, one point after the other (debugging).
    plots, progress : bool
        Write the summary PNGs; show the progress bar on stderr.
    build : bool
        Build stale FMUs first.
    allowed_failures : int
        Local cluster only: retries of a point whose worker died.
    on_record : callable, optional
        Called with each new journal record.

    Returns
    -------
    SweepResult
    """
    t_start = time.perf_counter()
    if not isinstance(sweep, Sweep):
        sweep = load_sweep(sweep)
    plan = plan_sweep(sweep, fmu_dir, build)
    folder = Path(out_dir) / sweep.name
    journal = Journal(folder / "journal.jsonl")
    records = journal.read()
    done = {p.key for p in plan.points if records.get(p.key, {}).get("status") in DONE}
    todo = [p for p in plan.points if p.key not in done]
    commit = git_commit()
    mode = "serial" if serial else f"dask {scheduler or f'LocalCluster({workers or os.cpu_count()} workers)'}"
    meta = {
        "sweep": sweep.name, "description": sweep.description, "sweep_file": str(sweep.path),
        "sweep_sha256": sweep.sha256, "scenario": sweep.scenario.name, "scenario_file": str(sweep.scenario.path),
        "scenario_sha256": plan.scenario_sha256, "base_case": sweep.case.key, "samples": sweep.scenario.samples,
        "axes": [{"field": a.field, "kind": a.kind, "values": a.values} for a in sweep.axes],
        "points": len(plan.points), "commit": commit, "execution": mode,
        "fmu_sets": [{"fmus": fs.names, "fmu_sha256": fs.sha256} for fs in plan.fmu_sets.values()],
        "started_at": _now(), "journal": "journal.jsonl", "columns": table_columns(plan),
    }
    write_json(folder / "sweep.json", meta)
    bar = Progress(sweep.name, len(plan.points), len(done), progress)
    if progress and done:
        sys.stderr.write(f"{sweep.name}: {len(done)} of {len(plan.points)} points done in {journal.path}, "
                         f"{len(todo)} to run\n")
    if journal.bad_lines:
        sys.stderr.write(f"{sweep.name}: skipped {journal.bad_lines} unreadable journal line(s)\n")
    other_build = sum(records[k].get("fmu_sha256") != plan.fmu_sets[plan.point_set[k]].sha256 for k in done)
    if other_build:
        sys.stderr.write(f"{sweep.name}: {other_build} point(s) in the journal ran on other FMU builds "
                         f"(fmu_sha256 columns); delete {journal.path} to run them again\n")
    client = cluster = None
    ran = 0
    try:
        if todo:
            if serial:
                results = iter_serial(plan, todo)
            else:
                from distributed import Client

                if scheduler:
                    client = Client(scheduler)
                else:
                    cluster = local_cluster(workers, allowed_failures)
                    client = Client(cluster)
                results = iter_dask(client, plan, todo)
            for rec in results:
                rec.update(commit=commit, finished_at=_now(), sweep_sha256=sweep.sha256)
                journal.append(rec)
                records[rec["key"]] = rec
                ran += 1
                bar.update(rec)
                if on_record is not None:
                    on_record(rec)
    finally:
        journal.close()
        if serial:
            close_loaded()
        if client is not None:
            if cluster is not None:
                try:
                    client.run(close_loaded)  # free the FMUs (and their unpacked folders) before the workers stop
                except Exception:  # noqa: BLE001 - a worker may be gone already
                    pass
            client.close()
        if cluster is not None:
            cluster.close()
        rows = table_rows(plan, records)
        tables = write_table(folder / f"{sweep.name}.csv", table_columns(plan), rows)
        write_json(folder / "sweep.json", {**meta, "finished_at": _now(), "run_now": ran, "from_journal": len(done),
                                           "status_counts": {st: sum(r["status"] == st for r in rows)
                                                             for st in STATUSES}})
    pngs = summary_plots(plan, rows, folder) if plots else []
    return SweepResult(plan, folder, rows, ran, len(done), tables, pngs, time.perf_counter() - t_start)


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def cli(args) -> int:
    """``python -m scenarios sweep``: run, then print the summary table and where the results are."""
    if args.serial and args.scheduler:
        raise SweepError("--serial and --scheduler: choose one")
    if args.workers is not None and (args.serial or args.scheduler):
        raise SweepError("--workers: only for the local cluster (not with --serial or --scheduler)")
    if args.workers is not None and args.workers < 1:
        raise SweepError(f"--workers: an integer >= 1, got {args.workers}")
    res = run_sweep(args.sweep, args.out, args.fmu_dir, scheduler=args.scheduler, workers=args.workers,
                    serial=args.serial, plots=not args.no_plots, progress=not args.quiet)
    counts = {s: sum(r["status"] == s for r in res.rows) for s in STATUSES}
    sw = res.plan.sweep
    print(f"\n== sweep {sw.name}: {sw.description}")
    print(f"   base: {sw.scenario.name}:{sw.case.key}, samples {sw.scenario.samples}; "
          f"{len(res.plan.points)} points ({res.ran} run now, {res.skipped} from the journal) in "
          f"{res.wall_time_s:.1f} s; ok {counts['ok']}, unbounded {counts['unbounded']}, failed {counts['failed']}")
    print(format_summary(res.plan, res.rows))
    for r in res.rows:
        if r["status"] == "failed":
            print(f"   failed #{r['index']} ({', '.join(_short(k, r[k]) for k in res.plan.points[0].values)}): "
                  f"{r['message'][:300]}")
    print("   table: " + ", ".join(str(p) for p in res.tables))
    if res.plots:
        print("   plots: " + ", ".join(str(p) for p in res.plots))
    return 0 if len(res.rows) == len(res.plan.points) else 1
