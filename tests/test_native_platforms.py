"""The native FMUs on every platform: win64 run under wine, built from their sources, darwin64 as built.

darwin64 binaries are cross-compiled and checked for their format and exports
here; they cannot run on this Linux machine.
"""

from __future__ import annotations

import shutil
import subprocess
import zipfile

import numpy as np
import pytest
from fmpy import read_model_description
from native_fmus import compile_host, native_fmus, read_host_csv, run_fmpy, unpack_alone, wine_env

N_STEPS = 200


def _torques(tmp_path):
    csv = tmp_path / "tau.csv"
    rows = (f"{float(3.0 * np.sin(k / 50.0))!r},{float(np.cos(k / 23.0))!r}\n" for k in range(N_STEPS))
    csv.write_text("tau1,tau2\n" + "".join(rows))
    return csv


def _host_run(cmd, env=None):
    run = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    return read_host_csv(run.stdout[run.stdout.index("time,"):])


def _wine() -> str:
    wine = shutil.which("wine") or shutil.which("wine64")
    if wine is None:
        pytest.skip("wine is not installed (Debian: apt-get install wine64); the win64 binaries were built but "
                    "not run")
    return wine


@pytest.mark.parametrize("settings", [(), ("damping_ratio=0.02",), ("integrator=2",)],
                         ids=["rodas4", "damping", "exponential"])
def test_win64_binary_under_wine_matches_linux64(tmp_path, settings):
    wine = _wine()
    plant = native_fmus()["plant"]
    unz = unpack_alone(plant, tmp_path / "fmu")
    csv = _torques(tmp_path)
    args = [str(unz), "--steps", str(N_STEPS), "--inputs", str(csv), "--quiet", "--set", "payload_mass=0.275"]
    for setting in settings:  # the damping matrix (Jacobi, square roots) and the matrix exponential too
        args += ["--set", setting]
    linux_host = compile_host(tmp_path)
    win_host = compile_host(tmp_path, target="win64")
    header_l, linux = _host_run([str(linux_host), *args], env={})
    header_w, windows = _host_run([wine, str(win_host), *args, "--check-errors"], env=wine_env())
    assert header_l == header_w
    assert np.abs(linux[:, header_l.index("q1")]).max() > 0.01  # the arm moved
    np.testing.assert_array_equal(windows, linux)  # bit for bit: sin/cos are the FMU's own (portable_math.c)


def test_darwin64_binary_is_a_macho_library_exporting_fmi2(tmp_path):
    plant = native_fmus()["plant"]
    with zipfile.ZipFile(plant) as z:
        lib = z.read("binaries/darwin64/FlexarmPlantNative.dylib")
    assert lib[:4] == bytes.fromhex("cafebabe")  # universal (x86_64 + arm64: tests/test_native_build_anywhere.py)
    for symbol in (b"_fmi2Instantiate", b"_fmi2DoStep", b"_fmi2GetReal", b"_fmi2SetFMUstate"):
        assert lib.count(symbol) >= 2  # in both slices


def test_fmu_compiled_from_its_sources_runs_like_the_shipped_binary(tmp_path):
    """A tool on another platform compiles <SourceFiles>: FMPy's build from sources, then a run."""
    build = pytest.importorskip("fmpy.build")
    if shutil.which("cmake") is None:
        pytest.skip("cmake is not installed (fmpy.build.build_platform_binary needs it)")
    plant = native_fmus()["plant"]
    unz = unpack_alone(plant, tmp_path / "src")
    shutil.rmtree(unz / "binaries")
    (tmp_path / "cmake-build").mkdir()
    build.build_platform_binary(unz.resolve(), build_dir=tmp_path / "cmake-build")
    md = read_model_description(str(unz))
    assert (unz / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so").is_file()
    inputs = lambda k: {"tau1": 3.0 * np.sin(k / 50.0), "tau2": np.cos(k / 23.0)}  # noqa: E731
    names, from_sources = run_fmpy(plant, N_STEPS, inputs, unzipdir=unz)
    _, shipped = run_fmpy(plant, N_STEPS, inputs)
    np.testing.assert_allclose(from_sources, shipped, rtol=0, atol=1e-9 * np.abs(shipped).max())
    assert np.abs(from_sources[:, names.index("q1")]).max() > 0.01


def test_every_native_fmu_runs_in_fmpy_simulate_with_no_options():
    """A tool user's first try: `fmpy simulate` with nothing set, on each native FMU."""
    from fmpy import simulate_fmu

    for name, fmu in native_fmus().items():
        md = read_model_description(str(fmu))
        result = simulate_fmu(str(fmu))
        assert abs(result["time"][-1] - float(md.defaultExperiment.stopTime)) < 1e-9, name
        if name == "controller_lqg":  # fmpy's own output interval (4 ms): the 1 ms filter samples inside the step
            assert np.diff(result["time"]).max() > 3.9e-3
        outputs = [v.name for v in md.modelVariables if v.causality == "output"]
        assert all(np.isfinite(result[n]).all() for n in outputs), name
