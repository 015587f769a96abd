"""The FMI masters of the conformance matrix, each run on one exported case archive as it is.

Every function takes a case's SSP archive (``python -m scenarios export-ssp``) and returns a :class:`Trace`
of the plant's element angles and rates and the torques at every communication point, so that each master is
judged by the same metrics (:func:`scenarios.conformance.matrix.figures`). Nothing is set on the FMUs: the archive's
baked values are the case.

* :func:`run_ours` - our master (:mod:`scenarios.master.cosim`), Gauss-Seidel or Jacobi;
* :func:`run_libcosim` - libcosim (Open Simulation Platform), Jacobi;
* :func:`run_ecos` - Ecos (``ecospy``), Jacobi;
* :func:`run_simulate_ssp` - fmpy's ``simulate_ssp``: Jacobi, nothing exchanged before its first step (every
  connected input is 0 over [0, h));
* :func:`run_oms_semantics` - a host stepping as OMSimulator's fixed-step master does (OMSimulator installs from
  no registry here): Gauss-Seidel in the SSD's connection order, no exchange in initialisation mode, the stop time
  reached by ``t += h`` in doubles with a last step of the rounding remainder;
* :func:`run_omsimulator` - OMSimulator itself (its command-line tool, built from source: ``$FLEXARM_OMSIMULATOR``
  or ``OMSimulator`` on the PATH), where it is installed;
* :func:`run_hostile` - :class:`HostileHost`: reads every output twice around every single set, sets inputs one
  by one in a seeded random order, three exchange rounds in initialisation mode;
* :func:`run_simulate_fmu` - fmpy's ``simulate_fmu`` on the plant alone, driven by given torques.
"""

from __future__ import annotations

import csv
import io
import os
import shutil
import subprocess
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenarios.conformance.ssp import NS

#: The plant's recorded state: element angles (rad) then rates (rad/s).
STATE = [f"theta{i}" for i in range(1, 12)] + [f"omega{i}" for i in range(1, 12)]


@dataclass(frozen=True)
class Trace:
    """A run as every master reports it.

    Attributes
    ----------
    time : ndarray, shape (n + 1,)
        Communication points, s (sample 0 after initialisation).
    theta, omega : ndarray, shape (n + 1, 11)
        The plant's element angles (rad) and rates (rad/s).
    tau : ndarray, shape (n + 1, 2)
        The torques the plant received, N·m.
    """

    time: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    tau: np.ndarray


def _trace(time, rows) -> Trace:
    """`rows`: (n + 1, 24) of STATE then tau1, tau2."""
    z = np.asarray(rows, dtype=float)
    return Trace(np.asarray(time, dtype=float), z[:, :11], z[:, 11:22], z[:, 22:24])


def _from_signals(time, signals: dict, plant: str = "plant", driver: str = "controller") -> Trace:
    cols = [signals[f"{plant}.{v}"] for v in STATE] + [signals[f"{driver}.tau1"], signals[f"{driver}.tau2"]]
    return _trace(time, np.column_stack(cols))


def experiment(ssp: Path) -> tuple[int, float]:
    """(communication steps, step size in s) of an archive: the DefaultExperiment's stop time over the fixed step
    its SSD names for libcosim (``osp:FixedStepAlgorithm``, the same as OMSimulator's, see
    scenarios.conformance.ssp)."""
    from lxml import etree

    doc = etree.parse(io.BytesIO(zipfile.ZipFile(ssp).read("SystemStructure.ssd")))
    exp = doc.find("ssd:DefaultExperiment", NS)
    algo = exp.find("ssd:Annotations/ssc:Annotation/osp:Algorithm/osp:FixedStepAlgorithm", NS)
    h = float(algo.get("baseStepSize"))
    return round(float(exp.get("stopTime")) / h), h


def extract_fmus(ssp: Path, folder: Path) -> dict[str, str]:
    """An archive's FMUs as files (instance -> path), so that every master runs exactly the same binaries."""
    from lxml import etree

    folder.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(ssp) as zf:
        doc = etree.parse(io.BytesIO(zf.read("SystemStructure.ssd")))
        names = {}
        for comp in doc.iterfind("ssd:System/ssd:Elements/ssd:Component", NS):
            target = folder / comp.get("source").split("/")[-1]
            target.write_bytes(zf.read(comp.get("source")))
            names[comp.get("name")] = str(target)
    return names


