"""Every FMU under misuse: fmi2Error with a message (never a crash), bounded memory, FMU state, reset.

Parametrised over every FMU the project builds (build_fmus.FMUS). The FMI
front end (fmus/common/fmi2_shim.c) tracks the FMI 2.0 state machine; the
Python glue rejects bad values; both must report fmi2Error with a log
message, change nothing, and leave the FMU usable.
"""

from __future__ import annotations

import gc
import math
import sys
import zipfile
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions
from fmu_harness import DT, ERROR, OK, SCENARIOS, Slave, built_fmus, drive, rss_mb, third_party_pythonpath

from fmu_build import FMUS
from scenarios.master.fmi_callbacks import logging_callbacks

ROOT = Path(__file__).resolve().parents[1]

NAMES = list(FMUS)
#: fmi2StatusKind values.
LAST_SUCCESSFUL_TIME = 2


@pytest.fixture(scope="module")
def fmus() -> dict[str, Path]:
    return built_fmus()


@pytest.fixture(scope="module")
def unzipped(fmus, tmp_path_factory) -> dict[str, str]:
    return {name: extract(str(path), unzipdir=str(tmp_path_factory.mktemp(f"{name}_unzipped")))
            for name, path in fmus.items()}


def _first(md, causality: str, type_: str | None = "Real"):
    """The first variable of that causality (and type), or None (the reference FMU has no inputs or parameters)."""
    return next((v for v in md.modelVariables if v.causality == causality and (type_ is None or v.type == type_)),
                None)


def _set_status(slave: Slave, var, value) -> int:
    try:
        slave.set(**{var.name: value})
    except FMICallException as exc:
        return int(exc.status)
    return OK


def _start_value(var):
    return {"Real": float, "Integer": int, "Enumeration": int, "Boolean": lambda s: s == "true",
            "String": str}[var.type](var.start)


# -- the FMI 2.0 state machine ---------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_wrong_state_calls_return_error_with_a_message(fmus, unzipped, name):
    s = Slave(fmus[name], unzipped[name], f"{name}_states", start=False)
    output = _first(s.md, "output")
    fixed = _first(s.md, "parameter", None)

    def refused(method, *args, call, state):
        n = len(s.messages)
        assert s.status(method, *args) == ERROR, f"{method} in state {state}"
        logged = [m for st, m in s.messages[n:] if st == ERROR]
        assert any(call in m and f"'{state}'" in m for m in logged), s.messages[n:]

    try:
        refused("doStep", 0.0, DT, call="fmi2DoStep", state="instantiated")
        refused("getReal", [output.valueReference], call="fmi2GetReal", state="instantiated")
        refused("exitInitializationMode", call="fmi2ExitInitializationMode", state="instantiated")
        refused("terminate", call="fmi2Terminate", state="instantiated")
        s.fmu.setupExperiment(startTime=0.0)
        s.fmu.enterInitializationMode()
        refused("doStep", 0.0, DT, call="fmi2DoStep", state="initializationMode")
        refused("setupExperiment", None, 0.0, call="fmi2SetupExperiment", state="initializationMode")
        refused("enterInitializationMode", call="fmi2EnterInitializationMode", state="initializationMode")
        refused("terminate", call="fmi2Terminate", state="initializationMode")
        s.fmu.exitInitializationMode()
        refused("enterInitializationMode", call="fmi2EnterInitializationMode", state="stepComplete")
        refused("exitInitializationMode", call="fmi2ExitInitializationMode", state="stepComplete")
        # A fixed parameter after initialisation: the glue refuses it, naming the parameter.
        if fixed is not None:
            n = len(s.messages)
            assert _set_status(s, fixed, _start_value(fixed)) == ERROR
            assert any(fixed.name in m and "fixed parameter" in m for _, m in s.messages[n:]), s.messages[n:]
        s.step()
        s.fmu.terminate()
        refused("doStep", s.time, DT, call="fmi2DoStep", state="terminated")
        if _first(s.md, "input") is not None:
            refused("setReal", [_first(s.md, "input").valueReference], [0.0], call="fmi2SetReal", state="terminated")
        refused("terminate", call="fmi2Terminate", state="terminated")
        # None of that did any harm: reset and run.
        s.fmu.reset()
        s.start()
        out = drive(s, name, 0, 3)
        assert np.all(np.isfinite(out))
    finally:
        s.close()


