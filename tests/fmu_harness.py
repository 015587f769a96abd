"""Drive one FMU step by step through fmpy's low-level FMU2Slave, with its log captured (test helpers)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

from scenarios.master.fmi_callbacks import logging_callbacks

DT = 1e-3
#: fmi2Status values.
OK, WARNING, DISCARD, ERROR, FATAL = 0, 1, 2, 3, 4


class Slave:
    """An FMU driven step by step through fmpy's FMU2Slave, with its log captured.

    With ``start=True`` (default) the instance is set up at t = 0, `params`
    are set in initialisation mode, and it leaves initialisation mode (any
    error raises ``FMICallException``); with ``start=False`` it is only
    instantiated (for tests of the state machine).
    """

    def __init__(self, fmu_path, unzipdir, name="fmu", *, start=True, **params):
        self.md = read_model_description(str(fmu_path))
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.messages: list[tuple[int, str]] = []

        def logger(component, instance, status, category, message):
            self.messages.append((status, message.decode()))

        self._callbacks = cb = logging_callbacks(logger)  # referenced as long as the instance lives
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=unzipdir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(callbacks=cb, loggingOn=True)
        self.time = 0.0
        if start:
            self.start(**params)

    def start(self, **params):
        """setupExperiment(0) -> enterInitializationMode -> set `params` -> exitInitializationMode."""
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.set(**params)
        self.fmu.exitInitializationMode()
        self.time = 0.0

    def set(self, **values):
        """Set variables by name; a choice parameter takes its option's name (as scenario files write it)."""
        for name, value in values.items():
            var = self.vars[name]
            if isinstance(value, str) and var.type == "Integer":
                value = choice(var, value)
            setter = {"Real": self.fmu.setReal, "Integer": self.fmu.setInteger,
                      "Boolean": self.fmu.setBoolean, "String": self.fmu.setString}[var.type]
            setter([var.valueReference], [value])

    def set_vector(self, names, values):
        self.fmu.setReal([self.vars[n].valueReference for n in names], [float(v) for v in values])

    def get(self, names) -> np.ndarray:
        return np.array(self.fmu.getReal([self.vars[n].valueReference for n in names]))

    def outputs(self) -> np.ndarray:
        """Every Real output, in model-description order."""
        return self.get([v.name for v in self.md.modelVariables if v.causality == "output" and v.type == "Real"])

    def step(self, h=DT):
        self.fmu.doStep(self.time, h)
        self.time += h

    def status(self, method: str, *args) -> int:
        """Call ``self.fmu.<method>(*args)`` and return its fmi2Status (0 for OK) instead of raising."""
        try:
            getattr(self.fmu, method)(*args)
        except FMICallException as exc:
            return int(exc.status)
        return OK

    def errors(self) -> list[str]:
        return [m for s, m in self.messages if s >= ERROR]

    def close(self):
        try:
            self.fmu.terminate()
        except FMICallException:  # e.g. still in initialisation mode after a failed initialisation
            pass
        self.fmu.freeInstance()


#: This project's own top-level packages: a child process that must take them from an FMU gets no path to them.
_OWN_PACKAGES = ("flexarm", "scenarios", "fmu_build", "fmus")
_ROOT = Path(__file__).resolve().parents[1]


def third_party_pythonpath() -> str:
    """A ``PYTHONPATH`` for a ``python -S -s`` child: this interpreter's import path without this project.

    Every folder of the running interpreter's ``sys.path`` (site-packages, the user site, a venv's, a
    conda prefix's, folders added by ``.pth`` files), wherever it lives, inside the checkout or not, minus
    the folders from which this project's own source would import: the checkout, and any other folder
    holding ``flexarm`` etc. as plain source (an editable install's path entry). A site-packages folder
    stays even if a non-editable install put ``flexarm`` there, as fmpy and NumPy live beside it. With
    ``-S`` no ``.pth`` file runs, so an editable install's import hook is not installed either.
    """
    import os
    import sys

    keep = []
    for entry in sys.path:
        if not entry or not Path(entry).is_dir():  # '' (the working folder), path-hook names, zips
            continue
        folder = Path(entry).resolve()
        site_dir = folder.name in ("site-packages", "dist-packages")
        own = (folder.is_relative_to(_ROOT)  # the checkout and its folders (tests/), but not a .venv inside it
               or any((folder / name / "__init__.py").is_file() for name in _OWN_PACKAGES))
        if own and not site_dir:
            continue
        if str(folder) not in keep:
            keep.append(str(folder))
    return os.pathsep.join(keep)


def rss_mb() -> float:
    """Resident set size of this process in MB (VmRSS of /proc/self/status)."""
    text = Path("/proc/self/status").read_text()
    return int(re.search(r"^VmRSS:\s+(\d+)\s+kB", text, re.M).group(1)) / 1024.0


def choice(var, name: str) -> int:
    """The integer of choice parameter `var`'s option `name` (listed in its description)."""
    from scenarios.master.values import parse_choices

    items = parse_choices(var.description or "")
    if name not in items:
        raise ValueError(f"{var.name}: {name!r} is not one of {list(items)}")
    return items[name]