def _setup(scenario, ssp: Path, folder: Path, kind: str):
    from scenarios.run.setup import prepare

    return prepare(scenario, names=extract_fmus(ssp, folder), build=False, kind=kind)


def run_ours(ssp: Path, scenario, kind: str, algorithm: str, folder: Path) -> Trace:
    """Our master on the archive's FMUs, nothing set, stepping `algorithm` ("gauss-seidel" or "jacobi")."""
    setup = _setup(scenario, ssp, folder, kind)
    n, h = experiment(ssp)
    with setup.open_master(algorithm) as m:
        out = m.run({}, setup.record, n, h)
    if out["status"] != "ok":
        raise RuntimeError(f"our master ({algorithm}): {out['status']}: {out['message']}")
    return _from_signals(out["time"], out["signals"], setup.plant, setup.driver)


def run_hostile(ssp: Path, scenario, kind: str, algorithm: str, folder: Path, seed: int = 0) -> Trace:
    """:class:`HostileHost` on the archive's FMUs, stepping `algorithm`, three initialisation rounds."""
    setup = _setup(scenario, ssp, folder, kind)
    n, h = experiment(ssp)
    out = HostileHost(setup, algorithm, init_rounds=3, seed=seed).run({}, setup.record, n, h)
    return _from_signals(out["time"], out["signals"], setup.plant, setup.driver)


def run_libcosim(ssp: Path) -> Trace:
    from scenarios.conformance.libcosim_runner import run_case_libcosim

    out = run_case_libcosim(ssp)
    return _from_signals(out["time"], out["signals"])


def run_simulate_ssp(ssp: Path) -> Trace:
    """fmpy's simulate_ssp with no parameter set: its row k holds the values after step k (time t_k + h).

    It exchanges nothing before its first step, so our controllers start the slew one sample later
    (``slew_start_index`` 2, docs/control.md "The slew starts when the loop is live"): the trace's time is the
    slew's, t − (slew_start_index − 1) h, which the figures compare with the trajectory."""
    from fmpy.ssp.simulation import simulate_ssp

    n, h = experiment(ssp)
    result = simulate_ssp(str(ssp), stop_time=n * h - h / 2, step_size=h)
    cols = [result[f"plant.{v}"] for v in STATE] + [result["controller.tau1"], result["controller.tau2"]]
    return _trace(np.asarray(result["time"]) + h - slew_start(result, "controller.slew_start_index", h),
                  np.column_stack(cols))


def slew_start(result, column: str, h: float) -> float:
    """The time (s) at which a run's controller started the slew, from its ``slew_start_index`` output (its last
    value: fixed at the first step); 0 for a controller without that output (a stranger's)."""
    from flexarm.loop_index import slew_start_samples

    if column not in result.dtype.names:
        return 0.0
    return slew_start_samples(float(np.asarray(result[column])[-1])) * h


def run_ecos(ssp: Path) -> Trace:
    """Ecos (ecospy) from the archive, fixed step: the values after initialisation, then after every step."""
    import ecospy

    n, h = experiment(ssp)
    ids = [f"plant::{v}" for v in STATE] + ["controller::tau1", "controller::tau2"]
    rows, times = [], []
    with ecospy.EcosSimulation(step_size=h, ssp_path=str(ssp)) as sim:
        if not sim.init():
            raise RuntimeError(f"Ecos: init failed: {ecospy.EcosLib.get_last_error()}")
        for k in range(n + 1):
            times.append(sim.get_time())
            rows.append([sim.get_real(i) for i in ids])
            if k < n:
                sim.step(1)
        sim.terminate()
    return _trace(times, rows)


def _slave(fmu: Path, name: str, folder: Path, messages: list[str]):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    from scenarios.master.fmi_callbacks import logging_callbacks

    md = read_model_description(str(fmu))
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu), unzipdir=str(folder / name)),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    slave.instantiate(callbacks=logging_callbacks(
        lambda c, i, status, cat, msg: messages.append(f"{name}: {msg.decode(errors='replace')}")
        if status > 1 else None))
    return slave, md


