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

import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from flexarm.parameters import DEFAULT_PARAMETER_FILE
from flexarm.provenance import git_commit, package_version, sha256_file, write_json
from flexarm.signals import names as signal_names
from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE
from scenarios.analysis.stability import loop_stability
from scenarios.config import KINDS, Scenario, ScenarioError, check_inputs_given, check_size
from scenarios.master import cosim as master
from scenarios.master import isolation
from scenarios.master.fmu_files import NotAnFmuError, read_description
from scenarios.master.fmu_proxy import DEFAULT_STEP_TIMEOUT_S
from scenarios.master.values import check_parameters
from scenarios.metrics import METRICS, UNITS, saturation_warnings, table_metrics
from scenarios.results import analysis_columns, portable, write_csv
from scenarios.run.loop_delay import INDEX_NAMES, loop_delay_record, loop_delay_warnings
from scenarios.run.outdir import check_writable, run_folder
from scenarios.run.verdict import judge

REPO = Path(__file__).resolve().parents[2]
#: Where FMUs are built and found: $FLEXARM_FMU_DIR, else ./build/fmus (relative to the current directory, as
#: fmu_build's default), made absolute once so that scenario and sweep files in other folders find the same.
DEFAULT_FMU_DIR = Path(os.environ.get("FLEXARM_FMU_DIR", Path("build") / "fmus")).resolve()
#: Where the native (plain C) FMUs are built and found: $FLEXARM_NATIVE_FMU_DIR, else ./build/fmus-native (as
#: fmu_build.native's default), made absolute once.
DEFAULT_NATIVE_FMU_DIR = Path(os.environ.get("FLEXARM_NATIVE_FMU_DIR", Path("build") / "fmus-native")).resolve()
N_EL = 11
#: The plant's state outputs (theta1..11, omega1..11), from the signal catalogue.
PLANT_STATE = list(signal_names("plant", "output", "state"))
#: Bytes a case's CSV and JSON take per sample (about 150 columns of 20 characters), for the free-space check.
BYTES_PER_SAMPLE = 3000


class DataChainError(ScenarioError):
    """A data file does not match the files it was made from (see :func:`verify_data_chain`)."""


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
    #: The linearised sampled loop's stability (:func:`scenarios.analysis.stability.loop_stability`: the check, or why it
    #: was not made and whether the plant scheme could show a bracket-mode instability anyway).
    loop_stability: dict | None = None
    #: The run's verdict from its own samples (:func:`scenarios.run.verdict.verdict`); None when it did not finish.
    verdict: dict | None = None


def _build_tool():
    """The packaged build tooling (:mod:`fmu_build`), or None where it is not installed."""
    try:
        import fmu_build
    except ImportError:
        return None
    return fmu_build


def known_fmu_names() -> list[str]:
    """The FMU names this project builds (``build_fmus.FMUS``); [] when the build tooling is not importable."""
    tool = _build_tool()
    return sorted(tool.FMUS) if tool is not None else []


def native_fmu_names() -> list[str] | None:
    """The FMU names that have a native build (``fmu_build.native_build.NATIVE_FMUS``); None if unknown here."""
    try:
        from fmu_build.native_build import NATIVE_FMUS
    except ImportError:
        return None
    return list(NATIVE_FMUS)


#: generationTool of a native FMU's model description (fmu_build/native_build.py) starts with this.
NATIVE_GENERATION_TOOL = "flexarm-fmi native build"


def fmu_kind(description) -> str:
    """The kind of an FMU from its description: "native" (our plain C), "python" (pythonfmu) or "other"."""
    tool = description.generationTool or ""
    if tool.startswith(NATIVE_GENERATION_TOOL):
        return "native"
    return "python" if tool.startswith("PythonFMU") else "other"


def refuse_without_native(names: dict[str, str], kind: str) -> None:
    """With kind "native": :class:`ScenarioError` naming an instance whose FMU name has no native build."""
    native = native_fmu_names() if kind == "native" else None
    if native is None:
        return
    for inst, name in names.items():
        if not name.endswith(".fmu") and name not in native:
            raise ScenarioError(f"fmus.{inst}: {name} has no native build (the native FMUs are "
                                f"{', '.join(native)}): run it with the Python FMUs (--python, or "
                                f"kind = \"python\" in [scenario]) or give a path to a .fmu")


def check_kind(scenario: Scenario, kind: str | None = None, controller: str | None = None) -> str:
    """The kind a run of `scenario` uses (`kind`, else the scenario's), after refusing a name of any case
    that has no FMU of that kind; nothing is built (the CLI checks every scenario before the first runs)."""
    kind = kind or scenario.kind
    if kind not in KINDS:
        raise ScenarioError(f"kind: one of {list(KINDS)}, got {kind!r}")
    for case in scenario.cases:
        names = dict(case.fmus or scenario.fmus)
        if controller is not None:
            names["controller"] = controller
        refuse_without_native(names, kind)
    return kind


