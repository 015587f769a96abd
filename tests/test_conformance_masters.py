"""One exported archive per case, one answer in every FMI master (issues 21 and 31): the conformance suite.

The masters live in :mod:`scenarios.conformance.hosts` and the matrix in :mod:`scenarios.conformance.matrix`
(``python -m scenarios conformance`` runs all of it, about an hour, and writes the table of
docs/masters-and-ssp.md). Here CI runs a part of it for real: each case is exported once, with nothing
stepping-specific in the archive, and run in every master with no parameter changed between them:

* our master, Gauss-Seidel (the reference) and Jacobi;
* libcosim, Ecos and fmpy's ``simulate_ssp`` (Jacobi; ``simulate_ssp`` feeds 0 to every connected input
  over its first step, which the FMUs recognise as "no sample yet" by the sample indices, and the controllers
  start the slew a sample later, which its figures compare with);
* a host with OMSimulator's semantics (Gauss-Seidel in the SSD's connection order, the last step the
  rounding remainder of the stop time), and the hostile host (double reads around every set, inputs in a
  random order, three initialisation rounds) in both steppings;
* fmpy's ``simulate_fmu``: the plant alone, driven by the reference run's torques.

Acceptance (issue 31): rms position and rms velocity error within 5 % or 0.005 deg (0.05 deg/s), whichever is
larger, of our master's Gauss-Seidel figure; both FMU kinds.
"""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path

import pytest
from fmu_harness import built_fmus
from lxml import etree
from native_fmus import native_fmus

from scenarios.config import load_scenario
from scenarios.conformance import matrix as conformance
from scenarios.conformance.hosts import omsimulator
from scenarios.conformance.ssp import NS, export_ssp, validate_ssp

#: The cases CI runs (kind -> scenario -> cases): the paper's law and the LQG (one Kalman filter, and the payload
#: bank under noise) in the native kind (the Python kind's laws are held to their twins elsewhere, and its runs
#: in our master and the hostile host both ways are in tests/test_hostile_host.py; CI's time is short). The
#: published matrix (docs/masters-and-ssp.md, ``python -m scenarios conformance --write``) runs every native case;
#: its inputs are checked against this checkout below. FLEXARM_CONFORMANCE_ALL=1 runs every case of both kinds.
CASES = {"native": {"table2": ("none",), "lqg": ("none", "noise_bank")}}
if os.environ.get("FLEXARM_CONFORMANCE_ALL"):
    CASES = {kind: {name: tuple(c.key for c in load_scenario(name).cases) for name in conformance.SCENARIOS}
             for kind in conformance.KINDS}
#: The masters here: all of them, OMSimulator where it is installed (FLEXARM_OMSIMULATOR; not in CI).
MASTERS = [m for m in conformance.MASTERS if m != "omsimulator" or omsimulator() is not None]


@pytest.fixture(scope="module")
def folders() -> dict[str, Path]:
    native = native_fmus()
    return {"fmu_dir": next(iter(built_fmus().values())).parent,
            "native_fmu_dir": next(iter(native.values())).parent}


@pytest.fixture(scope="module")
def archives(folders, tmp_path_factory) -> dict[tuple[str, str, str], Path]:
    """(kind, scenario, case) -> the exported archive."""
    out = {}
    for kind, scenarios in CASES.items():
        for name, cases in scenarios.items():
            written = export_ssp(load_scenario(name), tmp_path_factory.mktemp(f"ssp_{kind}_{name}"), build=False,
                                 cases=list(cases), kind=kind, **folders)
            out.update({(kind, name, key): path for key, path in written.items()})
    return out


def test_the_shipped_cases_exist():
    for scenarios in CASES.values():
        for name, cases in scenarios.items():
            assert set(cases) <= {c.key for c in load_scenario(name).cases}, name


def test_every_archive_is_valid_and_names_a_fixed_step_master_for_each_engine(archives):
    for (kind, name, case), path in archives.items():
        assert validate_ssp(path) == [], (kind, name, case)
        doc = etree.parse(io.BytesIO(zipfile.ZipFile(path).read("SystemStructure.ssd")))
        fixed = doc.find("ssd:System/ssd:Annotations/ssc:Annotation[@type='org.openmodelica']/oms:Annotations/"
                         "oms:SimulationInformation/oms:FixedStepMaster", NS)
        osp = doc.find("ssd:DefaultExperiment/ssd:Annotations/ssc:Annotation[@type='com.opensimulationplatform']/"
                       "osp:Algorithm/osp:FixedStepAlgorithm", NS)
        assert float(fixed.get("stepSize")) == float(osp.get("baseStepSize")) == load_scenario(name).step_size


ARCHIVES = [(kind, name, case) for kind, scenarios in CASES.items() for name, cases in scenarios.items()
            for case in cases]


