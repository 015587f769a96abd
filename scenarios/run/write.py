"""The write stage of a run: each judged case's CSV and JSON, and the scenario's figures, in the staging folder
that :func:`scenarios.run.outdir.run_folder` publishes when every case is done."""

from __future__ import annotations

from pathlib import Path

from flexarm.parameters import DEFAULT_PARAMETER_FILE
from flexarm.provenance import write_json
from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE
from scenarios.metrics import UNITS
from scenarios.results import portable, write_csv
from scenarios.run.setup import checkout_relative

#: The trajectory and the parameter file, as the results name them (relative to the checkout).
TRAJECTORY_FILE, PARAMETER_FILE = checkout_relative(DEFAULT_TRAJECTORY_FILE), checkout_relative(
    DEFAULT_PARAMETER_FILE)


def write_case(folder: Path, plan, case, result, out: dict) -> None:
    """``<key>.csv`` (the judged series) and ``<key>.json`` (status, verdict, metrics and the run's provenance)
    of a planned case (:class:`scenarios.run.plan.PlannedCase`) of `plan` (:class:`scenarios.run.plan.RunPlan`);
    `result` is its :class:`scenarios.run.verdict.CaseResult`, `out` the master's result."""
    scenario, data, fs = plan.scenario, plan.data, case.fmu_set
    chain = data.data_sha256
    write_csv(folder / f"{case.key}.csv", result.series)
    write_json(folder / f"{case.key}.json", portable({
        "scenario": scenario.name, "scenario_file": str(scenario.path),
        "scenario_sha256": data.scenario_sha256, "case": case.key, "label": case.label,
        "status": result.status, "message": result.message, "outcome": out["outcome"].as_dict(),
        "verdict": result.verdict,
        "warnings": result.warnings,
        "metrics": result.metrics, "metric_units": dict(UNITS), "parameters": case.parameters,
        "samples": fs.n_steps, "step_size_s": scenario.step_size, "algorithm": plan.algorithm,
        "fmus": {k: str(v) for k, v in fs.paths.items()}, "fmu_sha256": fs.fmu_sha256,
        "fmu_kind": fs.kind, "fmu_kinds": fs.fmu_kinds, "parameters_left_out": fs.left_out,
        "inputs_held_at_start": fs.held_inputs, "overrides": data.overrides,
        "commit": data.commit, "version": data.version, "wall_time_s": result.wall_time_s,
        "steps_done": out["steps_done"],
        "trajectory_sha256": chain[TRAJECTORY_FILE],
        "parameter_file": PARAMETER_FILE,
        "parameter_file_sha256": chain[PARAMETER_FILE],
        "data_sha256": chain, "fmu_log_tail": out["log"][-20:], "loop_stability": result.loop_stability,
    }, folder))


def write_figures(folder: Path, plan, results: list) -> None:
    """The scenario's PNG figures (:func:`scenarios.run.plots.plot_scenario`), against the first FMU set's
    desired states and the plan's trajectory."""
    from scenarios.run.plots import plot_scenario

    fs = plan.groups[0][0]
    plot_scenario(plan.scenario.name, results, fs.desired, plan.data.trajectory, fs.plant, fs.driver, folder)
