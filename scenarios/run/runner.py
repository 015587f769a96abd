"""Run a scenario's cases through the master, score them, write results.

Before any case runs (:func:`run_scenario`): the data chain is verified (:func:`verify_data_chain`), every
FMU is resolved and read (an unknown name or a file that is no FMU is refused), every case's values are
checked against the FMUs' model descriptions (:mod:`scenarios.master.values`), the output folder is locked and
checked writable (:mod:`scenarios.run.outdir`), and every case is initialised and stepped once with the
scenario's communication step (:meth:`scenarios.master.cosim.Master.probe`), so a step or a value an FMU refuses
is reported with the FMU's message before anything runs. Each case then ends with one outcome (see
docs/outcomes.md); the results folder is published only when every case has finished.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from flexarm.parameters import DEFAULT_PARAMETER_FILE
from flexarm.provenance import git_commit, package_version, sha256_file, write_json
from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE
from scenarios.analysis.stability import loop_stability
from scenarios.config import Scenario, ScenarioError
from scenarios.master import cosim as master
from scenarios.master import isolation
from scenarios.master.fmu_proxy import DEFAULT_STEP_TIMEOUT_S
from scenarios.metrics import METRICS, UNITS, saturation_warnings, table_metrics
from scenarios.results import analysis_columns, portable, write_csv
from scenarios.run.fmus import DEFAULT_FMU_DIR, DEFAULT_NATIVE_FMU_DIR, _say_numba_compile
from scenarios.run.loop_delay import loop_delay_record, loop_delay_warnings
from scenarios.run.outdir import check_writable, run_folder
from scenarios.run.setup import (
    Setup,
    _relative,
    check_overrides,
    desired_states,
    desired_trajectory,
    prepare,
    swap_report,
    verify_data_chain,
    with_overrides,
)
from scenarios.run.verdict import judge

N_EL = 11
#: Bytes a case's CSV and JSON take per sample (about 150 columns of 20 characters), for the free-space check.
BYTES_PER_SAMPLE = 3000


@dataclass
class CaseResult:
    key: str
    label: str
    status: str
    message: str
    metrics: dict[str, float] | None
    wall_time_s: float
    series: dict[str, np.ndarray]
    outcome: master.Outcome = field(default_factory=lambda: master.Outcome("ok"))
    #: What the run did not do well (e.g. torque saturation, :func:`scenarios.metrics.saturation_warnings`; an
    #: unstable sampled loop the plant scheme cannot show, :func:`scenarios.analysis.stability.loop_stability`).
    warnings: list[str] = field(default_factory=list)
    #: The linearised sampled loop's stability (:func:`scenarios.analysis.stability.loop_stability`: the check, or
    #: why it was not made and whether the plant scheme could show a bracket-mode instability anyway).
    loop_stability: dict | None = None
    #: The run's verdict from its own samples (:func:`scenarios.run.verdict.verdict`); None when it did not finish.
    verdict: dict | None = None


def simulate_case(setup: Setup, m: master.Master, parameters: dict[str, dict],
                  progress=None, divergence_limit: float = 1e4) -> tuple[dict, dict[str, float] | None]:
    """One run on a loaded master: the master's result and the table metrics (None unless the outcome is ok)."""
    delay = loop_delay_record(setup.descriptions, setup.driver)
    out = m.run(setup.case_parameters(parameters), setup.record + setup.seen + delay, setup.n_steps,
                setup.scenario.step_size, divergence_limit, progress=progress)
    out.setdefault("warnings", []).extend(loop_delay_warnings(out, delay))
    if out["status"] != "ok":
        return out, None
    sig, p, d = out["signals"], setup.plant, setup.driver
    theta = np.column_stack([sig[f"{p}.theta{i}"] for i in range(1, N_EL + 1)])
    omega = np.column_stack([sig[f"{p}.omega{i}"] for i in range(1, N_EL + 1)])
    tau = np.column_stack([sig[f"{d}.tau1"], sig[f"{d}.tau2"]])
    desired = setup.desired
    if len(desired["theta"]) != len(theta):  # a master that reports other time points
        desired = desired_states(desired_trajectory(), out["time"])
    from flexarm.parameters import load_parameters

    out.setdefault("warnings", []).extend(saturation_warnings(tau, load_parameters().peak_torque))
    return out, table_metrics(tau, theta, omega, desired["theta"], desired["omega"])


class StepRefused(ScenarioError):
    """An FMU refused a case's values or the communication step when probed, before anything ran."""


def probe_cases(setup: Setup, m: master.Master, cases) -> None:
    """Initialise and step once per case (:meth:`master.Master.probe`); :class:`StepRefused` with the FMU's message."""
    for case in cases:
        outcome = m.probe(setup.case_parameters(case.parameters), setup.scenario.step_size)
        if outcome.status == "error":
            raise StepRefused(f"{setup.scenario.path.name}: case {case.key}, communication step "
                              f"{setup.scenario.step_size:g} s: refused by {outcome.fmu} ({outcome.function} "
                              f"returned {outcome.fmu_status}): {outcome.fmu_message or outcome.message}")


