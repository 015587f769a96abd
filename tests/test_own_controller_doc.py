"""Issue 36: docs/own-controller.md covers a C FMU completely: its own code blocks (the C file, the model
description, the build script) build a working controller FMU, which tracks Table 2."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "own-controller.md"
#: The examples' bound on Table 2's rms position error (tests/test_own_controller.py), deg: the same law.
RMS_BOUND_DEG = 0.05


def doc_files() -> dict[str, str]:
    """File name -> text of every fenced block of the doc that names its file (``file: NAME`` in its first lines)."""
    out = {}
    for block in re.findall(r"```[a-z]*\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S):
        m = re.search(r"file: ([\w.]+)", "\n".join(block.splitlines()[:2]))
        if m:
            out[m[1]] = block
    return out


def test_the_doc_names_the_three_files():
    assert sorted(doc_files()) == ["build.sh", "modelDescription.xml", "mypd.c"]


@pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("zip") is None, reason="needs gcc and zip")
def test_the_documented_c_fmu_builds_and_tracks_table2(tmp_path):
    import fmpy

    from scenarios.config import load_scenario, select_cases
    from scenarios.run import runner

    for name, text in doc_files().items():
        (tmp_path / name).write_text(text)
    proc = subprocess.run(["sh", "build.sh"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and "warning" not in proc.stderr, proc.stderr  # -Wall -Wextra: clean
    fmu = tmp_path / "MyPD.fmu"
    md = fmpy.read_model_description(str(fmu), validate=True)
    assert md.coSimulation.modelIdentifier == "MyPD"
    r = runner.run_scenario(select_cases(load_scenario("table2"), ["none"]), tmp_path / "out",
                            controller=str(fmu), progress=False)[0]
    assert r.status == "ok" and r.verdict["verdict"] == "stable", r.message
    assert r.metrics["rms_position_error"] < RMS_BOUND_DEG, r.metrics
    assert 5.0 < r.metrics["peak_tau1"] < 7.0  # the feedforward arrived from the reference FMU