def run_oms_semantics(ssp: Path, folder: Path) -> Trace:
    """OMSimulator's fixed-step master ("oms-ma") as a host of ours, on the archive as it is (module docstring)."""
    from lxml import etree

    doc = etree.parse(io.BytesIO(zipfile.ZipFile(ssp).read("SystemStructure.ssd")))
    stop = float(doc.find("ssd:DefaultExperiment", NS).get("stopTime"))
    fixed = doc.find("ssd:System/ssd:Annotations/ssc:Annotation/oms:Annotations/oms:SimulationInformation/"
                     "oms:FixedStepMaster", NS)
    if fixed is None:
        raise RuntimeError("the SSD names no OMSimulator master (oms:FixedStepMaster)")
    h = float(fixed.get("stepSize"))
    names = extract_fmus(ssp, folder / "fmus")
    messages: list[str] = []
    slaves, vrs = {}, {}
    try:
        for comp in doc.iterfind("ssd:System/ssd:Elements/ssd:Component", NS):
            name = comp.get("name")
            slaves[name], md = _slave(Path(names[name]), name, folder, messages)
            vrs[name] = {v.name: v.valueReference for v in md.modelVariables}
        conns = [(c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
                 for c in doc.iterfind("ssd:System/ssd:Connections/ssd:Connection", NS)]
        for s in slaves.values():
            s.setupExperiment(startTime=0.0, stopTime=stop)
            s.enterInitializationMode()
            s.exitInitializationMode()
        state = [vrs["plant"][v] for v in STATE]
        torques = [vrs["controller"]["tau1"], vrs["controller"]["tau2"]]
        rows, times, t = [], [], 0.0
        while True:
            for a, av, b, bv in conns:
                slaves[b].setReal([vrs[b][bv]], slaves[a].getReal([vrs[a][av]]))
            times.append(t)
            rows.append(slaves["plant"].getReal(state) + slaves["controller"].getReal(torques))
            if not t < stop:
                break
            step = min(h, stop - t)
            for name, s in slaves.items():
                try:
                    s.doStep(currentCommunicationPoint=t, communicationStepSize=step)
                except Exception as exc:
                    raise RuntimeError(f"{name}: fmi2DoStep(t = {t!r}, h = {step!r}) failed: {exc}; "
                                       f"{messages[-1:]}") from None
            t += step
    finally:
        for s in slaves.values():
            try:
                s.terminate()
                s.freeInstance()
            except Exception:  # noqa: BLE001 - an FMU that failed may refuse; the others are freed
                pass
    # The last step is the rounding remainder (about 1e-13 s): a sample of its own, dropped from the figures
    # so that every master is judged on the same n + 1 communication points.
    keep = [0] + [k for k in range(1, len(times)) if times[k] - times[k - 1] > h / 2]
    return _trace(np.asarray(times)[keep], np.asarray(rows)[keep])


def omsimulator() -> str | None:
    """The OMSimulator command-line tool: ``$FLEXARM_OMSIMULATOR``, else ``OMSimulator`` on the PATH, else None."""
    return os.environ.get("FLEXARM_OMSIMULATOR") or shutil.which("OMSimulator")


def run_omsimulator(ssp: Path, folder: Path, timeout: float = 600.0) -> Trace:
    """OMSimulator's command-line tool on the archive as it is: its fixed-step master at the SSD's step and stop
    time, every variable to a CSV result file. The file holds each communication point twice (before and after
    the exchange; the last one three times): the last row of each time is the one after the exchange."""
    tool = omsimulator()
    if tool is None:
        raise RuntimeError("OMSimulator is not installed (set FLEXARM_OMSIMULATOR to its command-line tool)")
    n, h = experiment(ssp)
    folder.mkdir(parents=True, exist_ok=True)
    result = folder / "omsimulator.csv"
    # A Python FMU runs Python inside the tool's process; NumPy and SciPy must be importable there, which is what
    # its own error message asks a user to set (docs/fmus-in-other-tools.md): this interpreter's site-packages.
    site = str(Path(np.__file__).resolve().parent.parent)
    path = [site, *(p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p)]
    done = subprocess.run([tool, f"--stopTime={n * h!r}", f"--stepSize={h!r}", f"--resultFile={result}",
                           str(Path(ssp).resolve())], cwd=folder, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join(path)})
    errors = [ln for ln in (done.stdout + done.stderr).splitlines() if ln.startswith("error:")]
    if done.returncode != 0 or not result.is_file():  # it exits 0 when its initialisation fails
        raise RuntimeError(f"OMSimulator exited {done.returncode} without a result file: {' / '.join(errors)[-300:]}")
    with open(result, newline="") as f:
        rows = list(csv.reader(f))
    header, data = rows[0], np.array(rows[1:], dtype=float)

    def column(fmu: str, var: str) -> np.ndarray:
        hits = [i for i, name in enumerate(header) if name.endswith(f".{fmu}.{var}")]
        if len(hits) != 1:
            raise RuntimeError(f"OMSimulator's result file has {len(hits)} columns for {fmu}.{var}")
        return data[:, hits[0]]

    time = data[:, 0]
    last = np.flatnonzero(np.append(np.diff(time) > h / 2, True))  # the last row of each communication point
    if len(last) != n + 1:
        raise RuntimeError(f"OMSimulator's result file has {len(last)} communication points, not {n + 1}: "
                           f"{' / '.join(errors)[-300:]}")
    cols = [column("plant", v) for v in STATE] + [column("controller", "tau1"), column("controller", "tau2")]
    return _trace(time[last], np.column_stack(cols)[last])