@pytest.mark.parametrize(("kind", "name", "case"), ARCHIVES, ids=["-".join(a) for a in ARCHIVES])
def test_every_master_gives_our_gauss_seidel_figures(kind, name, case, archives):
    """Issue 31 acceptance: the same archive in every master, within 5 % or 0.005 deg / 0.05 deg/s.

    Every master outside :func:`scenarios.conformance.matrix.known_to_differ` must agree; those inside it are an
    expected failure while issue 31 is open (in the Jacobi masters: the paper's law's noise cases, the LQG's
    integral cases without payload; CI's subset runs neither)."""
    pytest.importorskip("ecospy", reason="ecospy is not installed: pip install ecospy (needs libtbb12)")
    pytest.importorskip("libcosimpy", reason="libcosimpy is not installed: pip install libcosimpy")
    ssp = archives[(kind, name, case)]
    cells = conformance.run_archive(ssp, name, kind, MASTERS)
    ref = cells[conformance.REFERENCE]
    assert "error" not in ref, ref
    print(f"\n{kind} {name}/{case}: {cells}")
    wrong = {m: c for m, c in cells.items() if m != conformance.REFERENCE and not conformance.judge(c, ref)}
    # the plant alone in simulate_fmu, driven by our torques, is our run: equal to the last digits that matter
    assert abs(cells["simulate_fmu"]["rms_position_error"] - ref["rms_position_error"]) <= \
        1e-6 * max(ref["rms_position_error"], 1e-3)  # both integrate the same binary on the same torques
    known = conformance.known_to_differ(conformance.has_loop_delay_parameter(ssp))
    assert not {m: c for m, c in wrong.items() if m not in known}, (ref, wrong)
    if wrong:
        pytest.xfail(f"issue 31, open: {sorted(wrong)} (conformance.known_to_differ): {ref} vs {wrong}")


def test_a_figure_outside_the_tolerance_is_marked_and_counted():
    """The table marks what differs: a cell 6 % off is bold with a cross, and the summary counts it."""
    ref = {"rms_position_error": 1.0, "rms_velocity_error": 10.0}
    doc = {"commit": "0" * 40, "masters": ["ours_gauss_seidel", "libcosim", "ecos"],
           "rows": [{"kind": "native", "scenario": "table2", "case": "none",
                     "masters": {"ours_gauss_seidel": ref,
                                 "libcosim": {"rms_position_error": 1.06, "rms_velocity_error": 10.0},
                                 "ecos": {"rms_position_error": 1.04, "rms_velocity_error": 10.4}}}]}
    text = conformance.render(doc)
    assert "**1.06 ✗**" in text and "| 1.04 |" in text
    assert "1 of 2 runs within" in text
    # the floor: 0.004 deg off a figure of 0.001 deg is within 0.005 deg
    assert conformance.judge({"rms_position_error": 0.005, "rms_velocity_error": 0.0},
                             {"rms_position_error": 0.001, "rms_velocity_error": 0.04})


def test_the_committed_matrix_is_this_checkouts(folders):
    """docs/masters-and-ssp.md's table is docs/conformance.json's, run on this checkout's FMUs and scenarios."""
    assert conformance.check(Path(folders["fmu_dir"]), Path(folders["native_fmu_dir"])) == []


def _loop_delays(ssp: Path) -> dict[str, str]:
    """The controller's loop_delay_samples in the three places an archive states it."""
    import json
    import re

    with zipfile.ZipFile(ssp) as zf:
        ssv = zf.read("resources/controller.ssv").decode()
        fmu = zipfile.ZipFile(io.BytesIO(zf.read("resources/controller.fmu")))
    md = etree.fromstring(fmu.read("modelDescription.xml"))
    start = md.find("ModelVariables/ScalarVariable[@name='loop_delay_samples']")[0].get("start")
    names = fmu.namelist()
    if "resources/flexarm_start_values.txt" in names:
        import struct

        lines = dict(ln.split(" ") for ln in fmu.read("resources/flexarm_start_values.txt").decode().splitlines())
        baked = struct.unpack(">d", bytes.fromhex(lines["loop_delay_samples"]))[0] \
            if "loop_delay_samples" in lines else None
    else:
        baked = json.loads(fmu.read("resources/flexarm_start_values.json")).get("loop_delay_samples")
    ssv_value = re.findall(r'name="loop_delay_samples"[^<]*<ssv:Integer value="(-?\d+)"', ssv)
    return {"start": start, "baked": None if baked is None else str(int(baked)),
            "ssv": ssv_value[0] if ssv_value else None}


@pytest.mark.parametrize("kind", ["native", "python"])
def test_no_archive_is_stepping_specific(kind, archives, folders, tmp_path):
    """Issue 31 item 3: a controller with loop_delay_samples has it automatic in every archive (the FMU's
    start value -1, nothing baked, nothing in the .ssv) whatever stepping its scenario names: lqg_jacobi's archive
    is lqg's."""
    automatic = {"start": "-1", "baked": None, "ssv": None}
    for name in ("lqg", "lqg_jacobi"):
        ssp = export_ssp(load_scenario(name), tmp_path / name, build=False, cases=["none"], kind=kind,
                         **folders)["none"]
        assert _loop_delays(ssp) == automatic, name
    for (k, name, case), ssp in archives.items():
        if k == kind and conformance.has_loop_delay_parameter(ssp):
            assert _loop_delays(ssp) == automatic, (name, case)
