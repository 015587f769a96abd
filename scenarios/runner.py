"""Run a scenario's cases through the master, score them, write results."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from fmpy import read_model_description

from . import master
from .config import Scenario
from .metrics import METRICS, table_metrics
from .results import git_commit, sha256_file, write_csv, write_json

REPO = Path(__file__).resolve().parent.parent
DEFAULT_FMU_DIR = REPO / "build" / "fmus"
N_EL = 11
PLANT_STATE = [f"theta{i}" for i in range(1, N_EL + 1)] + [f"omega{i}" for i in range(1, N_EL + 1)]


@dataclass
class CaseResult:
    key: str
    label: str
    status: str
    message: str
    metrics: dict[str, float] | None
    wall_time_s: float
    series: dict[str, np.ndarray]


def resolve_fmus(scenario: Scenario, fmu_dir: Path, controller: str | None = None, build: bool = True) -> dict:
    """FMU instance -> .fmu path; names are built into `fmu_dir` (rebuilt when older than their sources)."""
    names = dict(scenario.fmus)
    if controller is not None:
        names["controller"] = controller
    paths = {}
    to_build = [n for n in names.values() if not n.endswith(".fmu")]
    if to_build and build:
        sys.path.insert(0, str(REPO))
        import build_fmus

        built = build_fmus.build_all(fmu_dir, only=sorted(set(to_build)))
    for inst, name in names.items():
        if name.endswith(".fmu"):
            p = Path(name) if Path(name).is_absolute() else (scenario.path.parent / name)
        else:
            p = built[name] if build else fmu_dir / f"{name}.fmu"
        if not p.is_file():
            raise master.CoSimulationError(f"fmus.{inst}: no FMU at {p}")
        paths[inst] = p
    return paths


def connect_by_name(paths: dict[str, Path], explicit=None) -> list[master.Connection]:
    """Every input to the one output of the same name elsewhere (or the scenario's explicit list)."""
    if explicit is not None:
        return [master.Connection(*a.split("."), *b.split(".")) for a, b in explicit]
    outputs, inputs = {}, []
    for inst, p in paths.items():
        for v in read_model_description(str(p)).modelVariables:
            if v.causality == "output":
                outputs.setdefault(v.name, []).append(inst)
            elif v.causality == "input":
                inputs.append((inst, v.name))
    conns = []
    for inst, var in inputs:
        src = [s for s in outputs.get(var, []) if s != inst]
        if len(src) > 1:
            raise master.CoSimulationError(f"input {inst}.{var}: outputs of that name in {src}; "
                                           "use [connections] explicit = [...]")
        if src:
            conns.append(master.Connection(src[0], var, inst, var))
    return conns


def desired_trajectory():
    """The optimiser's trajectory (1 ms samples) that the controller tracks."""
    from flexarm.trajectory import load_trajectory

    return load_trajectory()


def run_scenario(scenario: Scenario, out_dir: Path, fmu_dir: Path = DEFAULT_FMU_DIR, controller: str | None = None,
                 progress: bool = True) -> list[CaseResult]:
    """Run every case; write per-case CSV and JSON into out_dir/<scenario>/."""
    paths = resolve_fmus(scenario, fmu_dir, controller)
    connections = connect_by_name(paths, scenario.connections)
    plant = next(c.dst_fmu for c in connections if c.dst_var == "tau1")
    driver = next(c.src_fmu for c in connections if c.dst_var == "tau1")
    record = [(plant, v) for v in PLANT_STATE + ["tip_x", "tip_y"]] + [(driver, "tau1"), (driver, "tau2")]
    record += [tuple(s.split(".", 1)) for s in scenario.record if tuple(s.split(".", 1)) not in record]
    traj = desired_trajectory()
    n = run_length(scenario, traj)
    desired = desired_states(traj, n + 1, scenario.step_size)
    start = start_parameters(traj)
    checksums = {inst: sha256_file(p) for inst, p in paths.items()}
    commit = git_commit()
    folder = out_dir / scenario.name
    results = []
    for case in scenario.cases:
        params = {inst: dict(v) for inst, v in case.parameters.items()}
        # The paper's runs start on the trajectory: the plant's initial joint angles
        # come from the trajectory file unless the scenario sets them.
        params[plant] = {**start, **params.get(plant, {})}
        system = master.System(fmus=paths, order=scenario.order, connections=connections,
                               parameters=params, record=record, step_size=scenario.step_size, n_steps=n)
        t0 = time.perf_counter()
        out = master.run(system, progress=_bar(f"{scenario.name}:{case.key}") if progress else None)
        wall = time.perf_counter() - t0
        sig = out["signals"]
        series = {"time": out["time"], **{k: v for k, v in sig.items()}}
        metrics = None
        if out["status"] == "ok":
            theta = np.column_stack([sig[f"{plant}.theta{i}"] for i in range(1, N_EL + 1)])
            omega = np.column_stack([sig[f"{plant}.omega{i}"] for i in range(1, N_EL + 1)])
            tau = np.column_stack([sig[f"{driver}.tau1"], sig[f"{driver}.tau2"]])
            metrics = table_metrics(tau, theta, omega, desired["theta"], desired["omega"])
        results.append(CaseResult(case.key, case.label, out["status"], out["message"], metrics, wall, series))
        write_csv(folder / f"{case.key}.csv", series)
        write_json(folder / f"{case.key}.json", {
            "scenario": scenario.name, "scenario_file": str(scenario.path),
            "scenario_sha256": sha256_file(scenario.path), "case": case.key, "label": case.label,
            "status": out["status"], "message": out["message"], "metrics": metrics,
            "metric_units": {"peak_tau1": "N.m", "peak_tau2": "N.m", "peak_position_error": "deg",
                             "peak_velocity_error": "deg/s", "rms_position_error": "deg",
                             "rms_velocity_error": "deg/s"},
            "parameters": params, "samples": n, "fmus": {k: str(v) for k, v in paths.items()},
            "fmu_sha256": checksums, "commit": commit, "wall_time_s": wall, "steps_done": out["steps_done"],
            "trajectory_sha256": traj_sha(traj), "fmu_log_tail": out["log"][-20:],
        })
    return results


def run_length(scenario: Scenario, traj) -> int:
    """Communication steps of a run: the scenario's, or the slew's length ("trajectory")."""
    return traj.n_samples if scenario.samples == "trajectory" else int(scenario.samples)


def start_parameters(traj) -> dict[str, float]:
    """Plant parameters that start the arm at the trajectory's initial joint angles (at rest, undeformed)."""
    from flexarm import joint_angles

    q = joint_angles(traj.theta[0])
    return {"q1_0": float(q[0]), "q2_0": float(q[1])}


def desired_states(traj, n_samples: int, dt: float) -> dict[str, np.ndarray]:
    """Desired θ, θ̇ at samples 0..n_samples−1 (the final state held after the slew)."""
    theta, omega = np.asarray(traj.theta), np.asarray(traj.omega)
    idx = np.minimum(np.arange(n_samples), len(theta) - 1)
    return {"theta": theta[idx], "omega": omega[idx] * (np.arange(n_samples) < len(theta))[:, None]}


def traj_sha(traj) -> str:
    """SHA-256 of the committed trajectory file the controller FMUs carry."""
    from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE

    return sha256_file(DEFAULT_TRAJECTORY_FILE)


def _bar(label: str):
    """A one-line text progress bar on stderr."""
    state = {"last": -1}

    def update(k: int, n: int) -> None:
        pct = int(100 * k / n)
        if pct != state["last"]:
            state["last"] = pct
            filled = pct // 4
            sys.stderr.write(f"\r{label:28s} [{'#' * filled}{'.' * (25 - filled)}] {pct:3d}%")
            if k == n:
                sys.stderr.write("\n")
            sys.stderr.flush()

    return update


def format_table(results: list[CaseResult], paper: dict | None) -> str:
    """Our metrics beside the paper's, with their ratio (ours / paper)."""
    from .metrics import LABELS

    head = f"{'':32s}" + "".join(f"{r.key:>28s}" for r in results)
    sub = f"{'':32s}" + "".join(f"{'ours':>10s}{'paper':>9s}{'ratio':>9s}" for _ in results)
    lines = [head, sub]
    for i, m in enumerate(METRICS):
        row = f"{LABELS[m]:32s}"
        for r in results:
            p = (paper or {}).get(r.key)
            pv = None if p is None or isinstance(p, dict) else p[i]
            ours = "unbounded" if r.metrics is None else f"{r.metrics[m]:.3f}"
            paper_s = "---" if isinstance(p, dict) else ("" if pv is None else f"{pv:.3f}")
            ratio = f"{r.metrics[m] / pv:.2f}" if r.metrics is not None and pv else ""
            row += f"{ours:>10s}{paper_s:>9s}{ratio:>9s}"
        lines.append(row)
    return "\n".join(lines)