@pytest.mark.parametrize("name", NAMES)
def test_non_finite_values_return_error_and_the_fmu_stays_usable(fmus, unzipped, name):
    s = Slave(fmus[name], unzipped[name], f"{name}_nan", start=False)
    inputs = [v for v in s.md.modelVariables if v.causality == "input" and v.type == "Real"]
    real_param = _first(s.md, "parameter")
    try:
        s.fmu.setupExperiment(startTime=0.0)
        s.fmu.enterInitializationMode()
        if real_param is not None:
            for bad in (math.nan, math.inf):  # a parameter: rejected, initialisation refused until it is valid
                assert _set_status(s, real_param, bad) == ERROR
                assert any(real_param.name in m and "finite" in m for m in s.errors()), s.messages
            assert s.status("exitInitializationMode") == ERROR
            s.set(**{real_param.name: _start_value(real_param)})
        s.fmu.exitInitializationMode()
        before = drive(s, name, 0, 5)
        for var in inputs:
            for bad in (math.nan, math.inf, -math.inf):
                n = len(s.messages)
                assert s.status("setReal", [var.valueReference], [bad]) == ERROR, (var.name, bad)
                assert any(var.name in m and "finite" in m for _, m in s.messages[n:]), s.messages[n:]
            assert s.status("doStep", s.time, DT) == ERROR  # refused while the input has no valid value
            s.set(**{var.name: 0.0})
        assert s.status("doStep", math.nan, DT) == ERROR
        assert s.status("doStep", s.time, math.inf) == ERROR
        assert s.status("doStep", s.time, -DT) == ERROR
        # a step longer than the documented bound is refused at once (it used not to return in 150 s), by name
        n = len(s.messages)
        assert s.status("doStep", s.time, 1e6) == ERROR
        assert any("step_size" in m and "10 s" in m for _, m in s.messages[n:]), s.messages[n:]
        after = drive(s, name, 5, 5)  # usable again: valid values were set
        assert np.all(np.isfinite(before)) and np.all(np.isfinite(after))
    finally:
        s.close()


def test_the_step_bound_is_one_fact():
    """The Python FMUs' MAX_STEP_SIZE and the native glue's GLUE_MAX_STEP_SIZE are the same bound (the docs name
    10 s for both)."""
    import re

    text = (ROOT / "fmus" / "common" / "flexarm_fmu_base.py").read_text()
    py = float(re.search(r"^MAX_STEP_SIZE = ([0-9.e+]+)$", text, re.M)[1])
    c = float(re.search(r"#define GLUE_MAX_STEP_SIZE ([0-9.e+]+)", (ROOT / "fmus" / "native" / "common" /
                                                                   "fmi2_glue.h").read_text())[1])
    assert py == c == 10.0
    assert "`h` > 10 s" in (ROOT / "docs" / "fmu-interface.md").read_text()


# -- memory: 200 instantiate/free cycles -------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_instantiate_free_cycles_keep_memory_bounded(fmus, unzipped, name):
    md = read_model_description(str(fmus[name]))
    callbacks = logging_callbacks(lambda *args: None)

    def cycle():  # load, instantiate, initialise, step, terminate, free (fmpy unloads the library)
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped[name],
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="cycle")
        fmu.instantiate(callbacks=callbacks, loggingOn=False)
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        fmu.doStep(0.0, DT)
        fmu.terminate()
        fmu.freeInstance()

    for _ in range(10):  # warm-up: imports, Numba compilation, caches
        cycle()
    gc.collect()
    before, path_length = rss_mb(), len(sys.path)
    for _ in range(200):
        cycle()
    gc.collect()
    growth = rss_mb() - before
    assert len(sys.path) == path_length  # pythonfmu adds the resources folder per instantiation; the glue dedupes
    print(f"\n{name}: 200 instantiate/free cycles, RSS {before:.1f} MB -> {before + growth:.1f} MB "
          f"(+{growth:.2f} MB)")
    assert growth < 20.0