# -- every FMU of the project, built once per test process ----------------------------------------
_BUILT: dict[str, Path] = {}


def built_fmus() -> dict[str, Path]:
    """Every FMU of fmu_build.FMUS in the checkout's build folder (the one ``python build_fmus.py`` and the scenarios
    use), rebuilt where older than a source (fmu_build's up-to-date check); once per process. Issue 34: no FMU is
    built twice in one test run, nor again after ``.ci/run`` has built them (builds are reproducible, so a forced
    rebuild would give the same bytes). Tests copy an FMU before they change it."""
    if not _BUILT:
        from fmu_build import build_all

        _BUILT.update(build_all())
    return dict(_BUILT)


def _wave(k: int, amplitude: float, period_steps: float, phase: float = 0.0) -> float:
    return amplitude * np.sin(2 * np.pi * k / period_steps + phase)


def _plant_inputs(k: int) -> dict[str, float]:
    return {"tau1": _wave(k, 3.0, 700), "tau2": _wave(k, 1.0, 230, 0.5)}


def _sensor_inputs(k: int) -> dict[str, float]:
    names = ("q1", "q2", "qd1", "qd2", "eps1", "eps2", "eps3", "eps4", "eps5", "eps6", "acc1_n", "acc2_n")
    scale = (0.5, 1.2, 1.0, 2.0, 1e-3, 1e-3, 1e-3, 1e-2, 1e-2, 1e-2, 5.0, 10.0)
    return {n: s * (0.3 + np.sin(2 * np.pi * k / (37 + 11 * i) + i)) for i, (n, s) in enumerate(zip(names, scale))}


def _controller_inputs(k: int) -> dict[str, float]:
    y = _sensor_inputs(k)
    return {f"{n}_m" if not n.startswith("acc") else n.replace("_n", "_m"): v for n, v in y.items()}


#: Per FMU: parameters that exercise its state (noise and filters on for the sensors) and its
#: inputs at communication point k (smooth, inside every range).
SCENARIOS: dict[str, dict] = {
    "plant": {"params": {"payload_mass": 0.275, "q1_0": 0.1, "substeps": 3}, "inputs": _plant_inputs},
    "sensors": {"params": {"noise_enabled": True, "noise_seed": 11, "accelerometer_noise_m_per_s2": 0.05,
                           "strain_gauge_filter": True, "accelerometer_filter": True, "adc_quantization": True},
                "inputs": _sensor_inputs},
    **{name: {"params": {"gain_set": "gamma0.1"},
              "inputs": _controller_inputs}
       for name in ("controller", "controller_ff", "controller_fb", "controller_dlqr")},
    "controller_lqg": {"params": {"gain_set": "gamma0.1", "loop_delay_samples": 2, "integral_action": True,
                                  "tau1_max": 1000.0, "tau2_max": 1000.0},  # the inputs are far off the path
                       "inputs": _controller_inputs},
    "reference": {"params": {"lead_samples": 3}, "inputs": lambda k: {}},  # no inputs: outputs follow the time
}


def drive(slave: Slave, name: str, k0: int, n: int) -> np.ndarray:
    """Run `n` communication points from k0 with SCENARIOS[name]'s inputs: (n, outputs) read before each step."""
    inputs = SCENARIOS[name]["inputs"]
    rows = []
    for k in range(k0, k0 + n):
        u = inputs(k)
        slave.set_vector(list(u), list(u.values()))
        rows.append(slave.outputs())
        slave.fmu.doStep(k * DT, DT)
        slave.time = (k + 1) * DT
    return np.array(rows)


def extract_ssp_fmus(ssp, folder) -> dict[str, str]:
    """An SSP archive's FMUs as files (instance -> path), so that two masters run exactly the same binaries."""
    import io
    import zipfile

    from lxml import etree

    from scenarios.conformance.ssp import NS

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(ssp) as zf:
        doc = etree.parse(io.BytesIO(zf.read("SystemStructure.ssd")))
        names = {}
        for comp in doc.iterfind("ssd:System/ssd:Elements/ssd:Component", NS):
            target = folder / comp.get("source").split("/")[-1]
            target.write_bytes(zf.read(comp.get("source")))
            names[comp.get("name")] = str(target)
    return names


_PD_IN_DO_STEP: list[Path] = []


def pd_in_do_step_fmu() -> Path:
    """tests/pd_in_do_step.py built with pythonfmu (a stranger's PD + feedforward, torques computed in do_step),
    once per test process into a temporary folder."""
    import atexit
    import shutil
    import subprocess
    import sys
    import tempfile

    if not _PD_IN_DO_STEP:
        root = Path(__file__).resolve().parents[1]
        out = Path(tempfile.mkdtemp(prefix="flexarm_pd_"))
        atexit.register(shutil.rmtree, out, True)
        subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(root / "tests" / "pd_in_do_step.py"),
                        "-d", str(out)], check=True, capture_output=True, text=True, cwd=root)
        _PD_IN_DO_STEP.append(out / "PDInDoStep.fmu")
    return _PD_IN_DO_STEP[0]
