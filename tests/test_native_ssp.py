"""The native FMUs through the SSP export: in fmpy's simulate_ssp and in libcosim, against our master.

Each SSP master is compared with our master in the stepping mode that reproduces it ("fmpy-ssp" for
simulate_ssp, "jacobi" for libcosim; see scenarios/master/cosim.py), on exactly the FMU files of the archive.
The libcosim runs happen in a subprocess, as in tests/test_ssp.py.
"""

from __future__ import annotations

import io
import struct
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmu_harness import Slave, built_fmus, extract_ssp_fmus
from lxml import etree
from native_fmus import native_fmus

from scenarios.config import ScenarioError, load_scenario
from scenarios.conformance.ssp import NATIVE_START_VALUES, export_ssp, validate_ssp
from scenarios.master.fmi_callbacks import logging_callbacks
from scenarios.run.setup import prepare

#: simulate_ssp or libcosim against our master in the mode that steps as they do, over the whole run.
TOLERANCE = 1e-9


@pytest.fixture(scope="module")
def folders() -> dict[str, object]:
    """The Python FMUs' folder and the native FMUs' folder (built once per test process)."""
    native = native_fmus()
    return {"fmu_dir": next(iter(built_fmus().values())).parent,
            "native_fmu_dir": next(iter(native.values())).parent}


@pytest.fixture(scope="module")
def table2_native(tmp_path_factory, folders):
    return export_ssp(load_scenario("table2"), tmp_path_factory.mktemp("ssp_native"), build=False, kind="native",
                      **folders)


@pytest.fixture(scope="module")
def ff_native(tmp_path_factory, folders):
    """compare_ff_fb, case ff: the native feedforward controller, no payload, no noise (open loop)."""
    return export_ssp(load_scenario("compare_ff_fb"), tmp_path_factory.mktemp("ssp_native_ff"), build=False,
                      cases=["ff"], kind="native", **folders)["ff"]


def _ours(scenario: str, ssp, folder, algorithm: str, parameters: dict | None = None):
    """Our master on the archive's FMUs; `parameters` None: nothing set (the archive's values are the defaults)."""
    sc = load_scenario(scenario)
    setup = prepare(sc, names=extract_ssp_fmus(ssp, folder))
    assert set(setup.fmu_kinds.values()) == {"native"}
    params = {} if parameters is None else setup.case_parameters(parameters)
    with setup.open_master(algorithm) as m:
        out = m.run(params, setup.record, setup.n_steps, sc.step_size)
    assert out["status"] == "ok", out["message"]
    return setup, out


def _worst(theirs: dict, ours: dict) -> tuple[str, float]:
    deltas = {k: float(np.max(np.abs(theirs[k] - ours[k]))) for k in theirs}
    worst = max(deltas, key=deltas.get)
    return worst, deltas[worst]


def _simulate_ssp(ssp, setup) -> dict:
    from fmpy.ssp.simulation import simulate_ssp

    n, h = setup.n_steps, setup.scenario.step_size
    result = simulate_ssp(str(ssp), stop_time=n * h - h / 2, step_size=h)  # no parameter set: the archive's values
    assert len(result) == n
    return {f"{i}.{v}": np.asarray(result[f"{i}.{v}"], dtype=float) for i, v in setup.record}


