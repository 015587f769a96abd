"""Every FMU, copied alone into an empty folder, runs in a native (C) FMI host with only NumPy and SciPy.

The host is tests/native_host/fmi2_host.c, compiled here with gcc against
fmpy's FMI 2.0 headers: no Python in it. It runs in a process whose
environment sees neither this project nor this interpreter's site-packages:

* ``LD_PRELOAD`` = this interpreter's ``libpython3.11.so.1.0``;
* ``PYTHONHOME`` = a folder whose ``lib/python3.11`` holds links to the
  standard library *without* its ``site-packages`` (so neither the editable
  install of ``flexarm`` nor Numba nor fmpy is importable);
* ``PYTHONPATH`` = the site-packages of a virtual environment holding only
  NumPy and SciPy (the versions of this interpreter, so that the numbers
  can be compared exactly), made with ``python -m venv`` and ``pip``, and
  kept in ``build/standalone-venv/`` for the next run.

``PYTHONVERBOSE=1`` makes Python list every module it imports with its
file, which proves the isolation: ``flexarm`` comes from the FMU's
``resources``, nothing from the project or from this interpreter's
site-packages, no Numba. The outputs must equal, to 1e-12, those of the same
FMU run by fmpy (in a process with the project hidden, ``FLEXARM_NO_NUMBA=1``
so that both run the NumPy kernels).
"""

from __future__ import annotations

import contextlib
import csv
import fcntl
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import numpy as np
import pytest
import scipy
from fmpy import read_model_description
from fmu_harness import DT, SCENARIOS, built_fmus, choice, third_party_pythonpath

ROOT = Path(__file__).resolve().parents[1]
HOST_SOURCE = ROOT / "tests" / "native_host" / "fmi2_host.c"
N_STEPS = 150
PY_TAG = f"python{sys.version_info.major}.{sys.version_info.minor}"
VENV_DIR = ROOT / "build" / "standalone-venv" / f"{PY_TAG}-numpy{np.__version__}-scipy{scipy.__version__}"
#: What the venv's site-packages may hold besides NumPy and SciPy (pip's own installation).
_VENV_ALLOWED = re.compile(r"^(numpy|scipy)([-.].*)?$|^(pip|setuptools|pkg_resources|_distutils_hack)([-.].*)?$"
                           r"|^distutils-precedence\.pth$|^__pycache__$")


def _libpython() -> Path:
    if not sysconfig.get_config_var("Py_ENABLE_SHARED"):
        pytest.skip(f"{sys.executable} is built without a shared libpython (a native host needs one)")
    lib = Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("INSTSONAME")
    if not lib.is_file():
        pytest.skip(f"{lib} is missing (Debian/Ubuntu: apt-get install libpython{sys.version_info.major}."
                    f"{sys.version_info.minor})")
    return lib


@contextlib.contextmanager
def _locked(path: Path):
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # several test processes may share the checkout
        yield


def _make_venv() -> Path:
    """The venv's site-packages (made once, then reused while its contents stay as made)."""
    marker = VENV_DIR / "flexarm-standalone-ok"
    with _locked(VENV_DIR.parent / f".{VENV_DIR.name}.lock"):
        if not marker.is_file():
            shutil.rmtree(VENV_DIR, ignore_errors=True)
            venv = subprocess.run([sys.executable, "-m", "venv", str(VENV_DIR)], capture_output=True, text=True)
            if venv.returncode != 0:
                shutil.rmtree(VENV_DIR, ignore_errors=True)
                pytest.skip(f"'{sys.executable} -m venv' failed (Debian/Ubuntu: apt-get install "
                            f"{PY_TAG}-venv): {venv.stderr.strip()[-500:]}")
            pip = subprocess.run(
                [str(VENV_DIR / "bin" / "python"), "-m", "pip", "install", "--disable-pip-version-check",
                 "--no-input", "--only-binary=:all:", "--timeout", "60", f"numpy=={np.__version__}",
                 f"scipy=={scipy.__version__}"], capture_output=True, text=True, timeout=900)
            if pip.returncode != 0:
                shutil.rmtree(VENV_DIR, ignore_errors=True)
                tail = "\n".join((pip.stdout + pip.stderr).strip().splitlines()[-4:])
                pytest.skip(f"could not install numpy {np.__version__} and scipy {scipy.__version__} into a fresh "
                            f"venv (no network, or no such wheels on the index?):\n{tail}")
            marker.write_text("numpy and scipy installed\n")
        sp = subprocess.run([str(VENV_DIR / "bin" / "python"), "-c",
                             "import sysconfig; print(sysconfig.get_path('purelib'))"],
                            check=True, capture_output=True, text=True).stdout.strip()
    return Path(sp)


