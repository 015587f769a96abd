"""A sweep's plan: the FMU sets (resolved, built, read once), every value checked against the FMUs'
model descriptions, a probe of the base point, and the points with their keys."""

from __future__ import annotations

import copy
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path

from flexarm.provenance import sha256_bytes
from scenarios.master.fmu_proxy import DEFAULT_STEP_TIMEOUT_S
from scenarios.master.values import check_value, check_variable
from scenarios.run.fmus import DEFAULT_FMU_DIR, DEFAULT_NATIVE_FMU_DIR, known_fmu_names
from scenarios.run.plan import PlannedCase, plan_case
from scenarios.run.setup import FmuSetPlan, prepare

from ..config import ScenarioError
from .spec import Axis, Sweep, SweepError, _require, toml_content_sha256


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
        return sha256_bytes(json.dumps(self.sha256, sort_keys=True).encode())[:16]


@dataclass
class Plan:
    """Everything a sweep runs: points, FMU sets, and the tasks sent to the workers."""

    sweep: Sweep
    points: list[Point]
    fmu_sets: dict[str, FmuSet]  # FmuSet.key -> set
    point_set: dict[str, str]  # point key -> FmuSet.key
    scenario_sha256: str
    #: Which FMUs run in a process of their own and how long a call may take (scenarios.run.setup.prepare).
    isolate: str = "foreign"
    step_timeout: float = DEFAULT_STEP_TIMEOUT_S
    #: Where the FMUs the points add by name (the reference FMU a controller's inputs ask for) are found:
    #: ``fmu_dir``, ``kind``, ``native_fmu_dir`` of :func:`scenarios.run.setup.prepare`, as the sweep was started with.
    where: dict = field(default_factory=dict)

    def task(self, point: Point) -> dict:
        """The picklable description of one point that :func:`run_point` runs."""
        fs = self.fmu_sets[self.point_set[point.key]]
        return {"key": point.key, "index": point.index, "scenario": self.sweep.scenario, "fmu_names": fs.names,
                "fmu_sha256": fs.sha256, "parameters": point.parameters,
                "isolate": self.isolate, "step_timeout": self.step_timeout, "where": self.where,
                "setup_key": f"{self.scenario_sha256[:16]}-{self.sweep.scenario.samples}-{fs.key}-{self.isolate}-"
                             f"{self.step_timeout:g}"}


def _check_axis(sweep: Sweep, axis: Axis, md, fmu_path: Path) -> None:
    """The axis names a parameter of the FMU and every value fits its type, range or enumeration items."""
    where = f"{sweep.path.name}: axes.{axis.field}"
    v = check_variable(where, md, axis.instance, axis.variable, fmu_path.name, SweepError)
    axis.unit = getattr(v, "unit", None) or ""
    if axis.kind == "uniform":
        _require(v.type == "Real", where, f"uniform samples only for a Real parameter ({axis.variable} is {v.type})",
                 axis.kind)
    for x in axis.values:
        check_value(where, v, x, SweepError)


def point_key(scenario_sha: str, samples, fmus: dict, parameters: dict, kind: str = "python") -> str:
    """A point's key: what defines its run (the scenario's parsed content, the run length, the FMU names, their
    kind and the parameters), not the sweep file's bytes: a comment, or a new value on an axis, reruns nothing.
    The kind enters only when it is not "python" (so journals written before kinds existed still match)."""
    what = {"scenario_content_sha256": scenario_sha, "samples": samples, "fmus": fmus, "parameters": parameters}
    if kind != "python":
        what["kind"] = kind
    blob = json.dumps(what, sort_keys=True, separators=(",", ":"))
    return sha256_bytes(blob.encode())[:16]