def resolve_fmus(scenario: Scenario, fmu_dir: Path, controller: str | None = None, build: bool = True,
                 names: dict[str, str] | None = None, kind: str | None = None,
                 native_fmu_dir: Path = DEFAULT_NATIVE_FMU_DIR) -> dict[str, Path]:
    """FMU instance -> .fmu path; names are built (rebuilt when older than their sources).

    `names` (instance -> FMU name or path) defaults to the scenario's ``[fmus]``;
    `controller` replaces the ``controller`` instance's FMU. `kind` (default the scenario's
    ``kind``) says which FMUs a name means: "python" (built into `fmu_dir`) or "native" (built into
    `native_fmu_dir`, with their Python twins in `fmu_dir`, whose interface they copy). An unknown name,
    or with kind "native" a name that has no native build, is refused listing the known ones; a path that
    is no FMU is refused naming the file (all :class:`ScenarioError`). A path to a .fmu is used as it is,
    whatever the kind. Without the build tooling (a non-editable install) names are taken from the
    folder as they are.
    """
    kind = kind or scenario.kind
    if kind not in KINDS:
        raise ScenarioError(f"kind: one of {list(KINDS)}, got {kind!r}")
    names = dict(scenario.fmus if names is None else names)
    if controller is not None:
        names["controller"] = controller
    to_build = sorted({n for n in names.values() if not n.endswith(".fmu")})
    tool = _build_tool() if to_build else None
    known = sorted(tool.FMUS) if tool is not None else []
    for inst, name in names.items():
        if not name.endswith(".fmu") and known and name not in known:
            raise ScenarioError(f"fmus.{inst}: an FMU name of this project {known} or a path to a .fmu file, "
                                f"got {name!r}")
    refuse_without_native(names, kind)
    folder = Path(native_fmu_dir if kind == "native" else fmu_dir)
    given = {inst: _given_path(scenario, name) for inst, name in names.items() if name.endswith(".fmu")}
    for inst, p in given.items():  # a file given by path is checked before minutes of building ours
        if not p.is_file():
            raise ScenarioError(f"fmus.{inst}: no FMU at {p}")
    read_descriptions(given)
    built = {}
    if to_build and build and tool is not None:
        try:
            built = tool.build_all(fmu_dir, only=to_build)
            if kind == "native":
                from fmu_build.native import build_native_all

                built = build_native_all(built, folder, only=to_build)
        except Exception as exc:  # noqa: BLE001 - one line naming what failed, not a traceback
            raise ScenarioError(f"building the {kind} FMUs {to_build} into {folder} failed: {type(exc).__name__}: "
                                f"{exc}") from exc
    paths = {}
    for inst, name in names.items():
        if name.endswith(".fmu"):
            p = given[inst]
        else:
            p = built.get(name, folder / f"{name}.fmu")
        if not p.is_file():
            hint = "" if tool is not None or name.endswith(".fmu") else (
                " (the build tooling build_fmus.py is not installed here: build the FMUs in a checkout and pass "
                "--fmu-dir" + (" / --native-fmu-dir" if kind == "native" else "") + ")")
            what = "FMU" if name.endswith(".fmu") else f"{kind} FMU"
            raise ScenarioError(f"fmus.{inst}: no {what} at {p}{hint}")
        paths[inst] = p
    return paths


def _given_path(scenario: Scenario, name: str) -> Path:
    """A .fmu given by path: as it is when absolute, else relative to the scenario file's folder."""
    return Path(name) if Path(name).is_absolute() else (scenario.path.parent / name)