def _libcosim(ssp, tmp_path) -> dict:
    pytest.importorskip("libcosimpy",
                        reason="libcosimpy (the libcosim master) is not installed: pip install libcosimpy")
    out = tmp_path / f"libcosim-{ssp.stem}.npz"
    proc = subprocess.run([sys.executable, "-m", "scenarios.conformance.libcosim_runner", str(ssp), "--out", str(out)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"libcosim run failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr[-3000:]}"
    return dict(np.load(out))


def test_the_archives_hold_the_native_fmus_with_the_case_values(table2_native):
    sc = load_scenario("table2")
    for case in sc.cases:
        path = table2_native[case.key]
        assert validate_ssp(path) == []
        with zipfile.ZipFile(path) as zf:
            for inst in sc.order:
                with zipfile.ZipFile(io.BytesIO(zf.read(f"resources/{inst}.fmu"))) as fmu:
                    md = etree.fromstring(fmu.read("modelDescription.xml"))
                    assert md.find("CoSimulation").get("modelIdentifier").endswith("Native")
                    assert any(n.startswith("binaries/win64/") for n in fmu.namelist())
                    lines = dict(ln.split(" ") for ln in fmu.read(f"resources/{NATIVE_START_VALUES}").decode()
                                 .splitlines())
            payload = struct.unpack(">d", bytes.fromhex(_baked(zf, "plant")["payload_mass"]))[0]
            assert payload == case.parameters["plant"]["payload_mass"]
            assert lines == _baked(zf, "controller")


def _baked(zf: zipfile.ZipFile, inst: str) -> dict[str, str]:
    with zipfile.ZipFile(io.BytesIO(zf.read(f"resources/{inst}.fmu"))) as fmu:
        return dict(ln.split(" ") for ln in fmu.read(f"resources/{NATIVE_START_VALUES}").decode().splitlines())


def test_a_native_case_fmu_starts_with_the_case_values(table2_native, tmp_path):
    """The tip case's plant, instantiated with nothing set, has the 0.275 kg payload; a value outside the
    parameter's range, or a name that is no parameter, fails fmi2Instantiate naming it."""
    with zipfile.ZipFile(table2_native["tip"]) as zf:
        data = zf.read("resources/plant.fmu")
    fmu = tmp_path / "plant.fmu"
    fmu.write_bytes(data)
    s = Slave(fmu, extract(str(fmu)), "baked")
    try:
        assert s.fmu.getReal([s.vars["payload_mass"].valueReference]) == [0.275]
    finally:
        s.close()
    for line, message in ((f"payload_mass {struct.pack('>d', -1.0).hex()}", "payload_mass = -1 is outside"),
                          (f"tau1 {struct.pack('>d', 1.0).hex()}", "'tau1' is not a parameter"),
                          ("payload_mass 0.275", "is not 'name' and 16 hex digits")):
        folder = tmp_path / f"bad{len(message)}"
        unzipped = extract(str(fmu), unzipdir=str(folder))
        (folder / "resources" / NATIVE_START_VALUES).write_text(line + "\n")
        messages = _instantiate_messages(fmu, unzipped)
        assert any(message in m for m in messages), messages


def _instantiate_messages(fmu, unzipped) -> list[str]:
    """The messages the FMU logs while fmi2Instantiate fails (which it must)."""
    md = read_model_description(str(fmu))
    got: list[str] = []
    cb = logging_callbacks(lambda component, instance, status, category, message: got.append(message.decode()))
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="bad")
    with pytest.raises(Exception, match="Failed to instantiate"):  # fmpy's message when fmi2Instantiate gives NULL
        slave.instantiate(callbacks=cb, loggingOn=True)
    return got


def test_simulate_ssp_runs_the_native_open_loop_case_as_our_master(ff_native, tmp_path):
    setup, ours = _ours("compare_ff_fb", ff_native, tmp_path / "fmus", "fmpy-ssp")
    theirs = _simulate_ssp(ff_native, setup)
    worst, delta = _worst(theirs, ours["signals"])
    assert delta <= TOLERANCE, f"simulate_ssp vs our fmpy-ssp mode, native: {delta:.3g} in {worst}"
    assert np.max(np.abs(theirs["plant.theta1"] - theirs["plant.theta1"][0])) > 1.0  # the arm did slew


def test_libcosim_runs_the_native_open_loop_case_as_our_master(ff_native, tmp_path):
    lc = _libcosim(ff_native, tmp_path)
    setup, ours = _ours("compare_ff_fb", ff_native, tmp_path / "fmus", "jacobi")
    assert len(lc["time"]) == setup.n_steps + 1
    worst, delta = _worst({k: v for k, v in lc.items() if k != "time"}, ours["signals"])
    assert delta <= TOLERANCE, f"libcosim vs our jacobi master, native: {delta:.3g} in {worst}"
    assert np.max(np.abs(lc["plant.theta1"] - lc["plant.theta1"][0])) > 1.0


def test_simulate_ssp_runs_native_table2_none_closed_loop_as_our_master(table2_native, tmp_path):
    setup, ours = _ours("table2", table2_native["none"], tmp_path / "fmus", "fmpy-ssp")
    theirs = _simulate_ssp(table2_native["none"], setup)
    worst, delta = _worst(theirs, ours["signals"])
    assert delta <= TOLERANCE, f"simulate_ssp vs our fmpy-ssp mode, native closed loop: {delta:.3g} in {worst}"


def test_libcosim_runs_native_table2_none_closed_loop_as_our_master(table2_native, tmp_path):
    lc = _libcosim(table2_native["none"], tmp_path)
    setup, ours = _ours("table2", table2_native["none"], tmp_path / "fmus", "jacobi")
    assert set(k for k in lc if k != "time") == {f"{i}.{v}" for i, v in setup.record}
    worst, delta = _worst({k: v for k, v in lc.items() if k != "time"}, ours["signals"])
    assert delta <= TOLERANCE, f"libcosim vs our jacobi master, native closed loop: {delta:.3g} in {worst}"


def test_simulate_ssp_runs_a_case_off_the_defaults_from_the_baked_values(table2_native, tmp_path, folders):
    """The tip case (0.275 kg) in simulate_ssp, which applies no parameter set, equals our master running the
    plain native FMUs with the case's values set, and differs from the no-payload case."""
    sc = load_scenario("table2")
    tip = next(c for c in sc.cases if c.key == "tip")
    setup = prepare(sc, folders["fmu_dir"], build=False, kind="native",
                           native_fmu_dir=folders["native_fmu_dir"])
    with setup.open_master("fmpy-ssp") as m:
        ours = m.run(setup.case_parameters(tip.parameters), setup.record, setup.n_steps, sc.step_size)
    assert ours["status"] == "ok", ours["message"]
    theirs = _simulate_ssp(table2_native["tip"], setup)
    worst, delta = _worst(theirs, ours["signals"])
    assert delta <= TOLERANCE, f"simulate_ssp, tip case from its baked values: {delta:.3g} in {worst}"
    none = _simulate_ssp(table2_native["none"], setup)
    assert np.max(np.abs(none["plant.tip_x"] - theirs["plant.tip_x"])) > 1e-3  # the payload made a difference


def test_export_refuses_a_case_without_a_native_fmu(tmp_path, folders, monkeypatch):
    """As if controller_ff had no native build: compare_ff_fb (whose ff cases swap it in) is refused naming it,
    and no archive is written, not even those of the cases that have every native FMU."""
    from fmu_build import native_build as build_native

    monkeypatch.setattr(build_native, "NATIVE_FMUS", {k: v for k, v in build_native.NATIVE_FMUS.items()
                                                      if k != "controller_ff"})
    with pytest.raises(ScenarioError, match="fmus.controller: controller_ff has no native build"):
        export_ssp(load_scenario("compare_ff_fb"), tmp_path, build=False, kind="native", **folders)
    assert not any(tmp_path.iterdir())