# -- two plant instances in one process --------------------------------------------------------------
def test_two_plant_instances_are_independent(fmus, unzipped):
    """A nominal arm and a 0.275 kg payload arm, stepped interleaved, each equal their solo runs bit for bit."""
    n = 400
    tau_a = np.array([[2.0 * np.sin(2 * np.pi * k / 500), 0.8 * np.cos(2 * np.pi * k / 170)] for k in range(n)])
    tau_b = np.array([[-1.5 * np.sin(2 * np.pi * k / 300), 1.2 * np.sin(2 * np.pi * k / 90)] for k in range(n)])

    def run(slaves_and_torques):
        records = [[] for _ in slaves_and_torques]
        for k in range(n):
            for s, tau in slaves_and_torques:
                s.set_vector(["tau1", "tau2"], tau[k])
            for (s, _), rec in zip(slaves_and_torques, records):
                s.step()
                rec.append(s.outputs())
        return [np.array(r) for r in records]

    def plant(label, payload):
        return Slave(fmus["plant"], unzipped["plant"], label, payload_mass=payload)

    solo = []
    for label, payload, tau in (("solo_a", 0.0, tau_a), ("solo_b", 0.275, tau_b)):
        s = plant(label, payload)
        try:
            solo.append(run([(s, tau)])[0])
        finally:
            s.close()
    a, b = plant("a", 0.0), plant("b", 0.275)
    try:
        together = run([(a, tau_a), (b, tau_b)])
    finally:
        a.close()
        b.close()
    np.testing.assert_array_equal(together[0], solo[0])
    np.testing.assert_array_equal(together[1], solo[1])
    assert not np.array_equal(solo[0], solo[1])


# -- FMU state ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_fmu_state_repeats_steps_bit_for_bit(fmus, unzipped, name):
    """get state, step N, set state, step N again: the same outputs (integrator, filter, noise generator)."""
    params = SCENARIOS[name]["params"]
    s = Slave(fmus[name], unzipped[name], f"{name}_state", **params)
    other = Slave(fmus[name], unzipped[name], f"{name}_other", **params)
    try:
        assert s.md.coSimulation.canGetAndSetFMUstate and s.md.coSimulation.canSerializeFMUstate
        drive(s, name, 0, 40)
        state = s.fmu.getFMUstate()
        blob = s.fmu.serializeFMUstate(state)
        first = drive(s, name, 40, 30)
        assert np.ptp(first, axis=0).max() > 0  # the outputs do change over the N steps
        s.fmu.setFMUstate(state)
        np.testing.assert_array_equal(drive(s, name, 40, 30), first)
        # Serialized, into another instance with another history (it is at t = 0).
        restored = other.fmu.deSerializeFMUstate(blob)
        other.fmu.setFMUstate(restored)
        other.fmu.freeFMUstate(restored)
        np.testing.assert_array_equal(drive(other, name, 40, 30), first)
        # The FMI state comes back too: after fmi2Terminate, restoring the state allows stepping again.
        s.fmu.terminate()
        s.fmu.setFMUstate(state)
        np.testing.assert_array_equal(drive(s, name, 40, 5), first[:5])
        # A damaged byte stream is refused (fmi2Error, not pythonfmu's fmi2Fatal); the instance carries on.
        damaged = bytearray(blob)
        damaged[-5] ^= 0x01
        n = len(s.messages)
        assert s.status("deSerializeFMUstate", bytes(damaged)) == ERROR
        assert any("checksum" in m for _, m in s.messages[n:]), s.messages[n:]
        assert s.status("deSerializeFMUstate", b"not a state") == ERROR
        s.fmu.freeFMUstate(state)
        assert np.all(np.isfinite(drive(s, name, 45, 2)))
        assert not s.errors()[:-2]  # only the two refusals above
    finally:
        s.close()
        other.close()