def read_descriptions(paths: dict[str, Path]) -> dict:
    """Instance -> model description; a file that is no FMU is refused naming the instance and the file."""
    out = {}
    for inst, p in paths.items():
        try:
            out[inst] = read_description(p)
        except NotAnFmuError as exc:
            raise ScenarioError(f"fmus.{inst}: {exc}") from exc
    return out


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
    """Check every data file through flexarm's verifying loaders (:func:`flexarm.data_chain.verify_data_files`:
    parameters, sensor settings, trajectory, gains, LQG designs and bank, every JSON's seal); refuse a mismatch.

    The one function the runner and the sweep call before anything runs; the checks themselves live in
    the loaders, so there is one place for each fact.

    Returns
    -------
    dict
        Every .npz, .json and .toml of flexarm/data (relative to the repository) -> SHA-256, for the results'
        provenance (``data_sha256``).

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
        desired_trajectory()  # the trajectory the run tracks, through the same loader
    except FlexarmDataChainError as exc:
        raise DataChainError(str(exc)) from exc
    except TrajectoryError as exc:
        raise DataChainError(f"data chain: {exc}") from exc
    return chain


def _relative(path: Path) -> str:
    path = Path(path)
    return str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path)


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

    def fmu_kinds(self) -> dict[str, str]:
        """Instance -> kind of the FMU file it runs, from its model description (:func:`fmu_kind`)."""
        return {inst: fmu_kind(md) for inst, md in self.descriptions.items()}

    def open_master(self, algorithm: str | None = None) -> master.Master:
        """Load this set's FMUs once (reuse the master for every case that shares them), stepping with
        `algorithm` (default the scenario's: a sweep point steps as the scenario does)."""
        return master.Master(self.paths, self.scenario.order, self.connections,
                             algorithm or self.scenario.algorithm, self.isolate, self.step_timeout)

    def case_parameters(self, case_parameters: dict[str, dict], where: str = "") -> dict[str, dict]:
        """The case's parameters checked against the FMUs and converted (:func:`scenarios.master.values.check_parameters`),
        with the plant started on the trajectory unless the case says otherwise."""
        case_parameters = {inst: {k: v for k, v in values.items() if k not in self.left_out.get(inst, ())}
                           for inst, values in case_parameters.items()}
        params = check_parameters(where or f"{self.scenario.path.name}: parameters", self.descriptions,
                                  case_parameters)
        params[self.plant] = {**self.start, **params.get(self.plant, {})}
        if self.reference_lead is not None:
            params[REFERENCE_FMU] = {"lead_samples": self.reference_lead, **params.get(REFERENCE_FMU, {})}
        return params


def prepare(scenario: Scenario, fmu_dir: Path = DEFAULT_FMU_DIR, controller: str | None = None,
            names: dict[str, str] | None = None, build: bool = True, kind: str | None = None,
            native_fmu_dir: Path = DEFAULT_NATIVE_FMU_DIR, algorithm: str | None = None) -> Setup:
    """Resolve (and build) the FMUs, read and wire them, and precompute what the cases share.

    `kind` (default the scenario's): "python" or "native", see :func:`resolve_fmus`. `algorithm` (default the
    scenario's): the stepping the FMUs will run in, which sets the reference FMU's lead (:func:`reference_lead`).
    """
    kind = kind or scenario.kind
    paths = resolve_fmus(scenario, fmu_dir, controller, build, names, kind, native_fmu_dir)
    foreign = isolation.foreign_instances(scenario, controller, names)
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
    traj = desired_trajectory()
    n = run_length(scenario, traj)
    seen = [(c.src_fmu, c.src_var) for c in connections if c.dst_fmu == driver and (c.src_fmu, c.src_var) not in record
            and c.src_var not in INDEX_NAMES]  # the sample indices are bookkeeping, not signals
    return Setup(scenario, paths, connections, plant, driver, record, n,
                 desired_states(traj, np.arange(n + 1) * scenario.step_size), start_parameters(traj),
                 descriptions, kind, left_out, held, list(dict.fromkeys(seen)),
                 reference_lead(scenario, descriptions, algorithm or scenario.algorithm), foreign)


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
    has no reference FMU with that parameter. A case's own value wins (:meth:`Setup.case_parameters`)."""
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


def check_overrides(setup: Setup, overrides: dict[str, dict]) -> dict[str, dict]:
    """``--set`` values checked against the FMUs' model descriptions (:func:`scenarios.master.values.check_parameters`)."""
    return check_parameters("--set", setup.descriptions, overrides)


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


def swap_report(setup: Setup) -> list[str]:
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


def numba_compiles(fmu: Path | None = None) -> bool:
    """Whether a Python plant FMU will compile Numba kernels when it steps.

    Numba must be importable and not switched off. Each Python FMU runs its own private copy of ``flexarm``
    (fmu_build.isolate), whose kernels Numba caches once per FMU build in the user's cache folder
    (:mod:`flexarm._numba_cache`); given the FMU file, this is also False when that cache holds its build.
    """
    import importlib.util

    if os.environ.get("FLEXARM_NO_NUMBA") or importlib.util.find_spec("numba") is None:
        return False
    if fmu is None:
        return True
    import zipfile

    from flexarm._numba_cache import cache_root

    try:
        with zipfile.ZipFile(fmu) as z:
            bundled = {n.split("/")[1] for n in z.namelist() if n.startswith("resources/_") and n.count("/") >= 2}
    except (OSError, zipfile.BadZipFile):
        return True
    return bool(bundled) and not any(next((cache_root() / b).glob("*.nbi"), None) for b in bundled)


def _say_numba_compile(fmu: Path | None = None) -> None:
    if numba_compiles(fmu):
        try:
            print("the Python plant FMU compiles its Numba kernels on its first step (about 20 s, once per FMU "
                  "build: then cached; FLEXARM_NO_NUMBA=1 runs NumPy instead)", file=sys.stderr, flush=True)
        except (OSError, ValueError):  # standard error unwritable: no reason to stop a run
            pass


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