def plan_sweep(sweep: Sweep, fmu_dir: Path = DEFAULT_FMU_DIR, build: bool = True, probe: bool = True,
               kind: str | None = None, native_fmu_dir: Path = DEFAULT_NATIVE_FMU_DIR, isolate: str = "foreign",
               step_timeout: float = DEFAULT_STEP_TIMEOUT_S) -> Plan:
    """Resolve (and build) the FMUs of every FMU set, check every value against them, list the points.

    Parameters
    ----------
    sweep : Sweep
        From :func:`load_sweep`.
    fmu_dir : Path
        Where built FMUs live (``build/fmus``); FMU names are built there when stale.
    build : bool
        Build stale FMUs (False: use the files as they are).
    probe : bool
        Initialise each FMU set with the base point and take one communication step, so that a step or a
        value the FMUs refuse is reported (with the FMU's message) before any point runs.
    kind : str, optional
        "python" or "native" FMUs (default: the scenario's ``kind``); native ones are found (and built) in
        `native_fmu_dir` (:func:`scenarios.run.fmus.resolve_fmus`).
    isolate, step_timeout
        Which FMUs run in a process of their own ("foreign": those given as a .fmu path; "all") and how long
        one call of theirs may take, s (:func:`scenarios.master.isolation.isolated_instances`), in the probe and
        the points.

    Returns
    -------
    Plan
        The points in product order, each FMU set's bytes and SHA-256.

    Raises
    ------
    SweepError
        Naming the field and its allowed values (or the FMU's message for a refused probe).
    """
    scenario, case = sweep.scenario, sweep.case
    kind = kind or scenario.kind
    dirs = {"fmu_dir": fmu_dir, "kind": kind, "native_fmu_dir": native_fmu_dir}
    scenario_sha = toml_content_sha256(scenario.path)
    fmu_axes = [a for a in sweep.axes if a.is_fmu]
    fmu_sets: dict[str, FmuSet] = {}
    by_combo: dict[tuple, str] = {}
    known = known_fmu_names()
    for a in fmu_axes:
        for v in a.values:
            where = f"{sweep.path.name}: axes.{a.field}"
            if v.endswith(".fmu"):
                _require(Path(v).is_file(), where, "paths to existing .fmu files", v)
            elif known:
                _require(v in known, where, f"FMU names of this project {known} or paths to .fmu files", v)
    for combo in itertools.product(*(a.values for a in fmu_axes)):
        names = {**case.fmus, **{a.instance: v for a, v in zip(fmu_axes, combo)}}
        try:  # planned as a run plans an FMU set and a case (scenarios.run.plan); FMU names built now, if asked
            fmu_set = prepare(scenario, fmu_dir, None, names, build, kind, native_fmu_dir, isolate=isolate,
                              step_timeout=step_timeout)
            base = plan_case(fmu_set, case.key, case.label, case.parameters,
                             f"{scenario.path.name}: cases[{case.key}].parameters")
        except ScenarioError as exc:
            raise SweepError(f"{sweep.path.name}: FMUs {names}: {exc}") from exc
        except Exception as exc:  # noqa: BLE001 - a failed build is named with the FMU set
            raise SweepError(f"{sweep.path.name}: FMUs {names}: could not resolve or build them: {exc}") from exc
        paths = {inst: p for inst, p in fmu_set.paths.items() if inst in names}  # without a reference FMU added
        for axis in sweep.axes:
            if not axis.is_fmu:
                _check_axis(sweep, axis, fmu_set.descriptions[axis.instance], paths[axis.instance])
        blobs = {inst: p.read_bytes() for inst, p in paths.items()}
        shas = {inst: sha256_bytes(b) for inst, b in blobs.items()}
        fs = FmuSet(names, paths, shas, blobs)
        if probe and fs.key not in fmu_sets:
            _probe(sweep, fmu_set, base)
        fmu_sets.setdefault(fs.key, fs)
        by_combo[combo] = fs.key
    points, point_set = [], {}
    for index, combo in enumerate(itertools.product(*(a.values for a in sweep.axes))):
        values = {a.field: v for a, v in zip(sweep.axes, combo)}
        params = copy.deepcopy(case.parameters)
        for a, v in zip(sweep.axes, combo):
            if not a.is_fmu:
                params.setdefault(a.instance, {})[a.variable] = v
        fs_key = by_combo[tuple(values[a.field] for a in fmu_axes)]
        names = fmu_sets[fs_key].names
        key = point_key(scenario_sha, scenario.samples, names, params, kind)
        points.append(Point(index, key, values, names, params))
        point_set[key] = fs_key
    return Plan(sweep, points, fmu_sets, point_set, scenario_sha, isolate, step_timeout, dirs)


def _probe(sweep: Sweep, fmu_set: FmuSetPlan, base: PlannedCase) -> None:
    """Initialise the base point on this FMU set and step once; a refusal is a :class:`SweepError`."""
    with fmu_set.open_master() as m:  # with a reference FMU added; stepping as the scenario does
        outcome = m.probe(base.parameters, sweep.scenario.step_size)
    if outcome.status == "error":
        raise SweepError(f"{sweep.path.name}: base point (case {sweep.case.key}, communication step "
                         f"{sweep.scenario.step_size:g} s) refused by {outcome.fmu} ({outcome.function} returned "
                         f"{outcome.fmu_status}): {outcome.fmu_message or outcome.message}")


__all__ = ["FmuSet", "Plan", "Point", "plan_sweep", "point_key"]
