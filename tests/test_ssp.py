"""SSP export (scenarios.ssp) and the second, independent master: libcosim (scenarios.libcosim_runner).

The libcosim run happens in a subprocess (``python -m scenarios.libcosim_runner``):
it keeps libcosim's copies of the FMU binaries out of the test process, which
also loads the same FMUs through fmpy.
"""

import io
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from lxml import etree

from scenarios import runner
from scenarios.config import load_scenario
from scenarios.ssp import NS, export_ssp, parameter_sets, validate_ssp

#: libcosim and our master in its libcosim-compatible mode ("jacobi") must agree this closely, over the whole slew.
SERIES_TOLERANCE = 1e-6


@pytest.fixture(scope="module")
def table2_ssp(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ssp")
    return export_ssp(load_scenario("table2"), folder)


def _ssv(zf: zipfile.ZipFile, case: str, inst: str) -> dict[str, str]:
    root = etree.parse(io.BytesIO(zf.read(f"resources/{case}/{inst}.ssv"))).getroot()
    assert root.get("name") == case
    return {p.get("name"): p[0].get("value") for p in root.iterfind("ssv:Parameters/ssv:Parameter", NS)}


def test_table2_export_is_a_valid_ssp(table2_ssp):
    """Schema-valid SSD and SSVs, the runner's wiring, one parameter set per case with the plant's start angles."""
    from fmpy.ssp.ssd import read_ssd

    assert table2_ssp.name == "table2.ssp"
    assert [p.name for p in table2_ssp.parent.iterdir()] == ["table2.ssp"]  # written atomically: no temporary left
    assert validate_ssp(table2_ssp) == []
    ssd = read_ssd(str(table2_ssp), validate=True)  # fmpy's reader validates the SSD and every referenced SSV
    sc = load_scenario("table2")
    assert [c.name for c in ssd.system.elements] == sc.order
    assert {c.name: c.source for c in ssd.system.elements} == {i: f"resources/{i}.fmu" for i in sc.order}

    setup = runner.prepare(sc)
    wired = {(c.src_fmu, c.src_var, c.dst_fmu, c.dst_var) for c in runner.connect_by_name(setup.paths)}
    assert {(c.startElement, c.startConnector, c.endElement, c.endConnector)
            for c in ssd.system.connections} == wired
    assert parameter_sets(table2_ssp) == {c.key: "SystemStructure.ssd" for c in sc.cases}

    with zipfile.ZipFile(table2_ssp) as zf:
        doc = etree.parse(io.BytesIO(zf.read("SystemStructure.ssd")))
        exp = doc.find("ssd:DefaultExperiment", NS)
        assert float(exp.get("startTime")) == 0.0
        assert float(exp.get("stopTime")) == pytest.approx(setup.n_steps * sc.step_size, abs=1e-12)
        algo = exp.find("ssd:Annotations/ssc:Annotation/osp:Algorithm/osp:FixedStepAlgorithm", NS)
        assert float(algo.get("baseStepSize")) == sc.step_size
        start = runner.start_parameters(runner.desired_trajectory())
        for case in sc.cases:
            plant = _ssv(zf, case.key, "plant")
            assert float(plant["q1_0"]) == start["q1_0"] and float(plant["q2_0"]) == start["q2_0"]  # bit for bit
            assert float(plant["payload_mass"]) == case.parameters["plant"]["payload_mass"]
            sensors = _ssv(zf, case.key, "sensors")
            assert sensors["noise_enabled"] == str(case.parameters["sensors"]["noise_enabled"]).lower()
            assert _ssv(zf, case.key, "controller") == {"gain_set": "gamma0.1", "schedule_period": "0.2"}
        # the order of the bindings selects the default case: the scenario's first
        for comp in doc.iterfind("ssd:System/ssd:Elements/ssd:Component", NS):
            sources = [b.get("source") for b in comp.iterfind("ssd:ParameterBindings/ssd:ParameterBinding", NS)]
            assert sources == [f"resources/{c.key}/{comp.get('name')}.ssv" for c in sc.cases]


def test_cases_that_swap_fmus_get_their_own_ssd(tmp_path):
    sc = load_scenario("compare_ff_fb")
    path = export_ssp(sc, tmp_path / "cmp.ssp")
    assert validate_ssp(path) == []
    sets = parameter_sets(path)
    assert set(sets) == {c.key for c in sc.cases}
    with zipfile.ZipFile(path) as zf:
        assert sorted(n for n in zf.namelist() if n.endswith(".fmu")) == [
            "resources/controller.fmu", "resources/controller_fb.fmu", "resources/controller_ff.fmu",
            "resources/plant.fmu", "resources/sensors.fmu"]
        for case in sc.cases:
            doc = etree.parse(io.BytesIO(zf.read(sets[case.key])))
            controller = doc.find("ssd:System/ssd:Elements/ssd:Component[@name='controller']", NS)
            assert controller.get("source") == f"resources/{case.fmus['controller']}.fmu"
    assert sets["both"] == "SystemStructure.ssd"


def _extract_fmus(ssp, folder) -> dict[str, str]:
    """The archive's FMUs as files, so that both masters run exactly the same binaries."""
    with zipfile.ZipFile(ssp) as zf:
        doc = etree.parse(io.BytesIO(zf.read("SystemStructure.ssd")))
        names = {}
        for comp in doc.iterfind("ssd:System/ssd:Elements/ssd:Component", NS):
            target = folder / comp.get("source").split("/")[-1]
            target.write_bytes(zf.read(comp.get("source")))
            names[comp.get("name")] = str(target)
    return names


def test_libcosim_matches_our_jacobi_master(table2_ssp, tmp_path):
    """Table 2, no tip mass, no noise, the whole slew: libcosim and our master stepping as libcosim does agree.

    libcosim's fixed-step algorithm is a Jacobi scheme (see scenarios/libcosim_runner.py for exactly
    what it does); our master's ``algorithm="jacobi"`` must reproduce it, initialisation and time
    points included.
    """
    pytest.importorskip("libcosimpy", reason="libcosimpy (the libcosim master) is not installed: "
                                             "pip install libcosimpy")
    out = tmp_path / "libcosim.npz"
    proc = subprocess.run([sys.executable, "-m", "scenarios.libcosim_runner", str(table2_ssp), "none",
                           "--out", str(out)], cwd=runner.REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"libcosim run failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr[-3000:]}"
    lc = dict(np.load(out))

    sc = load_scenario("table2")
    case = next(c for c in sc.cases if c.key == "none")
    setup = runner.prepare(sc, names=_extract_fmus(table2_ssp, tmp_path))
    with setup.open_master("jacobi") as m:
        ours = m.run(setup.case_parameters(case.parameters), setup.record, setup.n_steps, sc.step_size)
    assert ours["status"] == "ok", ours["message"]
    assert len(lc["time"]) == setup.n_steps + 1
    np.testing.assert_allclose(lc["time"], ours["time"], rtol=0, atol=1e-12)
    signals = [k for k in lc if k != "time"]
    assert set(signals) == {f"{i}.{v}" for i, v in setup.record}
    deltas = {k: float(np.max(np.abs(lc[k] - ours["signals"][k]))) for k in signals}
    worst = max(deltas, key=deltas.get)
    first = {k: int(np.argmax(np.abs(lc[k] - ours["signals"][k]) > SERIES_TOLERANCE)) for k in signals
             if deltas[k] > SERIES_TOLERANCE}
    assert deltas[worst] <= SERIES_TOLERANCE, (
        f"libcosim vs our jacobi master: max |delta| {deltas[worst]:.3g} in {worst}; "
        f"first sample above {SERIES_TOLERANCE:g} per signal: {dict(sorted(first.items(), key=lambda x: x[1])[:5])}")


def test_open_loop_metrics_in_libcosim_equal_the_default_mode(tmp_path):
    """Feedforward only with the payload: libcosim's table metrics are within 1 % of our default (Gauss-Seidel) run.

    Open loop, the stepping order cannot matter (the torque depends on time only), so the
    two masters must agree on the physics; the closed loop is another matter (next test).
    """
    pytest.importorskip("libcosimpy", reason="libcosimpy (the libcosim master) is not installed: "
                                             "pip install libcosimpy")
    from scenarios.metrics import METRICS, table_metrics

    sc = load_scenario("compare_ff_fb")
    case = next(c for c in sc.cases if c.key == "ff_tip")
    ssp = export_ssp(sc, tmp_path)
    out = tmp_path / "libcosim.npz"
    proc = subprocess.run([sys.executable, "-m", "scenarios.libcosim_runner", str(ssp), case.key, "--out", str(out)],
                          cwd=runner.REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"libcosim run failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr[-3000:]}"
    lc = dict(np.load(out))
    setup = runner.prepare(sc, names=case.fmus)
    with setup.open_master() as m:
        _, ours = runner.simulate_case(setup, m, case.parameters)
    theta = np.column_stack([lc[f"plant.theta{i}"] for i in range(1, 12)])
    omega = np.column_stack([lc[f"plant.omega{i}"] for i in range(1, 12)])
    tau = np.column_stack([lc["controller.tau1"], lc["controller.tau2"]])
    theirs = table_metrics(tau, theta, omega, setup.desired["theta"], setup.desired["omega"])
    for key in METRICS:
        assert theirs[key] == pytest.approx(ours[key], rel=0.01), key


def test_closed_loop_under_libcosim_stepping_is_unstable():
    """Why the closed loop cannot agree across masters: Jacobi stepping delays the torque by two samples.

    Our "jacobi" mode reproduces libcosim bit for bit (test above); with the two-sample delay
    (plant -> sensors -> controller, one sample per feedthrough FMU) the gamma = 0.1 loop that
    tracks to 0.002 deg rms under Gauss-Seidel stepping grows unstable and saturates the motors.
    """
    sc = load_scenario("table2")
    case = sc.cases[0]
    setup = runner.prepare(sc)
    metrics = {}
    for algorithm in ("gauss-seidel", "jacobi"):
        with setup.open_master(algorithm) as m:
            _, metrics[algorithm] = runner.simulate_case(setup, m, case.parameters)
    assert metrics["gauss-seidel"]["rms_position_error"] < 0.01
    assert metrics["jacobi"]["rms_position_error"] > 100 * metrics["gauss-seidel"]["rms_position_error"]
    assert metrics["jacobi"]["peak_tau1"] == pytest.approx(7.0)  # saturated
