"""Run a scenario: plan, connect, run, judge, write (docs/architecture.md, "A scenario run, stage by stage").

Before any case runs (:func:`run_scenario`): the data chain is verified and the trajectory loaded once
(:func:`scenarios.run.plan.read_run_data`), the output folder is locked and checked writable
(:mod:`scenarios.run.outdir`), every FMU is resolved and read (an unknown name or a file that is no FMU is refused)
and every case's values are checked once against the FMUs' model descriptions (:func:`scenarios.run.plan.plan_run`,
:mod:`scenarios.master.values`), and every case is initialised and stepped once with the scenario's communication
step (:mod:`scenarios.run.connect`), so a step or a value an FMU refuses is reported with the FMU's message before
anything runs. Each case then runs here (:func:`simulate`), is judged (:func:`scenarios.run.verdict.judge_case`)
and written (:mod:`scenarios.run.write`); it ends with one outcome (see docs/outcomes.md); the results folder is
published only when every case has finished.
"""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path

import numpy as np

from fmu_build.progress import heartbeat
from scenarios.config import Scenario
from scenarios.master import cosim as master
from scenarios.master.fmu_proxy import DEFAULT_STEP_TIMEOUT_S
from scenarios.metrics import METRICS, saturation_warnings, table_metrics
from scenarios.run.connect import StepRefused, connected, probe_cases
from scenarios.run.fmus import DEFAULT_FMU_DIR, DEFAULT_NATIVE_FMU_DIR, _say_numba_compile
from scenarios.run.loop_delay import loop_delay_record, loop_delay_warnings, slew_start, slew_start_record
from scenarios.run.outdir import check_writable, run_folder
from scenarios.run.plan import PlannedCase, RunPlan, plan_run, read_run_data
from scenarios.run.setup import FmuSetPlan, desired_states, desired_trajectory, prepare, verify_data_chain
from scenarios.run.verdict import CaseResult, judge_case
from scenarios.run.write import write_case, write_figures

#: prepare and verify_data_chain (scenarios.run.setup) are named here as well: callers import them from the runner.
__all__ = ["CaseResult", "StepRefused", "format_table", "prepare", "probe_cases", "run_case", "run_scenario",
           "simulate", "simulate_case", "verify_data_chain"]

N_EL = 11
#: Bytes a case's CSV and JSON take per sample (about 150 columns of 20 characters), for the free-space check.
BYTES_PER_SAMPLE = 3000


def simulate(setup: FmuSetPlan, m: master.Master, parameters, progress=None,
             divergence_limit: float = 1e4) -> tuple[dict, dict[str, float] | None]:
    """One run on a loaded master with checked `parameters` (a planned case's,
    :attr:`scenarios.run.plan.PlannedCase.parameters`): the master's result and the table metrics (None unless
    the outcome is ok)."""
    delay = loop_delay_record(setup.descriptions, setup.driver)
    start_record = slew_start_record(setup.descriptions, setup.driver)
    out = m.run(parameters, setup.record + setup.seen + delay + start_record, setup.n_steps,
                setup.scenario.step_size, divergence_limit, progress=progress)
    out.setdefault("warnings", []).extend(loop_delay_warnings(out, delay))
    try:
        start = slew_start(out, start_record)
    except ValueError as exc:  # a controller that says no sample: which slew it ran is unknown, so no figures
        if out["status"] == "ok":
            out["outcome"] = master.Outcome("error", f"{setup.driver}: {exc}; the errors cannot be judged against "
                                            "a slew whose start the controller does not give")
            out["status"], out["message"] = "error", out["outcome"].message
        return out, None
    if out["status"] != "ok":
        return out, None
    sig, p, d = out["signals"], setup.plant, setup.driver
    theta = np.column_stack([sig[f"{p}.theta{i}"] for i in range(1, N_EL + 1)])
    omega = np.column_stack([sig[f"{p}.omega{i}"] for i in range(1, N_EL + 1)])
    tau = np.column_stack([sig[f"{d}.tau1"], sig[f"{d}.tau2"]])
    desired = setup.desired
    if len(desired["theta"]) != len(theta) or start:  # other time points, or the slew started late
        traj = setup.trajectory if setup.trajectory is not None else desired_trajectory()
        desired = desired_states(traj, out["time"] - start * setup.scenario.step_size)
    if start:
        late = start * setup.scenario.step_size
        out["warnings"].append(f"{d} started the slew {start} sample(s) late, at t = {late:g} s (slew_start_index): "
                               "the master exchanged nothing before its first step, so the plant held no torque "
                               "over it; the errors compare the arm with the slew from then")
    from flexarm.parameters import load_parameters

    out.setdefault("warnings", []).extend(saturation_warnings(tau, load_parameters().peak_torque))
    return out, table_metrics(tau, theta, omega, desired["theta"], desired["omega"])


def simulate_case(setup: FmuSetPlan, m: master.Master, parameters: dict[str, dict],
                  progress=None, divergence_limit: float = 1e4) -> tuple[dict, dict[str, float] | None]:
    """:func:`simulate` with a case's values as the scenario file gives them (checked here first)."""
    return simulate(setup, m, setup.case_parameters(parameters), progress, divergence_limit)


def run_case(plan: RunPlan, case: PlannedCase, m: master.Master, progress: bool = True,
             divergence_limit: float = 1e4) -> tuple[CaseResult, dict]:
    """The run and judge stages of one planned case on its loaded master: its :class:`CaseResult` and the
    master's result (which the write stage records)."""
    t0 = time.perf_counter()
    bar = _bar(f"{plan.scenario.name}:{case.key}") if progress else None
    out, metrics = simulate(case.fmu_set, m, case.parameters, progress=bar, divergence_limit=divergence_limit)
    wall = time.perf_counter() - t0
    return judge_case(case, out, metrics, wall, plan.algorithm, plan.data.reference), out


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
    may take (:func:`scenarios.master.isolation.isolated_instances`).
    """
    data = read_run_data(scenario, overrides)  # refused data leaves no results folder behind
    with run_folder(out_dir, data.scenario.name) as folder:  # locked and writable before FMUs are built
        plan = plan_run(scenario, fmu_dir=fmu_dir, controller=controller, kind=kind, native_fmu_dir=native_fmu_dir,
                        algorithm=algorithm, overrides=overrides, isolate=isolate, step_timeout=step_timeout,
                        data=data)
        for line in plan.notes:
            print(line)
        check_writable(folder, sum(BYTES_PER_SAMPLE * (fs.n_steps + 1) * len(cases) for fs, cases in plan.groups))
        compiling = False
        if progress:  # a Python plant FMU whose build has no kernels cached yet compiles them on its first step
            for plant in dict.fromkeys(fs.paths[fs.plant] for fs, _ in plan.groups):
                compiling = _say_numba_compile(plant) or compiling
        by_key: dict[str, CaseResult] = {}
        with contextlib.ExitStack() as first_case:
            if compiling:  # a sign of life until the first case has run (issue 34: no silence over 10 s)
                first_case.enter_context(heartbeat("the Numba compile", prefix=""))
            with connected(plan) as masters:  # every case probed before the first one runs
                for _, cases, m in masters:
                    for case in cases:
                        by_key[case.key], out = run_case(plan, case, m, progress, divergence_limit)
                        first_case.close()
                        write_case(folder, plan, case, by_key[case.key], out)
        results = [by_key[c.key] for c in plan.scenario.cases]
        if plots:
            write_figures(folder, plan, results)
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