def run_simulate_fmu(ssp: Path, torques: Trace, folder: Path) -> Trace:
    """fmpy's simulate_fmu on the archive's plant alone, its torques those of `torques` (held per step)."""
    from fmpy import simulate_fmu

    plant = Path(extract_fmus(ssp, folder)["plant"])
    n, h = experiment(ssp)
    signals = np.zeros(n + 1, dtype=[("time", float), ("tau1", float), ("tau2", float)])
    signals["time"] = np.arange(n + 1) * h
    signals["tau1"], signals["tau2"] = torques.tau[: n + 1, 0], torques.tau[: n + 1, 1]
    result = simulate_fmu(str(plant), stop_time=n * h, step_size=h, output_interval=h, input=signals, output=STATE)
    rows = np.column_stack([result[v] for v in STATE] + [signals["tau1"], signals["tau2"]])
    return _trace(result["time"], rows)


class HostileHost:
    """Runs a :class:`scenarios.run.setup.Setup`'s FMUs like :meth:`scenarios.master.cosim.Master.run`, hostilely.

    Parameters
    ----------
    setup : Setup
    algorithm : {"gauss-seidel", "jacobi"}
    init_rounds : int
        Exchange rounds in initialisation mode (Jacobi exchange).
    seed : int
        Seed of the order in which inputs are set.
    extra_reads : int
        Reads of every output of an FMU before and after each single set (0: a plain host).
    shuffle : bool
        Set the inputs in a random order (else in the connections' order).
    extra_tau_read : bool
        Only this hostility: one more ``getReal(tau)`` after the controller's inputs are set (the Ecos pattern).
    """

    def __init__(self, setup, algorithm: str, init_rounds: int = 0, seed: int = 0, extra_reads: int = 2,
                 shuffle: bool = True, extra_tau_read: bool = False):
        self.setup, self.algorithm, self.init_rounds = setup, algorithm, init_rounds
        self.rng = np.random.default_rng(seed)
        self.extra_reads, self.shuffle, self.extra_tau_read = extra_reads, shuffle, extra_tau_read
        self.order = setup.scenario.order
        self.rank = {name: i for i, name in enumerate(self.order)}

    def _load(self):
        self.tmp = Path(tempfile.mkdtemp(prefix="hostile_"))
        self.slaves, self.vars, self.outputs, self.messages = {}, {}, {}, []
        for name in self.order:
            s, md = _slave(self.setup.paths[name], name, self.tmp, self.messages)
            self.slaves[name] = s
            self.vars[name] = {v.name: v for v in md.modelVariables}
            self.outputs[name] = [v.valueReference for v in md.modelVariables if v.causality == "output"]

    def _free(self):
        for s in self.slaves.values():
            s.terminate()
            s.freeInstance()
        shutil.rmtree(self.tmp, ignore_errors=True)

    def _vr(self, fmu: str, var: str) -> int:
        return self.vars[fmu][var].valueReference

    def _set_parameter(self, fmu: str, var: str, value) -> None:
        v, s = self.vars[fmu][var], self.slaves[fmu]
        if v.type == "Real":
            s.setReal([v.valueReference], [float(value)])
        elif v.type == "Boolean":
            s.setBoolean([v.valueReference], [bool(value)])
        else:
            s.setInteger([v.valueReference], [int(value)])

    def _read_all(self, fmu: str) -> None:
        for _ in range(self.extra_reads):
            self.slaves[fmu].getReal(self.outputs[fmu])

    def _get(self, fmu: str, var: str) -> float:
        self._read_all(fmu)
        return self.slaves[fmu].getReal([self._vr(fmu, var)])[0]

    def _set_inputs(self, items: list[tuple[str, str, float]]) -> None:
        """Set (fmu, input, value) one by one, in random order, reading every output around each set."""
        order = self.rng.permutation(len(items)) if self.shuffle else range(len(items))
        for i in order:
            fmu, var, value = items[i]
            self._read_all(fmu)
            self.slaves[fmu].setReal([self._vr(fmu, var)], [value])
            self._read_all(fmu)
        if self.extra_tau_read:
            for fmu in {f for f, _, _ in items}:
                if "tau1" in self.vars[fmu]:
                    self.slaves[fmu].getReal([self._vr(fmu, "tau1"), self._vr(fmu, "tau2")])

    def _jacobi_exchange(self) -> None:
        values = [(c, self._get(c.src_fmu, c.src_var)) for c in self.setup.connections]
        self._set_inputs([(c.dst_fmu, c.dst_var, v) for c, v in values])

    def _gauss_seidel_exchange(self) -> None:
        for name in self.order:  # forward edges: sources earlier in the order, at this FMU's turn
            edges = [c for c in self.setup.connections
                     if c.dst_fmu == name and self.rank[c.src_fmu] < self.rank[name]]
            self._set_inputs([(c.dst_fmu, c.dst_var, self._get(c.src_fmu, c.src_var)) for c in edges])
        feedback = [c for c in self.setup.connections if self.rank[c.src_fmu] >= self.rank[c.dst_fmu]]
        self._set_inputs([(c.dst_fmu, c.dst_var, self._get(c.src_fmu, c.src_var)) for c in feedback])

    def run(self, parameters, record, n_steps, step_size, divergence_limit=1e4, progress=None, **_) -> dict:
        """:meth:`scenarios.master.cosim.Master.run`'s interface (status always "ok": an FMU error raises)."""
        self._load()
        try:
            for name, s in self.slaves.items():
                s.setupExperiment(startTime=0.0)
                for var, value in parameters.get(name, {}).items():
                    self._set_parameter(name, var, value)
                s.enterInitializationMode()
            for _ in range(self.init_rounds):
                self._jacobi_exchange()
            for s in self.slaves.values():
                s.exitInitializationMode()
            data = np.full((n_steps + 1, len(record)), np.nan)
            for k in range(n_steps + 1):
                if self.algorithm == "jacobi":  # the values exchanged, read before any input changed
                    data[k] = [self._get(f, v) for f, v in record]
                    self._jacobi_exchange()
                else:  # the values at t_k after every input is set
                    self._gauss_seidel_exchange()
                    data[k] = [self._get(f, v) for f, v in record]
                if k < n_steps:
                    for name in self.order:
                        self.slaves[name].doStep(k * step_size, step_size)
        finally:
            self._free()
        return {"status": "ok", "message": "", "time": np.arange(n_steps + 1) * step_size,
                "signals": {f"{f}.{v}": data[:, i] for i, (f, v) in enumerate(record)}}
