"""Run a scenario's cases through the master, score them, write results."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from fmpy import read_model_description

from flexarm.parameters import DEFAULT_PARAMETER_FILE
from flexarm.signals import names as signal_names
from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE

from . import master
from .config import Scenario
from .metrics import METRICS, UNITS, table_metrics
from .results import git_commit, sha256_file, write_csv, write_json

REPO = Path(__file__).resolve().parent.parent
DEFAULT_FMU_DIR = REPO / "build" / "fmus"
N_EL = 11
#: The plant's state outputs (theta1..11, omega1..11), from the signal catalogue.
PLANT_STATE = list(signal_names("plant", "output", "state"))


@dataclass
class CaseResult:
    key: str
    label: str
    status: str
    message: str
    metrics: dict[str, float] | None
    wall_time_s: float
    series: dict[str, np.ndarray]


def resolve_fmus(scenario: Scenario, fmu_dir: Path, controller: str | None = None, build: bool = True,
                 names: dict[str, str] | None = None) -> dict[str, Path]:
    """FMU instance -> .fmu path; names are built into `fmu_dir` (rebuilt when older than their sources).

    `names` (instance -> FMU name or path) defaults to the scenario's ``[fmus]``;
    `controller` replaces the ``controller`` instance's FMU.
    """
    names = dict(scenario.fmus if names is None else names)
    if controller is not None:
        names["controller"] = controller
    paths = {}
    to_build = [n for n in names.values() if not n.endswith(".fmu")]
    built = {}
    if to_build and build:
        import fmu_build

        built = fmu_build.build_all(fmu_dir, only=sorted(set(to_build)))
    for inst, name in names.items():
        if name.endswith(".fmu"):
            p = Path(name) if Path(name).is_absolute() else (scenario.path.parent / name)
        else:
            p = built.get(name, fmu_dir / f"{name}.fmu")
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


@dataclass
class Setup:
    """What every case of one FMU set shares: FMU paths, wiring, records, run length, desired states."""

    scenario: Scenario
    paths: dict[str, Path]
    connections: list[master.Connection]
    plant: str
    driver: str
    record: list[tuple[str, str]]
    n_steps: int
    desired: dict[str, np.ndarray]
    start: dict[str, float]

    def open_master(self, algorithm: str = "gauss-seidel") -> master.Master:
        """Load this set's FMUs once (reuse the master for every case that shares them)."""
        return master.Master(self.paths, self.scenario.order, self.connections, algorithm)

    def case_parameters(self, case_parameters: dict[str, dict]) -> dict[str, dict]:
        """The case's parameters, with the plant started on the trajectory unless the case says otherwise."""
        params = {inst: dict(v) for inst, v in case_parameters.items()}
        params[self.plant] = {**self.start, **params.get(self.plant, {})}
        return params


def prepare(scenario: Scenario, fmu_dir: Path = DEFAULT_FMU_DIR, controller: str | None = None,
            names: dict[str, str] | None = None, build: bool = True) -> Setup:
    """Resolve (and build) the FMUs, wire them, and precompute what the cases share."""
    paths = resolve_fmus(scenario, fmu_dir, controller, build, names)
    connections = connect_by_name(paths, scenario.connections)
    torque_edges = [c for c in connections if c.dst_var == "tau1"]
    if not torque_edges:
        raise master.CoSimulationError("connections: nothing drives an input 'tau1' (the plant's torque)")
    plant, driver = torque_edges[0].dst_fmu, torque_edges[0].src_fmu
    record = [(plant, v) for v in PLANT_STATE + ["tip_x", "tip_y"]] + [(driver, "tau1"), (driver, "tau2")]
    record += [tuple(s.split(".", 1)) for s in scenario.record if tuple(s.split(".", 1)) not in record]
    traj = desired_trajectory()
    n = run_length(scenario, traj)
    return Setup(scenario, paths, connections, plant, driver, record, n,
                 desired_states(traj, n + 1, scenario.step_size), start_parameters(traj))


def simulate_case(setup: Setup, m: master.Master, parameters: dict[str, dict],
                  progress=None) -> tuple[dict, dict[str, float] | None]:
    """One run on a loaded master: the master's result and the table metrics (None when unbounded)."""
    out = m.run(setup.case_parameters(parameters), setup.record, setup.n_steps, setup.scenario.step_size,
                progress=progress)
    if out["status"] != "ok":
        return out, None
    sig, p, d = out["signals"], setup.plant, setup.driver
    theta = np.column_stack([sig[f"{p}.theta{i}"] for i in range(1, N_EL + 1)])
    omega = np.column_stack([sig[f"{p}.omega{i}"] for i in range(1, N_EL + 1)])
    tau = np.column_stack([sig[f"{d}.tau1"], sig[f"{d}.tau2"]])
    return out, table_metrics(tau, theta, omega, setup.desired["theta"], setup.desired["omega"])


def run_scenario(scenario: Scenario, out_dir: Path, fmu_dir: Path = DEFAULT_FMU_DIR, controller: str | None = None,
                 progress: bool = True, algorithm: str = "gauss-seidel") -> list[CaseResult]:
    """Run every case; write per-case CSV and JSON into out_dir/<scenario>/.

    Cases with the same FMUs share one loaded master (reset between cases).
    """
    groups: dict[tuple, list] = {}
    for case in scenario.cases:
        groups.setdefault(tuple(sorted(case.fmus.items())) if case.fmus else (), []).append(case)
    by_key: dict[str, CaseResult] = {}
    commit = git_commit()
    traj_hash = sha256_file(DEFAULT_TRAJECTORY_FILE)
    # The arm's parameter file the FMUs bundle (flexarm/data/sandia_arm.toml, the same file).
    param_file = str(DEFAULT_PARAMETER_FILE.relative_to(REPO)) if DEFAULT_PARAMETER_FILE.is_relative_to(REPO) \
        else str(DEFAULT_PARAMETER_FILE)
    param_hash = sha256_file(DEFAULT_PARAMETER_FILE)
    folder = out_dir / scenario.name
    for names, cases in groups.items():
        setup = prepare(scenario, fmu_dir, controller, dict(names) if names else None)
        checksums = {inst: sha256_file(p) for inst, p in setup.paths.items()}
        with setup.open_master(algorithm) as m:
            for case in cases:
                params = setup.case_parameters(case.parameters)
                t0 = time.perf_counter()
                bar = _bar(f"{scenario.name}:{case.key}") if progress else None
                out, metrics = simulate_case(setup, m, case.parameters, progress=bar)
                wall = time.perf_counter() - t0
                series = {"time": out["time"], **out["signals"]}
                by_key[case.key] = CaseResult(case.key, case.label, out["status"], out["message"], metrics, wall,
                                              series)
                write_csv(folder / f"{case.key}.csv", series)
                write_json(folder / f"{case.key}.json", {
                    "scenario": scenario.name, "scenario_file": str(scenario.path),
                    "scenario_sha256": sha256_file(scenario.path), "case": case.key, "label": case.label,
                    "status": out["status"], "message": out["message"], "metrics": metrics,
                    "metric_units": dict(UNITS), "parameters": params, "samples": setup.n_steps,
                    "algorithm": algorithm, "fmus": {k: str(v) for k, v in setup.paths.items()},
                    "fmu_sha256": checksums, "commit": commit, "wall_time_s": wall,
                    "steps_done": out["steps_done"], "trajectory_sha256": traj_hash,
                    "parameter_file": param_file, "parameter_file_sha256": param_hash,
                    "fmu_log_tail": out["log"][-20:],
                })
    return [by_key[c.key] for c in scenario.cases]


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