# -- fmi2Reset ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_reset_returns_to_the_initial_state(fmus, unzipped, name):
    """After a run with other parameters, reset + initialise + steps equals a fresh instance bit for bit."""
    params = SCENARIOS[name]["params"]
    other_params = {"plant": {"payload_mass": 1.0, "q2_0": 0.5},
                    "sensors": {"noise_seed": 99, "strain_gauge_filter": True},
                    "reference": {}}.get(name, {"schedule_period": 0.02})
    references = {}
    for label, p in (("default", {}), ("params", params)):
        fresh = Slave(fmus[name], unzipped[name], f"{name}_fresh", **p)
        try:
            references[label] = drive(fresh, name, 0, 40)
        finally:
            fresh.close()
    s = Slave(fmus[name], unzipped[name], f"{name}_reset", **other_params)
    try:
        drive(s, name, 0, 25)
        for label, p in (("default", {}), ("params", params), ("default", {})):
            s.fmu.reset()
            s.start(**p)
            np.testing.assert_array_equal(drive(s, name, 0, 40), references[label], err_msg=label)
    finally:
        s.close()


# -- several FMUs in one interpreter -------------------------------------------------------------------
def test_slave_modules_are_unique_and_every_fmu_loads_into_one_process(fmus, unzipped):
    modules, identifiers = {}, {}
    for name, path in fmus.items():
        with zipfile.ZipFile(path) as z:
            modules[name] = z.read("resources/slavemodule.txt").decode().strip()
        identifiers[name] = read_model_description(str(path)).coSimulation.modelIdentifier
    assert len(set(modules.values())) == len(modules), modules
    assert len(set(identifiers.values())) == len(identifiers), identifiers
    slaves = [Slave(fmus[name], unzipped[name], name, **SCENARIOS[name]["params"]) for name in NAMES]
    try:
        for name, s in zip(NAMES, slaves):
            assert np.all(np.isfinite(drive(s, name, 0, 3)))
            assert not s.errors(), s.errors()
    finally:
        for s in slaves:
            s.close()


_SIMULATE_TWICE = r"""
import json, sys
import importlib.util
assert importlib.util.find_spec("flexarm") is None, "flexarm importable outside the FMU"
from fmpy import simulate_fmu
fmus = json.loads(sys.argv[2])
out = {}
for name in ("plant", "plant", "sensors", "controller", "plant"):  # each unpacked to, and deleted from, a new folder
    result = simulate_fmu(fmus[name], stop_time=0.01, output_interval=1e-3)
    out.setdefault(name, []).append([float(x) for x in result[-1]])
print(json.dumps(out))
"""


def test_fmpy_simulate_fmu_runs_fmus_again_in_one_process(fmus, tmp_path):
    """fmpy's simulate_fmu deletes each unpacked FMU afterwards; the next FMU must not use its modules.

    With pythonfmu alone the second run crashed the process (the slave module cached from the deleted
    folder cannot be re-executed, and pythonfmu's error path releases an uninitialised pointer). Run in a
    process where `flexarm` can only come from the FMUs (`python -I -S`, site-packages appended), with
    the NumPy kernels (no Numba compilation in throwaway folders).
    """
    import json
    import os
    import subprocess

    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    env["FLEXARM_NO_NUMBA"] = "1"
    # -S: no site, so no .pth (the editable 'flexarm'); this interpreter's import path minus the project
    env["PYTHONPATH"] = third_party_pythonpath()
    proc = subprocess.run([sys.executable, "-S", "-s", "-c", _SIMULATE_TWICE, "[]",
                           json.dumps({k: str(v) for k, v in fmus.items()})],
                          env=env, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert len(out["plant"]) == 3 and out["plant"][0] == out["plant"][1] == out["plant"][2]
    assert len(out["sensors"]) == len(out["controller"]) == 1


# -- what the shim checks that pythonfmu does not ---------------------------------------------------------
def test_instantiate_checks_guid_and_type(fmus, unzipped):
    md = read_model_description(str(fmus["plant"]))
    messages = []
    callbacks = logging_callbacks(lambda c, i, status, cat, msg: messages.append((status, msg.decode())))
    fmu = FMU2Slave(guid="not-the-guid", unzipDirectory=unzipped["plant"],
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="wrong")
    with pytest.raises(Exception, match="instantiate"):
        fmu.instantiate(callbacks=callbacks)
    assert any(status == ERROR and "fmuGUID" in m and md.guid in m for status, m in messages), messages
    resources = (Path(unzipped["plant"]) / "resources").as_uri().encode()
    component = fmu.fmi2Instantiate(b"me", 0, md.guid.encode(), resources, callbacks, 0, 0)  # 0: model exchange
    assert not component
    assert any("co-simulation FMU only" in m for _, m in messages), messages
    fmu.freeLibrary()


def test_null_pointers_unknown_categories_and_status_queries(fmus, unzipped):
    s = Slave(fmus["plant"], unzipped["plant"], "checks")
    try:
        get_real = s.fmu._functions["fmi2GetReal"]
        assert get_real(s.fmu.component, None, 2, None) == ERROR
        assert any("must not be NULL" in m for m in s.errors())
        assert s.status("setDebugLogging", True, ["logEverything"]) == ERROR
        assert any("unknown log category 'logEverything'" in m for m in s.errors())
        assert s.status("setDebugLogging", False, []) == OK
        n = len(s.messages)
        assert s.status("doStep", 0.0, -1.0) == ERROR  # errors are logged even with debug logging off
        assert any("step_size" in m for _, m in s.messages[n:])
        for _ in range(3):
            s.step()
        assert s.fmu.getRealStatus(LAST_SUCCESSFUL_TIME) == pytest.approx(3 * DT)
        assert not s.fmu.getBooleanStatus(3)  # fmi2Terminated: the FMU never asks to stop
    finally:
        s.close()


def test_errors_reach_a_host_that_instantiates_without_logging(fmus, unzipped):
    md = read_model_description(str(fmus["plant"]))
    messages = []
    callbacks: fmi2CallbackFunctions = logging_callbacks(lambda c, i, st, cat, m: messages.append((st, m.decode())))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped["plant"], modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="quiet")
    fmu.instantiate(callbacks=callbacks, loggingOn=False)
    try:
        with pytest.raises(FMICallException):
            fmu.doStep(0.0, DT)
        assert [st for st, _ in messages] == [ERROR] and "fmi2DoStep" in messages[0][1]
    finally:
        fmu.freeInstance()