@pytest.fixture(scope="module")
def venv_site_packages() -> Path:
    sp = _make_venv()
    extra = sorted(p.name for p in sp.iterdir() if not _VENV_ALLOWED.match(p.name))
    assert not extra, f"the venv holds more than NumPy and SciPy: {extra}"
    return sp


@pytest.fixture(scope="module")
def python_home(tmp_path_factory) -> Path:
    """A PYTHONHOME with the standard library of this Python and no site-packages."""
    stdlib = Path(os.__file__).resolve().parent
    home = tmp_path_factory.mktemp("python_home")
    lib = home / "lib" / stdlib.name
    lib.mkdir(parents=True)
    for entry in stdlib.iterdir():
        if entry.name != "site-packages":
            (lib / entry.name).symlink_to(entry)
    return home


@pytest.fixture(scope="module")
def host(tmp_path_factory) -> Path:
    import fmpy

    if shutil.which("gcc") is None:
        pytest.fail("gcc is needed to build the native FMI host (and the FMUs)")
    exe = tmp_path_factory.mktemp("native_host") / "fmi2_host"
    subprocess.run(["gcc", "-std=c11", "-O2", "-Wall", "-Wextra", "-Werror",
                    f"-I{Path(fmpy.__file__).parent / 'c-code'}", "-o", str(exe), str(HOST_SOURCE), "-ldl"],
                   check=True, capture_output=True, text=True)
    return exe


def _alone(fmu: Path, folder: Path) -> Path:
    """Copy the FMU alone into an empty folder and unpack it there; the unpacked folder."""
    folder.mkdir()
    copy = folder / fmu.name
    shutil.copy2(fmu, copy)
    unpacked = folder / fmu.stem
    with zipfile.ZipFile(copy) as z:
        z.extractall(unpacked)
    return unpacked


def _scenario_files(name: str, md, folder: Path) -> tuple[list[str], Path]:
    """The --set arguments and the inputs CSV of SCENARIOS[name] for N_STEPS points."""
    variables = {v.name: v for v in md.modelVariables}
    sets = []
    for key, value in SCENARIOS[name]["params"].items():
        if isinstance(value, str) and variables[key].type == "Integer":
            value = choice(variables[key], value)
        text = {"Real": repr, "Integer": str, "Boolean": lambda b: "true" if b else "false",
                "String": str}[variables[key].type](value)
        sets += ["--set", f"{key}={text}"]
    rows = [SCENARIOS[name]["inputs"](k) for k in range(N_STEPS)]
    path = folder / "inputs.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(list(rows[0]))
        w.writerows([[repr(float(x)) for x in r.values()] for r in rows])
    return sets, path


#: Settings of the BLAS/LAPACK kernels (OPENBLAS_CORETYPE picks other kernels than autodetection, a few 1e-9
#: apart): the native host keeps them, as the fmpy reference does, so both processes compute with the same ones.
_BLAS_SETTINGS = ("OPENBLAS_", "OMP_", "MKL_", "GOTO_")


def _native_env(libpython: Path, home: Path, site_packages: Path, folder: Path, **extra) -> dict[str, str]:
    env = {"PATH": "/usr/bin:/bin", "HOME": str(folder), "LANG": "C.UTF-8", "LD_PRELOAD": str(libpython),
           "PYTHONHOME": str(home), "PYTHONPATH": str(site_packages), "PYTHONNOUSERSITE": "1",
           "PYTHONDONTWRITEBYTECODE": "1"}
    env.update({k: v for k, v in os.environ.items() if k.startswith(_BLAS_SETTINGS)})
    env.update(extra)
    return {k: v for k, v in env.items() if v is not None}


