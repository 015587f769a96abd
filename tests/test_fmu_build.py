"""The packaged build tooling (fmu_build): lean FMU files, pinned pythonfmu, the data chain, default folders."""

from __future__ import annotations

import json
import os
import shutil
import stat
import sysconfig
import zipfile
from pathlib import Path

import pytest
from fmu_harness import built_fmus

import fmu_build
from fmu_build import package, registry
from fmu_build.compile import BuildError

#: Never in an FMU: optimiser code, figures, pythonfmu's builder and tools.
FORBIDDEN = ("resources/flexarm/trajectory.py", "resources/flexarm/calibration.py", "resources/pythonfmu/builder.py",
             "resources/pythonfmu/csvbuilder.py", "resources/pythonfmu/deploy.py")


def _members(fmu: Path) -> list[str]:
    """The FMU's files, its bundled flexarm (under the private name of its build, fmu_build/isolate.py) shown as
    ``resources/flexarm/``."""
    with zipfile.ZipFile(fmu) as z:
        package = json.loads(z.read("resources/flexarm_bundle.json"))["package"]
        return [m.replace(f"resources/{package}/", "resources/flexarm/", 1) for m in z.namelist()]


@pytest.mark.parametrize("name", list(registry.FMUS))
def test_each_fmu_carries_only_what_it_needs(name):
    fmu = built_fmus()[name]
    members = _members(fmu)
    assert not [m for m in members if m in FORBIDDEN or m.endswith((".png", ".pyc"))], members
    runtime = {m.rsplit("/", 1)[1] for m in members if m.startswith("resources/pythonfmu/")}
    assert runtime == set(package.PYTHONFMU_RUNTIME)  # its __init__ too (rewritten without the builder)
    gains = sorted(m.rsplit("/", 1)[1] for m in members if m.startswith("resources/flexarm/data/gains/"))
    if name in ("controller", "controller_fb"):
        assert gains and not [g for g in gains if g.startswith("dlqr-")]
    elif name == "controller_dlqr":
        assert gains and all(g.startswith("dlqr-") for g in gains)
    else:  # the plant, the sensors and the feedforward need no gains
        assert gains == []
    tracks = name.startswith("controller") or name == "reference"
    assert ("resources/flexarm/data/trajectory.npz" in members) == tracks
    mode = stat.S_IMODE(fmu.stat().st_mode)
    umask = os.umask(0)
    os.umask(umask)
    assert mode == 0o644 & ~umask, oct(mode)  # 0644 under the usual umasks (022, 002)
    print(f"\n{name}.fmu: {fmu.stat().st_size / 1e3:.0f} kB, {len(members)} files")
    with zipfile.ZipFile(fmu) as z:  # the LQG's designs (Kalman and LQR per schedule point) are its own data
        designs = sum(i.compress_size for i in z.infolist() if "/data/lqg/" in i.filename)
    # every FMU bundles the union of the FMUs' flexarm modules (about 300 kB with its binaries): the bound is there
    # to catch data that does not belong, the 0.4 MB trajectory or the gains, not a module more
    assert fmu.stat().st_size - designs < (900e3 if tracks else 320e3)


def test_the_front_end_loads_the_libpython_of_the_building_python():
    name = sysconfig.get_config_var("INSTSONAME")
    with zipfile.ZipFile(built_fmus()["plant"]) as z:
        shim = z.read("binaries/linux64/FlexarmPlant.so")
    assert name.encode() in shim


def test_the_build_refuses_a_pythonfmu_other_than_the_pinned_one(monkeypatch):
    import importlib.metadata

    monkeypatch.setattr(importlib.metadata, "version", lambda dist: "0.7.1" if dist == "pythonfmu" else "0")
    with pytest.raises(BuildError, match=r"pythonfmu 0\.7\.1 is installed.*pythonfmu==0\.7\.0"):
        package.check_pythonfmu()


def test_the_build_refuses_data_whose_sha256_chain_does_not_verify(tmp_path, monkeypatch):
    copy = tmp_path / "flexarm"
    shutil.copytree(registry.FLEXARM_DIR / "data", copy / "data")
    package.check_data_chain()  # the committed data verify
    gains = copy / "data" / "gains" / "gamma1_200ms.json"
    meta = json.loads(gains.read_text())
    meta["trajectory_sha256"] = "f" * 64
    gains.write_text(json.dumps(meta))
    monkeypatch.setattr(package, "FLEXARM_DIR", copy)
    with pytest.raises(BuildError) as exc:
        package.check_data_chain()
    text = str(exc.value)
    assert "gains/gamma1_200ms.json records trajectory_sha256" in text and "flexarm/data/trajectory.npz" in text
    assert "python -m flexarm.lqr --write" in text and "no FMU is built" in text


def test_default_output_folder_follows_the_environment_then_the_current_directory(tmp_path, monkeypatch):
    monkeypatch.delenv(registry.OUT_DIR_ENV, raising=False)
    monkeypatch.chdir(tmp_path)
    assert fmu_build.default_out_dir() == tmp_path / "build" / "fmus"
    monkeypatch.setenv(registry.OUT_DIR_ENV, str(tmp_path / "elsewhere"))
    assert fmu_build.default_out_dir() == tmp_path / "elsewhere"


def test_entry_point_is_thin_and_sources_are_found_from_the_package():
    top = Path(registry.SOURCES).parent / "build_fmus.py"
    if top.is_file():  # a checkout (an installed package has only fmu_build)
        assert len(top.read_text().splitlines()) <= 150
    assert all(spec.script.is_file() for spec in registry.FMUS.values())
    assert registry.SHIM_SOURCES and all(p.is_file() for p in registry.SHIM_SOURCES)


def test_a_long_step_prints_a_heartbeat_and_stops_with_it(capsys):
    """Issue 34: no silence over 10 s on a first run. A step wrapped in heartbeat() prints a line every `every`
    seconds while it runs (here a sleep, which holds no lock), and none once it has ended."""
    import time

    from fmu_build.progress import heartbeat

    with heartbeat("compiling X", every=0.05):
        time.sleep(0.3)
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) >= 3 and all(ln.startswith("fmu_build: compiling X: still at it, ") for ln in lines), lines
    time.sleep(0.15)
    assert capsys.readouterr().err == ""
