"""From an installed package (no checkout beside it), a command that rewrites committed files refuses at once,
with the reason and exit 2, and writes nothing (issue 23: "works or refuses in under a second with a reason").

The package is the project's packages copied into a folder with nothing else (as ``pip install .`` lays them
out in site-packages: no build_fmus.py, README.md or docs/), run in a fresh process from another folder.
benchmarks/bench_installed.py runs every documented command that way, from a real ``pip install .``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGES = ("flexarm", "scenarios", "fmu_build", "fmus")


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    site = tmp_path_factory.mktemp("site-packages")
    for name in PACKAGES:
        shutil.copytree(REPO / name, site / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    return site


def _snapshot(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


@pytest.mark.parametrize("command", [
    ["flexarm.lqr", "--write"],
    ["flexarm.regenerate"],
    ["scenarios.reports.reexamine"],
    ["scenarios.reports.ilc_report"],
    ["scenarios.reports.ilc_report", "--check"],
    ["scenarios.ilc.floor"],
    ["scenarios.reports.scheme_accuracy", "--check"],
    ["scenarios.reports.scheme_accuracy", "--write", "--part", "horizons"],
    ["scenarios.reports.module_map", "--write"],
    ["fmu_build", "--write-doc"],  # flexarm-build-fmus --write-doc
])
def test_commands_that_rewrite_committed_files_refuse_outside_a_checkout(site, tmp_path, command):
    before = _snapshot(site)
    env = {**os.environ, "PYTHONPATH": str(site)}
    proc = subprocess.run([sys.executable, "-m", *command], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "installed package" in proc.stderr and "clone of the repository" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr
    after = {k: v for k, v in _snapshot(site).items() if "__pycache__" not in k}
    assert after == {k: v for k, v in before.items() if "__pycache__" not in k}  # nothing written


def test_every_data_file_of_the_packages_is_installed_with_them():
    """A file the packages read at run time (a C source compiled on first use, a scenario, data) must be in
    pyproject.toml's package-data, or ``pip install .`` leaves it out: scenarios/master/step_loop.c was."""
    import fnmatch
    import tomllib

    declared = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    missing = []
    for package in PACKAGES:
        patterns = declared.get(package, [])
        for path in sorted((REPO / package).rglob("*")):
            if not path.is_file() or path.suffix in (".py", ".pyc") or "__pycache__" in path.parts:
                continue
            rel = path.relative_to(REPO / package).as_posix()
            # setuptools' glob: '*' does not cross a folder
            if not any(fnmatch.fnmatch(rel, p) and rel.count("/") == p.count("/") for p in patterns):
                missing.append(f"{package}/{rel}")
    assert missing == []