def _read_csv(text: str) -> tuple[list[str], np.ndarray]:
    lines = [ln for ln in text.splitlines() if ln and not ln.startswith("check-errors:")]
    return lines[0].split(","), np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]])


# The same sequence as fmi2_host, by fmpy: setup at 0, parameters in initialisation mode, then at each
# point set the inputs of row k, read the outputs, step. `python -I -S` ignores PYTHON* variables, the
# user site and site-packages processing, so the editable install's import hook for `flexarm` (a .pth
# file) is not installed; the site-packages folders are then appended as plain paths for fmpy and NumPy,
# and the only `flexarm` left is the FMU's own.
_FMPY_RUN = r"""
import csv, json, sys
args = json.loads(sys.argv[1])
import importlib.util
assert importlib.util.find_spec("flexarm") is None, "flexarm importable outside the FMU"
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave
md = read_model_description(args["dir"])
v = {x.name: x for x in md.modelVariables}
fmu = FMU2Slave(guid=md.guid, unzipDirectory=args["dir"], modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName="fmpy")
fmu.instantiate()
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
for name, value in args["params"].items():
    setter = {"Real": fmu.setReal, "Integer": fmu.setInteger, "Boolean": fmu.setBoolean, "String": fmu.setString}
    setter[v[name].type]([v[name].valueReference], [value])
fmu.exitInitializationMode()
with open(args["inputs"]) as f:
    rows = list(csv.reader(f))
in_vr = [v[n].valueReference for n in rows[0]]
out_names = [x.name for x in md.modelVariables if x.causality == "output" and x.type == "Real"]
out_vr = [v[n].valueReference for n in out_names]
n, dt, result = args["steps"], args["dt"], []
for k in range(n + 1):
    if k < n:
        fmu.setReal(in_vr, [float(x) for x in rows[1 + min(k, len(rows) - 2)]])
    result.append([k * dt] + fmu.getReal(out_vr))
    if k < n:
        fmu.doStep(k * dt, dt)
fmu.terminate()
fmu.freeInstance()
import flexarm._kernels
with open(args["out"], "w") as f:
    json.dump({"names": ["time"] + out_names, "rows": result, "flexarm": flexarm._kernels.__file__,
               "numba": flexarm._kernels.HAVE_NUMBA}, f)
"""