# -- documentation/index.html -----------------------------------------------------------------------------
class _Rows(HTMLParser):
    """Table rows with an id: {id: [cell texts]}."""

    def __init__(self):
        super().__init__()
        self.rows: dict[str, list[str]] = {}
        self._row = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "tr" and attrs.get("id"):
            self._row = self.rows.setdefault(attrs["id"], [])
        elif tag == "td" and self._row is not None:
            self._row.append("")

    def handle_endtag(self, tag):
        if tag == "tr":
            self._row = None

    def handle_data(self, data):
        if self._row:
            self._row[-1] += data


@pytest.mark.parametrize("name", NAMES)
def test_interface_doc_describes_every_variable(fmus, name):
    doc = (ROOT / "docs" / "fmu-interface.md").read_text()
    md = read_model_description(str(fmus[name]))
    missing = [v.name for v in md.modelVariables if f"`{v.name}`" not in doc]
    assert not missing, f"docs/fmu-interface.md does not describe {missing} of {name}"


@pytest.mark.parametrize("name", NAMES)
def test_documentation_lists_every_variable(fmus, name):
    with zipfile.ZipFile(fmus[name]) as z:
        page = z.read("documentation/index.html").decode()
    md = read_model_description(str(fmus[name]))
    parser = _Rows()
    parser.feed(page)
    missing = [v.name for v in md.modelVariables if f"var-{v.name}" not in parser.rows]
    assert not missing, f"documentation/index.html does not list {missing}"
    for v in md.modelVariables:
        cells = parser.rows[f"var-{v.name}"]
        assert cells[0] == v.name and cells[1] == str(v.valueReference) and cells[2] == v.type
        if v.type == "Real" and v.unit not in (None, "1"):
            assert cells[3] == v.unit, (v.name, cells)
        if v.causality == "parameter" and v.min is not None:
            assert f"{float(v.min):.16g}" in cells[6] or "π" in cells[6], (v.name, cells)
        if v.causality == "parameter":
            start = cells[5]
            assert start.split(" ")[0].strip('"').lower() in (v.start.lower(), f"{float(v.start):.16g}"
                                                               if v.type == "Real" else v.start.lower()) \
                or "π" in start, (v.name, start, v.start)
    for words in ("What it models", "How to use it", "fmi2DoStep", "LD_PRELOAD", md.coSimulation.modelIdentifier):
        assert words in page
