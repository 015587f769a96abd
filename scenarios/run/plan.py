"""A run's plan: everything a scenario run decides before its first case runs, built once, frozen (:class:`RunPlan`).

The plan is the first stage of a run (docs/architecture.md, "Data flow"): :func:`read_run_data` applies the
``--set`` values and verifies the data chain, loading the trajectory once (:class:`RunData`); :func:`plan_run`
then prepares each FMU set once (:func:`scenarios.run.setup.prepare`: paths, wiring, records, which FMUs are
isolated) and checks each case's values once against its FMUs (:func:`plan_case`). The later stages (connect,
run, judge, write) read the plan; none of them changes it or computes any of it again. The sweep and the score
plan their FMU sets and their points with the same two functions, :func:`scenarios.run.setup.prepare` and
:func:`plan_case`.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

from flexarm.provenance import git_commit, package_version, sha256_file
from scenarios.config import Scenario
from scenarios.master.fmu_proxy import DEFAULT_STEP_TIMEOUT_S
from scenarios.run.fmus import DEFAULT_FMU_DIR, DEFAULT_NATIVE_FMU_DIR
from scenarios.run.setup import FmuSetPlan, check_overrides, prepare, swap_report, verified_data, with_overrides


@dataclass(frozen=True)
class RunData:
    """What a run reads before any FMU: the scenario with the ``--set`` values applied, the verified data chain
    and the trajectory, loaded once (:func:`read_run_data`)."""

    #: The scenario with the ``--set`` values applied to every case (:func:`scenarios.run.setup.with_overrides`).
    scenario: Scenario
    #: The ``--set`` values ({instance: {variable: value}}) as given.
    overrides: Mapping[str, dict]
    #: The trajectory the run tracks (:func:`scenarios.run.setup.verified_data`).
    trajectory: object = field(repr=False)
    #: Every data file (relative to the repository) -> SHA-256 (the results' ``data_sha256``).
    data_sha256: Mapping[str, str] = field(repr=False)
    commit: str | None
    version: str
    scenario_sha256: str

    @functools.cached_property
    def reference(self):
        """The reference signals of the trajectory (the CSV's ``ref.*`` and ``err.*`` columns,
        scenarios/results.py), made when the judge stage first needs them, after the run: nothing the master's
        first step waits for (issue 34, start-up)."""
        from flexarm.reference import ReferenceSignals

        return ReferenceSignals(self.trajectory)


def read_run_data(scenario: Scenario, overrides: dict[str, dict] | None = None) -> RunData:
    """The ``--set`` values applied (an unknown instance refused), the data chain verified (a mismatch refused:
    :class:`scenarios.run.setup.DataChainError`), the trajectory loaded once: nothing here touches an FMU or
    the results folder."""
    scenario = with_overrides(scenario, overrides)
    chain, traj = verified_data()
    return RunData(scenario, MappingProxyType(dict(overrides or {})), traj, MappingProxyType(chain), git_commit(),
                   package_version(), sha256_file(scenario.path))


@dataclass(frozen=True)
class PlannedCase:
    """One case of a run: its FMU set and its values, checked and converted once (:func:`plan_case`)."""

    key: str
    label: str
    #: {instance: {variable: value}} checked against the FMUs and converted, with the plant's start and the
    #: reference FMU's lead (:meth:`scenarios.run.setup.FmuSetPlan.case_parameters`): what the master sets.
    parameters: Mapping[str, dict]
    fmu_set: FmuSetPlan = field(repr=False)


def plan_case(fmu_set: FmuSetPlan, key: str, label: str, parameters: dict[str, dict], where: str = "") -> PlannedCase:
    """A case's values checked against `fmu_set`'s FMUs and converted, once; a refusal (ScenarioError) names
    `where` (e.g. ``table2.toml: cases[none].parameters``) and the field."""
    return PlannedCase(key, label, MappingProxyType(fmu_set.case_parameters(parameters, where)), fmu_set)


@dataclass(frozen=True)
class RunPlan:
    """A scenario run, decided: its data, stepping, FMU sets and cases (checked). Built once by :func:`plan_run`."""

    data: RunData
    #: The scenario with the ``--set`` values applied (:attr:`RunData.scenario`).
    scenario: Scenario
    #: The co-simulation algorithm the run steps with (the caller's, else the scenario's).
    algorithm: str
    #: One per distinct set of FMUs the cases name, in the order of their first case, each with its cases
    #: (the order they run in).
    groups: tuple[tuple[FmuSetPlan, tuple[PlannedCase, ...]], ...]
    #: Lines a run prints once: parameters left out, inputs held, the reference FMU's feeds
    #: (:func:`scenarios.run.setup.swap_report`).
    notes: tuple[str, ...] = ()

    @property
    def cases(self) -> tuple[PlannedCase, ...]:
        """Every planned case, in the order they run."""
        return tuple(c for _, cases in self.groups for c in cases)


def plan_run(scenario: Scenario, *, fmu_dir: Path = DEFAULT_FMU_DIR, controller: str | None = None,
             kind: str | None = None, native_fmu_dir: Path = DEFAULT_NATIVE_FMU_DIR, algorithm: str | None = None,
             overrides: dict[str, dict] | None = None, isolate: str = "foreign",
             step_timeout: float = DEFAULT_STEP_TIMEOUT_S, data: RunData | None = None) -> RunPlan:
    """Decide a scenario run before anything runs (see :func:`scenarios.run.runner.run_scenario` for the arguments).

    Each FMU set the cases name is prepared once (:func:`scenarios.run.setup.prepare`, with its isolated FMUs and
    step timeout), the ``--set`` values are checked against it, and each case's values are checked once
    (:func:`plan_case`, naming ``cases[<key>].parameters``). `data` (:func:`read_run_data`) when the caller has
    read it already (the runner reads it before it locks the results folder).
    """
    data = data if data is not None else read_run_data(scenario, overrides)
    scenario = data.scenario
    algorithm = algorithm or scenario.algorithm
    groups: dict[tuple, list] = {}
    for case in scenario.cases:
        groups.setdefault(tuple(sorted(case.fmus.items())) if case.fmus else (), []).append(case)
    planned, notes = [], []
    for names, group in groups.items():
        fmu_set = prepare(scenario, fmu_dir, controller, dict(names) if names else None, kind=kind,
                          native_fmu_dir=native_fmu_dir, algorithm=algorithm, isolate=isolate,
                          step_timeout=step_timeout, trajectory=data.trajectory)
        check_overrides(fmu_set, dict(data.overrides))
        planned.append((fmu_set, tuple(plan_case(fmu_set, case.key, case.label, case.parameters,
                                                 f"{scenario.path.name}: cases[{case.key}].parameters")
                                       for case in group)))
        for line in swap_report(fmu_set):  # once per run, not once per FMU set
            if line not in notes:
                notes.append(line)
    return RunPlan(data, scenario, algorithm, tuple(planned), tuple(notes))