def run_scenario(scenario: Scenario, out_dir: Path, fmu_dir: Path = DEFAULT_FMU_DIR, controller: str | None = None,
                 progress: bool = True, algorithm: str | None = None, plots: bool = False, kind: str | None = None,
                 native_fmu_dir: Path = DEFAULT_NATIVE_FMU_DIR,
                 overrides: dict[str, dict] | None = None, divergence_limit: float = 1e4,
                 isolate: str = "foreign", step_timeout: float = DEFAULT_STEP_TIMEOUT_S) -> list[CaseResult]:
    """Check everything, then run every case; publish per-case CSV and JSON (and PNGs) in out_dir/<scenario>/.

    Cases with the same FMUs share one loaded master (reset between cases). ``algorithm`` None: the
    scenario file's (``scenario.algorithm``, default Gauss-Seidel). ``kind`` None: the scenario file's
    (``scenario.kind``, default "python"); "native" runs the plain-C FMUs (:func:`resolve_fmus`). Every refusal
    (:class:`ScenarioError`, :class:`scenarios.run.outdir.OutputError`) comes before the first case runs; on
    Ctrl-C (:class:`scenarios.master.cosim.RunInterrupted`) or a filesystem error nothing is published and the
    previous results stay as they were.

    ``controller`` (a name or a .fmu path, see :func:`resolve_fmus`) replaces the scenario's controller: the
    scenario's controller parameters it does not have are left out (one printed line names them), and it is
    fed the reference FMU's outputs when it has inputs of their names (:func:`with_reference`).
    ``overrides`` ({instance: {variable: value}}, the CLI's ``--set``) are checked against the FMUs' model
    descriptions like scenario values and applied to every case after the scenario's own.
    ``divergence_limit``: a recorded |value| above it ends a case as "unbounded" (:meth:`master.Master.run`).
    ``isolate`` and ``step_timeout``: which FMUs run in a process of their own, and how long a call of theirs
    may take (:func:`scenarios.master.isolation.apply`).
    """
    algorithm = algorithm or scenario.algorithm
    scenario = with_overrides(scenario, overrides)
    chain = verify_data_chain()
    by_key: dict[str, CaseResult] = {}
    commit = git_commit()
    scenario_sha = sha256_file(scenario.path)
    from flexarm.reference import ReferenceSignals

    reference = ReferenceSignals(desired_trajectory())  # the CSV's ref.* columns (scenarios/results.py)
    with run_folder(out_dir, scenario.name) as folder:  # locked and writable before FMUs are built
        groups: dict[tuple, list] = {}
        reported: list[str] = []
        for case in scenario.cases:
            groups.setdefault(tuple(sorted(case.fmus.items())) if case.fmus else (), []).append(case)
        setups = []
        for names, cases in groups.items():
            setup = prepare(scenario, fmu_dir, controller, dict(names) if names else None, kind=kind,
                            native_fmu_dir=native_fmu_dir, algorithm=algorithm)
            isolation.apply(setup, isolate, step_timeout)
            check_overrides(setup, overrides or {})
            for case in cases:
                setup.case_parameters(case.parameters, f"{scenario.path.name}: cases[{case.key}].parameters")
            setups.append((setup, cases))
            for line in swap_report(setup):  # once per run, not once per FMU set
                if line not in reported:
                    reported.append(line)
                    print(line)
        check_writable(folder, sum(BYTES_PER_SAMPLE * (s.n_steps + 1) * len(c) for s, c in setups))
        if progress:  # a Python plant FMU whose build has no kernels cached yet compiles them on its first step
            for plant in dict.fromkeys(s.paths[s.plant] for s, _ in setups):
                _say_numba_compile(plant)
        opened = []
        try:
            for setup, cases in setups:  # every case probed before the first one runs
                opened.append(setup.open_master(algorithm))
                probe_cases(setup, opened[-1], cases)
            for (setup, cases), m in zip(setups, opened):
                checksums = {inst: sha256_file(p) for inst, p in setup.paths.items()}
                kinds = setup.fmu_kinds()
                for case in cases:
                    params = setup.case_parameters(case.parameters)
                    t0 = time.perf_counter()
                    bar = _bar(f"{scenario.name}:{case.key}") if progress else None
                    out, metrics = simulate_case(setup, m, case.parameters, progress=bar,
                                                 divergence_limit=divergence_limit)
                    wall = time.perf_counter() - t0
                    series = {"time": out["time"], **out["signals"]}
                    stab = loop_stability(setup.paths, setup.plant, setup.driver, params, scenario.step_size,
                                          setup.n_steps * scenario.step_size, algorithm, metrics=metrics)
                    notes = list(out.get("warnings", [])) + ([stab["note"]] if stab and stab["note"] else [])
                    series.update(analysis_columns(series, setup.plant, reference))
                    status, message, judged = judge(out, series, setup.driver)  # scenarios/run/verdict.py
                    by_key[case.key] = CaseResult(case.key, case.label, status, message, metrics,
                                                  wall, series, out["outcome"], notes, stab, judged)
                    write_csv(folder / f"{case.key}.csv", series)
                    write_json(folder / f"{case.key}.json", portable({
                        "scenario": scenario.name, "scenario_file": str(scenario.path),
                        "scenario_sha256": scenario_sha, "case": case.key, "label": case.label,
                        "status": status, "message": message, "outcome": out["outcome"].as_dict(),
                        "verdict": judged,
                        "warnings": by_key[case.key].warnings,
                        "metrics": metrics, "metric_units": dict(UNITS), "parameters": params,
                        "samples": setup.n_steps, "step_size_s": scenario.step_size, "algorithm": algorithm,
                        "fmus": {k: str(v) for k, v in setup.paths.items()}, "fmu_sha256": checksums,
                        "fmu_kind": setup.kind, "fmu_kinds": kinds, "parameters_left_out": setup.left_out,
                        "inputs_held_at_start": setup.held_inputs, "overrides": overrides or {},
                        "commit": commit, "version": package_version(), "wall_time_s": wall,
                        "steps_done": out["steps_done"],
                        "trajectory_sha256": chain[_relative(DEFAULT_TRAJECTORY_FILE)],
                        "parameter_file": _relative(DEFAULT_PARAMETER_FILE),
                        "parameter_file_sha256": chain[_relative(DEFAULT_PARAMETER_FILE)],
                        "data_sha256": chain, "fmu_log_tail": out["log"][-20:], "loop_stability": stab,
                    }, folder))
        finally:
            for m in opened:
                m.close()
        results = [by_key[c.key] for c in scenario.cases]
        if plots:
            from scenarios.run.plots import plot_scenario

            traj = desired_trajectory()
            setup = setups[0][0]
            plot_scenario(scenario.name, results, setup.desired, traj, setup.plant, setup.driver, folder)
    return results