def _fmpy_reference(unpacked: Path, params: dict, inputs: Path, out: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    env["FLEXARM_NO_NUMBA"] = "1"
    # -S: no site, so no .pth (the editable 'flexarm'); this interpreter's import path minus the project
    env["PYTHONPATH"] = third_party_pythonpath()
    args = {"dir": str(unpacked), "params": params, "inputs": str(inputs), "steps": N_STEPS,
            "dt": DT, "out": str(out)}
    proc = subprocess.run([sys.executable, "-S", "-s", "-c", _FMPY_RUN, json.dumps(args)], cwd=unpacked.parent,
                          env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(out.read_text())


def _imports(stderr: str) -> tuple[set[str], set[str]]:
    """Module names and file paths Python reported importing (PYTHONVERBOSE=1)."""
    modules = set(re.findall(r"^import '([\w.]+)'", stderr, re.M))
    paths = set(re.findall(r"(/[^\s'\"]+?\.(?:py|pyc|so))\b", stderr))
    return modules, paths


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_fmu_alone_in_a_native_host_equals_fmpy(name, host, venv_site_packages, python_home, tmp_path):
    fmu = built_fmus()[name]
    unpacked = _alone(fmu, tmp_path / "alone")
    md = read_model_description(str(fmu))
    sets, inputs = _scenario_files(name, md, tmp_path)
    libpython = _libpython()
    env = _native_env(libpython, python_home, venv_site_packages, unpacked.parent, PYTHONVERBOSE="1")
    proc = subprocess.run([str(host), str(unpacked), "--steps", str(N_STEPS), "--dt", repr(DT), *sets,
                           "--inputs", str(inputs), "--check-errors", "--quiet"],
                          cwd=unpacked.parent, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    checks = [ln for ln in proc.stdout.splitlines() if ln.startswith("check-errors:")]
    has_input = any(v.causality == "input" for v in md.modelVariables)  # the reference FMU has none: 2 fewer checks
    assert len(checks) >= (9 if has_input else 7) and all("(as expected)" in ln for ln in checks), checks

    # Isolation: the FMU's own flexarm, NumPy and SciPy from the venv, nothing else from outside.
    modules, paths = _imports(proc.stderr)
    own = (unpacked / "resources").resolve()
    package = json.loads((own / "flexarm_bundle.json").read_text())["package"]  # its private name
    assert package in modules and "numpy" in modules and "flexarm" not in modules
    assert not {m for m in modules if m.split(".")[0] in ("numba", "fmpy", "pythonfmu_tests", "scenarios")}
    flexarm_files = {p for p in paths if f"/{package}/" in p}
    assert flexarm_files and all(Path(p).resolve().is_relative_to(own) for p in flexarm_files), flexarm_files
    stdlib = Path(os.__file__).resolve().parent
    allowed = (own, venv_site_packages.resolve(), stdlib)
    outside = sorted(p for p in paths if not any(Path(p).resolve().is_relative_to(a) for a in allowed)
                     or Path(p).resolve().is_relative_to(stdlib / "site-packages"))
    assert not outside, f"imported from outside the FMU, the venv and the standard library: {outside[:5]}"

    names, native = _read_csv(proc.stdout)
    variables = {v.name: v for v in read_model_description(str(unpacked)).modelVariables}
    params = {k: choice(variables[k], v) if isinstance(v, str) else v for k, v in SCENARIOS[name]["params"].items()}
    reference = _fmpy_reference(unpacked, params, inputs, tmp_path / "fmpy.json")
    assert reference["numba"] is False
    assert names == reference["names"]
    expected = np.array(reference["rows"])
    assert native.shape == expected.shape == (N_STEPS + 1, len(names))
    diff = np.max(np.abs(native - expected))
    print(f"\n{name}: native host vs fmpy over {N_STEPS} steps, {len(names) - 1} outputs: max |diff| = {diff:.3g}")
    np.testing.assert_allclose(native, expected, rtol=0, atol=1e-12)
    assert np.ptp(native[:, 1:], axis=0).max() > 0  # the run is not trivial


def test_the_fmu_loads_python_itself_or_says_what_is_missing(host, venv_site_packages, python_home, tmp_path):
    """Without LD_PRELOAD the FMU's front end loads libpython itself; if it cannot, fmi2Instantiate says why."""
    unpacked = _alone(built_fmus()["plant"], tmp_path / "alone")
    libpython = _libpython()
    args = [str(host), str(unpacked), "--steps", "20", "--set", "tau1=1.5", "--out", "q1,q2"]
    preload = _native_env(libpython, python_home, venv_site_packages, tmp_path)
    by_preload = subprocess.run(args, env=preload, capture_output=True, text=True, timeout=300)
    assert by_preload.returncode == 0, by_preload.stderr[-2000:]
    itself = subprocess.run(args, env=_native_env(libpython, python_home, venv_site_packages, tmp_path,
                                                  LD_PRELOAD=None, FLEXARM_FMU_LIBPYTHON=str(libpython)),
                            capture_output=True, text=True, timeout=300)
    assert itself.returncode == 0, itself.stderr[-2000:]
    assert itself.stdout == by_preload.stdout
    assert f"loaded {libpython}" in itself.stderr
    missing = subprocess.run(args, env=_native_env(libpython, python_home, venv_site_packages, tmp_path,
                                                   LD_PRELOAD=None, FLEXARM_FMU_LIBPYTHON="/nonexistent/libpython.so"),
                             capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2  # the host's "could not instantiate", not a crash
    assert "Python 3.11" in missing.stderr and "LD_PRELOAD" in missing.stderr, missing.stderr


def test_a_broken_python_environment_is_an_error_not_a_crash(host, python_home, tmp_path):
    """No NumPy on the path, or a PYTHONHOME without a standard library: fmi2Instantiate fails with the reason.

    pythonfmu 0.7.0 alone crashes the host when the slave module cannot be imported, and Python ends
    the process when PYTHONHOME is wrong; the FMU's front end checks both first.
    """
    unpacked = _alone(built_fmus()["plant"], tmp_path / "alone")
    libpython = _libpython()
    args = [str(host), str(unpacked), "--steps", "3", "--out", "q1"]
    no_numpy = subprocess.run(args, env=_native_env(libpython, python_home, tmp_path / "empty", tmp_path),
                              capture_output=True, text=True, timeout=120)
    assert no_numpy.returncode == 2, (no_numpy.returncode, no_numpy.stderr[-2000:])  # not a signal
    assert "No module named 'numpy'" in no_numpy.stderr and "PYTHONPATH" in no_numpy.stderr, no_numpy.stderr
    no_home = subprocess.run(args, env=_native_env(libpython, tmp_path / "nowhere", tmp_path / "empty", tmp_path),
                             capture_output=True, text=True, timeout=120)
    assert no_home.returncode == 2, (no_home.returncode, no_home.stderr[-2000:])
    assert "is not the prefix of a Python 3.11" in no_home.stderr, no_home.stderr


@pytest.mark.parametrize("damage", ["runtime", "missing", "altered", "chain"])
def test_an_fmu_that_cannot_start_says_why_at_error_level(host, venv_site_packages, python_home, tmp_path, damage):
    """Issue 12: fmi2Instantiate returns NULL after an fmi2Error message naming what is missing and the remedy.

    With loggingOn = false: the message must not depend on the host's debug setting.
    """
    name = "controller" if damage == "chain" else "plant"
    unpacked = _alone(built_fmus()[name], tmp_path / "alone")
    libpython = _libpython()
    env = _native_env(libpython, python_home, venv_site_packages, tmp_path)
    package = json.loads((unpacked / "resources" / "flexarm_bundle.json").read_text())["package"]
    data = unpacked / "resources" / package / "data"
    if damage == "runtime":
        env = _native_env(libpython, python_home, venv_site_packages, tmp_path, LD_PRELOAD=None,
                          FLEXARM_FMU_LIBPYTHON="/nonexistent/libpython.so")
        expected = ["/nonexistent/libpython.so", "LD_PRELOAD", "FLEXARM_FMU_LIBPYTHON"]
    elif damage == "missing":
        (data / "sandia_arm.toml").unlink()
        expected = [f"resources/{package}/data/sandia_arm.toml is missing", "build_fmus.py"]
    elif damage == "altered":
        path = data / "sandia_arm.toml"
        path.write_text(path.read_text() + "\n# edited\n")
        expected = [f"resources/{package}/data/sandia_arm.toml differs", "flexarm_bundle.json", "build_fmus.py"]
    else:  # a gain file recording another trajectory than the one bundled, and a manifest that agrees with both
        gains = data / "gains" / "gamma0.1_200ms.json"
        meta = json.loads(gains.read_text())
        meta["trajectory_sha256"] = "0" * 64
        gains.write_text(json.dumps(meta))
        manifest = unpacked / "resources" / "flexarm_bundle.json"
        info = json.loads(manifest.read_text())
        info["data_sha256"]["gains/gamma0.1_200ms.json"] = hashlib.sha256(gains.read_bytes()).hexdigest()
        manifest.write_text(json.dumps(info))
        expected = ["gains/gamma0.1_200ms.json records trajectory_sha256", "flexarm/data/trajectory.npz",
                    "python -m flexarm.lqr --write", "build_fmus.py"]
    proc = subprocess.run([str(host), str(unpacked), "--steps", "2", "--out", "tau1" if name != "plant" else "q1",
                           "--logging-off"], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])  # NULL from fmi2Instantiate, not a crash
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("[Error]") and "(logStatusError)" in ln]
    assert errors, proc.stderr[-2000:]
    text = "\n".join(proc.stderr.splitlines())
    assert all(e in text for e in expected), proc.stderr[-3000:]
    assert "fmi2Instantiate failed" in proc.stderr
