"""Test helpers for the native FMUs: one build per test process, runs in fmpy, the C host."""

from __future__ import annotations

import os
import shutil
import subprocess
import zipfile
from pathlib import Path

import fmpy
import numpy as np
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave
from fmu_harness import built_fmus

from fmu_build.native_build import NATIVE_FMUS, PLATFORMS

ROOT = Path(__file__).resolve().parents[1]
HOST_SOURCE = ROOT / "tests" / "native_host" / "fmi2_host.c"
FMI_HEADERS = Path(fmpy.__file__).parent / "c-code"
_BUILT: dict[str, Path] = {}


def native_fmus() -> dict[str, Path]:
    """Every native FMU (all platforms) in the checkout's build folder, rebuilt where stale, once per test process
    (as :func:`fmu_harness.built_fmus`)."""
    if not _BUILT:
        from fmu_build import build_native_all

        python = built_fmus()
        _BUILT.update(build_native_all({n: python[n] for n in NATIVE_FMUS}))
    return dict(_BUILT)


def unpack_alone(fmu: Path, folder: Path) -> Path:
    """The FMU copied alone into an empty folder and unpacked there; returns the unpacked folder."""
    folder.mkdir(parents=True, exist_ok=True)
    copy = folder / fmu.name
    shutil.copy2(fmu, copy)
    unpacked = folder / fmu.stem
    with zipfile.ZipFile(copy) as z:
        z.extractall(unpacked)
    return unpacked


def compile_host(out: Path, target: str | None = None) -> Path:
    """tests/native_host/fmi2_host.c compiled with gcc (target None) or Zig's cc for `target` (e.g. win64)."""
    if target is None:
        exe = out / "fmi2_host"
        cmd = ["gcc", "-std=c11", "-O2", "-I", str(FMI_HEADERS), "-o", str(exe), str(HOST_SOURCE), "-ldl", "-lm"]
    else:
        from fmu_build.native_build import zig_command

        exe = out / "fmi2_host.exe"
        cmd = [*zig_command(), "-target", PLATFORMS[target][0], "-O2", "-g0", "-s", "-I", str(FMI_HEADERS),
               "-o", str(exe), str(HOST_SOURCE)]
    subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=out)
    return exe


def read_host_csv(text: str) -> tuple[list[str], np.ndarray]:
    lines = [ln for ln in text.replace("\r", "").splitlines() if ln]
    return lines[0].split(","), np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]])


def run_fmpy(fmu: Path, n_steps: int, inputs=None, params=None, outputs=None, dt: float = 1e-3,
             unzipdir: Path | None = None, inputs_in_initialization: bool = True) -> tuple[list[str], np.ndarray]:
    """Step an FMU in fmpy: params in initialisation mode, inputs(k) -> {name: value} before reading at t_k.

    Returns the output names and rows (n_steps + 1, n_outputs) at t_0 ... t_n, read after setting the inputs.
    """
    md = read_model_description(str(fmu))
    unzipdir = unzipdir if unzipdir is not None else Path(fmpy.extract(str(fmu)))
    var = {v.name: v for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=str(unzipdir), modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="run")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    for name, value in (params or {}).items():
        v = var[name]
        setter = {"Real": slave.setReal, "Integer": slave.setInteger, "Enumeration": slave.setInteger,
                  "Boolean": slave.setBoolean, "String": slave.setString}[v.type]
        setter([v.valueReference], [value])
    if inputs is not None and inputs_in_initialization:
        _set(slave, var, inputs(0))
    slave.exitInitializationMode()
    names = outputs or [v.name for v in md.modelVariables if v.causality == "output"]
    vrs = [var[n].valueReference for n in names]
    rows = []
    for k in range(n_steps + 1):
        if inputs is not None:
            _set(slave, var, inputs(k))
        rows.append(slave.getReal(vrs))
        if k < n_steps:
            slave.doStep(k * dt, dt)
    slave.terminate()
    slave.freeInstance()
    return names, np.array(rows)


def _set(slave, var, values: dict) -> None:
    if values:
        slave.setReal([var[n].valueReference for n in values], [float(x) for x in values.values()])


def clean_env() -> dict:
    """An environment with nothing in it (as `env -i`)."""
    return {}


def wine_env() -> dict:
    return {**os.environ, "WINEDEBUG": "-all"}


# -- the state fuzz harness (tests/native_host/state_fuzz.c), shared by the native and the Python kind's tests ----
STATE_FUZZ_SANITIZE = ("-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer", "-g")
STATE_FUZZ_CHECKS = {"serialised_bit_flips_and_lengths", "in_memory_bit_flips", "foreign_state_bytes_instance",
                     "freed_or_null_state", "sound_state_refused", "freed_instance"}


def run_state_fuzz(specs: list[str], folder: Path, env: dict, n_fmus: int) -> list[list[str]]:
    """Build the harness under the sanitizers, run it on `specs` ('LIB,DIR,GUID[,BYTES]') and check that no
    sanitizer reported, every attack of every check was refused (0 accepted) for each of the `n_fmus` FMUs, and
    each FMU's state went to every other; the rows '<fmu> <check> <tried> <accepted>'."""
    harness = folder / "state_fuzz"
    subprocess.run(["gcc", "-std=c11", *STATE_FUZZ_SANITIZE, "-O1", "-I", str(FMI_HEADERS), "-o", str(harness),
                    str(ROOT / "tests" / "native_host" / "state_fuzz.c"), "-ldl"], check=True, capture_output=True,
                   text=True)
    env = {**env, "UBSAN_OPTIONS": "halt_on_error=1:print_stacktrace=1"}
    run = subprocess.run([str(harness), *specs], capture_output=True, text=True, env=env, timeout=900, cwd=folder)
    assert "Sanitizer" not in run.stderr and "runtime error" not in run.stderr, run.stderr[-4000:]
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    rows = [line.split() for line in run.stdout.splitlines() if not line.startswith("messages")]
    seen: dict[str, set[str]] = {}
    for fmu, check, tried, accepted in rows:
        assert int(tried) > 0 and int(accepted) == 0, (fmu, check, tried, accepted)
        seen.setdefault(fmu, set()).add(check)
    assert len(seen) == n_fmus and all(checks == STATE_FUZZ_CHECKS for checks in seen.values()), seen
    # each FMU's state given to each of the others
    assert sum(check == "foreign_state_bytes_instance" for _, check, _, _ in rows) == n_fmus * (n_fmus - 1)
    return rows