def _bar(label: str, stream=None):
    """Progress of one case on stderr: a redrawn bar on a terminal; otherwise (a log, a pipe) one line when
    the case is under way (its first report), with no carriage-return frames."""
    stream = sys.stderr if stream is None else stream
    tty = hasattr(stream, "isatty") and stream.isatty()
    state = {"last": -1}

    def update(k: int, n: int) -> None:
        pct = int(100 * k / n)
        if pct == state["last"]:
            return
        first, state["last"] = state["last"] == -1, pct
        if tty:
            filled = pct // 4
            text = f"\r{label:28s} [{'#' * filled}{'.' * (25 - filled)}] {pct:3d}%" + ("\n" if k == n else "")
        elif first:
            text = f"{label:28s} running, {n} steps\n"
        else:
            return
        try:  # a progress line standard error cannot take (2>/dev/full) is no reason to stop a run
            stream.write(text)
            stream.flush()
        except (OSError, ValueError):
            pass

    return update


#: Cases per block of the printed table (4 fit a 150-column terminal; more cases continue below).
CASES_PER_BLOCK = 4


def format_table(results: list[CaseResult], paper: dict | None) -> str:
    """Our metrics beside the paper's, with their ratio (ours / paper); blocks of :data:`CASES_PER_BLOCK`
    cases, separated by a blank line."""
    from scenarios.metrics import LABELS

    blocks = []
    for start in range(0, len(results), CASES_PER_BLOCK):
        chunk = results[start:start + CASES_PER_BLOCK]
        head = f"{'':32s}" + "".join(f"{r.key + ('' if r.status == 'ok' else f' [{r.status}]'):>28s}" for r in chunk)
        sub = f"{'':32s}" + "".join(f"{'ours':>10s}{'paper':>9s}{'ratio':>9s}" for _ in chunk)
        lines = [head, sub]
        for i, m in enumerate(METRICS):
            row = f"{LABELS[m]:32s}"
            for r in chunk:
                p = (paper or {}).get(r.key)
                pv = None if p is None or isinstance(p, dict) else p[i]
                ours = r.status if r.metrics is None else f"{r.metrics[m]:.3f}"
                paper_s = "---" if isinstance(p, dict) else ("" if pv is None else f"{pv:.3f}")
                ratio = f"{r.metrics[m] / pv:.2f}" if r.metrics is not None and pv else ""
                row += f"{ours:>10s}{paper_s:>9s}{ratio:>9s}"
            lines.append(row)
        blocks.append("\n".join(lines))
    return "\n\n".join(blocks)
