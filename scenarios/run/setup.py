"""A run's setup: the data chain verified, the FMUs wired and checked, what every case of one FMU set shares
(:class:`FmuSetPlan`, frozen, built once by :func:`prepare`; the whole run's plan is :mod:`scenarios.run.plan`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from flexarm.data_chain import relative_path
from flexarm.provenance import sha256_file
from flexarm.signals import names as signal_names
from scenarios.config import Scenario, ScenarioError, check_inputs_given, check_size
from scenarios.master import cosim as master
from scenarios.master import isolation
from scenarios.master.fmu_files import read_description
from scenarios.master.fmu_proxy import DEFAULT_STEP_TIMEOUT_S
from scenarios.master.values import check_parameters
from scenarios.run.fmus import DEFAULT_FMU_DIR, DEFAULT_NATIVE_FMU_DIR, fmu_kind, read_descriptions, resolve_fmus
from scenarios.run.loop_delay import INDEX_NAMES

REPO = Path(__file__).resolve().parents[2]
#: The plant's state outputs (theta1..11, omega1..11), from the signal catalogue.
PLANT_STATE = list(signal_names("plant", "output", "state"))


class DataChainError(ScenarioError):
    """A data file does not match the files it was made from (see :func:`verify_data_chain`)."""


def connect_by_name(paths: dict[str, Path], explicit=None, descriptions: dict | None = None) -> list[master.Connection]:
    """Every input to the one output of the same name elsewhere (or the scenario's explicit list).

    Explicit connections are checked: an output to an input, each input driven once.
    """
    mds = descriptions or read_descriptions(paths)
    if explicit is not None:
        conns = [master.Connection(*a.split("."), *b.split(".")) for a, b in explicit]
        driven: dict[tuple[str, str], str] = {}
        for c in conns:
            edge = f"connections.explicit: {c.src_fmu}.{c.src_var} -> {c.dst_fmu}.{c.dst_var}"
            for inst, var, causality in ((c.src_fmu, c.src_var, "output"), (c.dst_fmu, c.dst_var, "input")):
                have = sorted(v.name for v in mds[inst].modelVariables if v.causality == causality)
                if var not in have:
                    raise ScenarioError(f"{edge}: {inst}.{var} must be an {causality} of {inst} ({have})")
            before = driven.setdefault((c.dst_fmu, c.dst_var), f"{c.src_fmu}.{c.src_var}")
            if before != f"{c.src_fmu}.{c.src_var}" or sum(d == c for d in conns) > 1:
                raise ScenarioError(f"{edge}: input {c.dst_fmu}.{c.dst_var} is already driven by {before}; "
                                    "one input takes one connection")
        return conns
    outputs, inputs = {}, []
    for inst, md in mds.items():
        for v in md.modelVariables:
            if v.causality == "output":
                outputs.setdefault(v.name, []).append(inst)
            elif v.causality == "input":
                inputs.append((inst, v.name))
    conns = []
    for inst, var in inputs:
        src = [s for s in outputs.get(var, []) if s != inst]
        if len(src) > 1:
            raise ScenarioError(f"input {inst}.{var}: outputs of that name in {src}; "
                                "use [connections] explicit = [...]")
        if src:
            conns.append(master.Connection(src[0], var, inst, var))
    return conns


def desired_trajectory():
    """The optimiser's trajectory (1 ms samples) that the controller tracks, through flexarm's loader."""
    from flexarm.trajectory import load_trajectory

    return load_trajectory()


def verify_data_chain() -> dict[str, str]:
    """Check every data file through flexarm's verifying loaders; the SHA-256 of each (:func:`verified_data`)."""
    return verified_data()[0]


def verified_data():
    """Check every data file through flexarm's verifying loaders (:func:`flexarm.data_chain.verify_data_files`:
    parameters, sensor settings, trajectory, gains, LQG designs and bank, every JSON's seal); refuse a mismatch.

    The one function the runner and the sweep call before anything runs; the checks themselves live in
    the loaders, so there is one place for each fact.

    Returns
    -------
    dict
        Every .npz, .json and .toml of flexarm/data (relative to the repository) -> SHA-256, for the results'
        provenance (``data_sha256``).
    TrajectoryResult
        The trajectory the run tracks (:func:`desired_trajectory`), loaded once, through the same loader.

    Raises
    ------
    DataChainError
        The loader's message: both files and the command that regenerates them.
    """
    from flexarm.data_chain import DataChainError as FlexarmDataChainError
    from flexarm.data_chain import verify_data_files
    from flexarm.trajectory import TrajectoryError

    try:
        chain = verify_data_files(REPO)
        traj = desired_trajectory()
    except FlexarmDataChainError as exc:
        raise DataChainError(str(exc)) from exc
    except TrajectoryError as exc:
        raise DataChainError(f"data chain: {exc}") from exc
    return chain, traj


def checkout_relative(path: Path) -> str:
    """`path` as the results name it: relative to the checkout, as the data chain's keys are."""
    return relative_path(path, REPO)


@dataclass(frozen=True)
class FmuSetPlan:
    """What every case of one FMU set shares: FMU paths, wiring, records, run length, desired states, and which
    FMUs run in a process of their own. Frozen: decided once by :func:`prepare` (``dataclasses.replace`` makes
    a variant); its dicts and lists are not to be changed either."""

    scenario: Scenario
    paths: dict[str, Path]
    connections: list[master.Connection]
    plant: str
    driver: str
    record: list[tuple[str, str]]
    n_steps: int
    desired: dict[str, np.ndarray] = field(repr=False)
    start: dict[str, float]
    descriptions: dict = field(default_factory=dict, repr=False)
    #: The kind the names were resolved as ("python" or "native"; see :func:`resolve_fmus`).
    kind: str = "python"
    #: Instance -> scenario parameters its (swapped-in) FMU does not have, left out (:func:`left_out_parameters`).
    left_out: dict[str, list[str]] = field(default_factory=dict)
    #: Instance -> inputs that nothing feeds, held at their declared start values (:func:`unfed_inputs`).
    held_inputs: dict[str, list[str]] = field(default_factory=dict)
    #: The outputs wired into the torques' source (what the controller saw), recorded after :attr:`record`.
    seen: list[tuple[str, str]] = field(default_factory=list)
    #: The reference FMU's ``lead_samples`` for the run's stepping (:func:`reference_lead`), unless a case sets
    #: it; None without a reference FMU that has the parameter.
    reference_lead: int | None = None
    #: Instances run each in a process of their own (:mod:`scenarios.master.fmu_proxy`): by default those given as a
    #: .fmu path (not ours, :func:`scenarios.master.isolation.foreign_instances`); every one with ``--isolate all``.
    isolate: list[str] = field(default_factory=list)
    #: Seconds a call of an isolated FMU may take (``--step-timeout``).
    step_timeout: float = DEFAULT_STEP_TIMEOUT_S
    #: Instance -> kind of the FMU file it runs, from its model description (:func:`scenarios.run.fmus.fmu_kind`).
    fmu_kinds: dict[str, str] = field(default_factory=dict)
    #: Instance -> SHA-256 of its FMU file, for the results' provenance.
    fmu_sha256: dict[str, str] = field(default_factory=dict, repr=False)
    #: The trajectory the desired states and the start come from (loaded once per run, :func:`verified_data`).
    trajectory: object = field(default=None, repr=False, compare=False)

    def open_master(self, algorithm: str | None = None) -> master.Master:
        """Load this set's FMUs once (reuse the master for every case that shares them), stepping with
        `algorithm` (default the scenario's: a sweep point steps as the scenario does)."""
        return master.Master(self.paths, self.scenario.order, self.connections,
                             algorithm or self.scenario.algorithm, self.isolate, self.step_timeout)

    def case_parameters(self, case_parameters: dict[str, dict], where: str = "") -> dict[str, dict]:
        """The case's parameters checked against the FMUs and converted
        (:func:`scenarios.master.values.check_parameters`), with the plant started on the trajectory unless the case
        says otherwise. A run checks each case once, when it is planned (:func:`scenarios.run.plan.plan_case`)."""
        case_parameters = {inst: {k: v for k, v in values.items() if k not in self.left_out.get(inst, ())}
                           for inst, values in case_parameters.items()}
        params = check_parameters(where or f"{self.scenario.path.name}: parameters", self.descriptions,
                                  case_parameters)
        params[self.plant] = {**self.start, **params.get(self.plant, {})}
        if self.reference_lead is not None:
            params[REFERENCE_FMU] = {"lead_samples": self.reference_lead, **params.get(REFERENCE_FMU, {})}
        return params


#: The name tests and docs knew the FMU set's plan by.
Setup = FmuSetPlan


def prepare(scenario: Scenario, fmu_dir: Path = DEFAULT_FMU_DIR, controller: str | None = None,
            names: dict[str, str] | None = None, build: bool = True, kind: str | None = None,
            native_fmu_dir: Path = DEFAULT_NATIVE_FMU_DIR, algorithm: str | None = None, *,
            isolate: str = "foreign", step_timeout: float = DEFAULT_STEP_TIMEOUT_S,
            named_as: dict[str, str] | None = None, trajectory=None) -> FmuSetPlan:
    """Resolve (and build) the FMUs, read and wire them, and precompute what the cases share.

    `kind` (default the scenario's): "python" or "native", see :func:`resolve_fmus`. `algorithm` (default the
    scenario's): the stepping the FMUs will run in, which sets the reference FMU's lead (:func:`reference_lead`).
    `isolate` and `step_timeout`: which FMUs run in a process of their own ("foreign": those named by a .fmu path
    in `named_as`, default `names`, else the scenario's; "all") and how long a call of theirs may take
    (:func:`scenarios.master.isolation.isolated_instances`). `trajectory`: the run's, when already loaded.
    """
    kind = kind or scenario.kind
    paths = resolve_fmus(scenario, fmu_dir, controller, build, names, kind, native_fmu_dir)
    foreign = isolation.foreign_instances(scenario, controller, names if named_as is None else named_as)
    descriptions = read_descriptions(paths)
    scenario, paths, descriptions = with_reference(scenario, paths, descriptions, fmu_dir, build, kind,
                                                   native_fmu_dir)
    connections = connect_by_name(paths, scenario.connections, descriptions)
    check_inputs_given(scenario, {inst: [v.name for v in md.modelVariables if v.causality == "input"]
                                  for inst, md in descriptions.items()},
                       {(c.dst_fmu, c.dst_var) for c in connections})
    held = unfed_inputs(descriptions, connections)
    left_out = left_out_parameters(scenario, descriptions) if controller is not None else {}
    torque_edges = [c for c in connections if c.dst_var == "tau1"]
    if not torque_edges:
        raise ScenarioError("connections: nothing drives an input 'tau1' (the plant's torque)")
    plant, driver = torque_edges[0].dst_fmu, torque_edges[0].src_fmu
    record = [(plant, v) for v in PLANT_STATE + ["tip_x", "tip_y"]] + [(driver, "tau1"), (driver, "tau2")]
    record += [tuple(s.split(".", 1)) for s in scenario.record if tuple(s.split(".", 1)) not in record]
    traj = desired_trajectory() if trajectory is None else trajectory
    n = run_length(scenario, traj)
    seen = [(c.src_fmu, c.src_var) for c in connections if c.dst_fmu == driver and (c.src_fmu, c.src_var) not in record
            and c.src_var not in INDEX_NAMES]  # the sample indices are bookkeeping, not signals
    return FmuSetPlan(scenario, paths, connections, plant, driver, record, n,
                      desired_states(traj, np.arange(n + 1) * scenario.step_size), start_parameters(traj),
                      descriptions, kind, left_out, held, list(dict.fromkeys(seen)),
                      reference_lead(scenario, descriptions, algorithm or scenario.algorithm),
                      isolation.isolated_instances(isolate, paths, foreign), step_timeout,
                      {inst: fmu_kind(md) for inst, md in descriptions.items()},
                      {inst: sha256_file(p) for inst, p in paths.items()}, traj)


#: The FMU name of the reference signals (fmus/reference/), added to a run whose controller asks for them.
REFERENCE_FMU = "reference"


def with_reference(scenario: Scenario, paths: dict[str, Path], descriptions: dict, fmu_dir: Path, build: bool,
                   kind: str, native_fmu_dir: Path) -> tuple[Scenario, dict[str, Path], dict]:
    """Add the reference FMU (instance ``reference``, first in the order) when an FMU has inputs of its names.

    With connections by name, an input named like a reference output (``theta_ref1``, ``q1_ref``, ``tau1_ff``,
    ..., the signal catalogue's fmu "reference") that no FMU of the scenario outputs is fed by the reference
    FMU, of the run's kind. Returns the scenario (a copy with the instance when added), paths and descriptions.
    """
    from dataclasses import replace

    if scenario.connections is not None or REFERENCE_FMU in paths:
        return scenario, paths, descriptions
    offered = set(signal_names("reference", "output"))
    outputs = {v.name for md in descriptions.values() for v in md.modelVariables if v.causality == "output"}
    wanted = sorted({v.name for md in descriptions.values() for v in md.modelVariables
                     if v.causality == "input" and v.name in offered and v.name not in outputs})
    if not wanted:
        return scenario, paths, descriptions
    names = {REFERENCE_FMU: REFERENCE_FMU}
    extra = resolve_fmus(replace(scenario, fmus=names), fmu_dir, None, build, names, kind, native_fmu_dir)
    paths = {REFERENCE_FMU: extra[REFERENCE_FMU], **paths}
    descriptions = {REFERENCE_FMU: read_description(extra[REFERENCE_FMU]), **descriptions}
    return replace(scenario, order=[REFERENCE_FMU, *scenario.order], fmus={REFERENCE_FMU: REFERENCE_FMU,
                                                                          **scenario.fmus}), paths, descriptions


def reference_lead(scenario: Scenario, descriptions: dict, algorithm: str) -> int | None:
    """The reference FMU's ``lead_samples`` for `algorithm` at the scenario's step
    (:func:`flexarm.reference.lead_samples_for`: 0 Gauss-Seidel, the step in samples Jacobi); None when the run
    has no reference FMU with that parameter. A case's own value wins (:meth:`FmuSetPlan.case_parameters`)."""
    from flexarm.reference import lead_samples_for
    from flexarm.trajectory.io import SAMPLE_TIME

    md = descriptions.get(REFERENCE_FMU)
    if md is None or not any(v.name == "lead_samples" for v in md.modelVariables):
        return None
    samples = round(scenario.step_size / SAMPLE_TIME)
    if samples < 1 or abs(scenario.step_size - samples * SAMPLE_TIME) > 1e-9:
        return None  # no whole number of samples: the reference FMU refuses the step itself, naming it
    try:
        return lead_samples_for(algorithm, samples)
    except ValueError as exc:
        raise ScenarioError(f"{scenario.path.name}: the reference FMU's lead_samples: {exc}") from None


def unfed_inputs(descriptions: dict, connections: list[master.Connection]) -> dict[str, list[str]]:
    """Instance -> its inputs that no connection feeds and that declare a start value (held at it).

    Raises
    ------
    ScenarioError
        Naming an input that nothing feeds and that declares no start value (the FMU would run on an
        undefined value).
    """
    fed = {(c.dst_fmu, c.dst_var) for c in connections}
    held: dict[str, list[str]] = {}
    for inst, md in descriptions.items():
        for v in md.modelVariables:
            if v.causality != "input" or (inst, v.name) in fed:
                continue
            if v.start in (None, ""):
                raise ScenarioError(f"input {inst}.{v.name}: nothing feeds it (no output of that name in "
                                    f"{sorted(descriptions)}) and the FMU declares no start value for it; "
                                    "connect it ([connections] explicit) or give it a start value")
            held.setdefault(inst, []).append(v.name)
    return held


def left_out_parameters(scenario: Scenario, descriptions: dict, instance: str = "controller") -> dict[str, list[str]]:
    """{instance: names} of the scenario's parameters for `instance` that its FMU does not have.

    Used when ``--controller`` swaps in another FMU: the scenario's settings of our controllers
    (``gain_set``, ``schedule_period``, ...) mean nothing to it and are left out (the CLI prints them).
    """
    from scenarios.master.values import settable

    if instance not in descriptions:
        return {}
    have = settable(descriptions[instance])
    given = set(scenario.parameters.get(instance, {}))
    for case in scenario.cases:
        given |= set(case.parameters.get(instance, {}))
    missing = sorted(given - set(have))
    return {instance: missing} if missing else {}


def check_overrides(setup: FmuSetPlan, overrides: dict[str, dict]) -> dict[str, dict]:
    """``--set`` values checked against the FMUs' model descriptions
    (:func:`scenarios.master.values.check_parameters`)."""
    return check_parameters("--set", setup.descriptions, overrides)


def with_overrides(scenario: Scenario, overrides: dict[str, dict] | None) -> Scenario:
    """A copy of `scenario` whose every case has `overrides` ({instance: {variable: value}}) applied last."""
    from dataclasses import replace

    if not overrides:
        return scenario
    unknown = sorted(set(overrides) - set(scenario.fmus))
    if unknown:
        raise ScenarioError(f"--set {unknown[0]}.…: an FMU instance of scenario {scenario.name} "
                            f"({', '.join(sorted(scenario.fmus))}), got {unknown[0]!r}")
    cases = [replace(c, parameters={**c.parameters, **{inst: {**c.parameters.get(inst, {}), **values}
                                                       for inst, values in overrides.items()}})
             for c in scenario.cases]
    return replace(scenario, cases=cases)


def swap_report(setup: FmuSetPlan) -> list[str]:
    """Lines naming the scenario parameters a swapped-in FMU does not have (left out), the inputs held at their
    start values, and what the reference FMU feeds."""
    name, lines = setup.scenario.name, []
    for inst, missing in setup.left_out.items():
        lines.append(f"{name}: {inst} {setup.descriptions[inst].modelName} does not have the scenario's {inst} "
                     f"parameter(s) {', '.join(missing)}: left out")
    for inst, held in setup.held_inputs.items():
        lines.append(f"{name}: {inst} input(s) {', '.join(held)} fed by nothing: held at their start values")
    if REFERENCE_FMU in setup.paths:
        fed = sorted({c.dst_fmu for c in setup.connections if c.src_fmu == REFERENCE_FMU})
        lead = "" if setup.reference_lead is None else (
            f", lead_samples = {setup.reference_lead} (the stepping's delay from the reference to the plant)")
        lines.append(f"{name}: {', '.join(fed) or 'nothing'} fed by the reference FMU ({setup.paths[REFERENCE_FMU]})"
                     + lead)
    return lines


def run_length(scenario: Scenario, traj) -> int:
    """Communication steps of a run: the scenario's, or as many as cover the slew ("trajectory"); ScenarioError
    past :data:`scenarios.config.MAX_SAMPLES` unless the run allows it (:func:`scenarios.config.check_size`)."""
    if scenario.samples == "trajectory":
        n = math.ceil(traj.t_f / scenario.step_size - 1e-9)
    else:
        n = int(scenario.samples)
    check_size(scenario, n)
    return n


def start_parameters(traj) -> dict[str, float]:
    """Plant parameters that start the arm at the trajectory's initial joint angles (at rest, undeformed)."""
    from flexarm import joint_angles

    q = joint_angles(traj.theta[0])
    return {"q1_0": float(q[0]), "q2_0": float(q[1])}


def desired_states(traj, times, dt: float | None = None) -> dict[str, np.ndarray]:
    """Desired θ, θ̇ at the given times, by time (not by sample index): the metrics hold for any step.

    Parameters
    ----------
    traj : TrajectoryResult
        Samples ``traj.t`` (s), ``traj.theta``, ``traj.omega`` (n, 11).
    times : ndarray, shape (m,), or int
        Times, s; or a number of samples `m` taken every `dt` seconds from 0.
    dt : float, optional
        With an int `times`: the communication step, s.

    Returns
    -------
    dict
        ``theta``, ``omega``: shape (m, 11). Linear interpolation between the trajectory's samples
        (exact at them); after the slew the final state is held at rest (θ̇ = 0).
    """
    if np.isscalar(times):
        if dt is None:
            raise ValueError("desired_states: dt is required with a number of samples")
        times = np.arange(int(times)) * float(dt)
    t = np.asarray(traj.t, dtype=float)
    times = np.asarray(times, dtype=float)
    theta, omega = np.asarray(traj.theta), np.asarray(traj.omega)
    th = np.column_stack([np.interp(times, t, theta[:, j]) for j in range(theta.shape[1])])
    om = np.column_stack([np.interp(times, t, omega[:, j]) for j in range(omega.shape[1])])
    om[times > t[-1] + 1e-12] = 0.0
    return {"theta": th, "omega": om}
