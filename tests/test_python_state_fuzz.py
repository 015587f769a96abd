"""Sealed FMU states of the Python FMUs, fuzzed under AddressSanitizer and UBSan (issue 26, the Python kind).

The same harness as tests/test_native_state_fuzz.py (tests/native_host/state_fuzz.c) loads every Python FMU, its
C front end (fmus/common/fmi2_shim*.c and the live-handle table it shares with the native FMUs) compiled with
``gcc -fsanitize=address,undefined``: every bit of each serialised state and of the front end's in-memory state
flipped, each FMU's state, bytes and instance given to every other FMU, freed states used, each instance freed
twice. Every attack must be refused with fmi2Error (0 accepted), no sanitizer may report anything, and each
FMU's own states must still restore it exactly. (Python and the extension modules are not instrumented: the
sanitizers watch the front end and what it is given, which is where a host's mistakes land.)
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import sysconfig
import zipfile
from pathlib import Path

import numpy
import pytest
from fmpy import read_model_description
from fmu_harness import built_fmus
from native_fmus import STATE_FUZZ_SANITIZE, run_state_fuzz

from fmu_build.compile import compile_shim
from fmu_build.registry import FMUS

#: sizeof(State) in fmus/common/fmi2_shim.h (magic, state, two times, pythonfmu's state, seal); a static assert
#: there keeps the two in step.
SHIM_STATE_BYTES = 40


def _sanitized_fmu(fmu: Path, folder: Path) -> str:
    """The FMU unpacked with its front end rebuilt under the sanitizers: 'LIB,DIR,GUID,BYTES' for the harness."""
    unz = folder / fmu.stem
    with zipfile.ZipFile(fmu) as z:
        z.extractall(unz)
    md = read_model_description(str(fmu))
    model_id = md.coSimulation.modelIdentifier
    lib = unz / "binaries" / "linux64" / f"{model_id}.so"
    preflight = json.loads((unz / "resources" / "flexarm_bundle.json").read_text())["preflight"]
    compile_shim(md.guid, model_id, lib, preflight, cflags=STATE_FUZZ_SANITIZE)
    return f"{lib},{unz},{md.guid},{SHIM_STATE_BYTES}"


def test_every_corrupt_foreign_or_freed_state_of_a_python_fmu_is_refused_under_sanitizers(tmp_path):
    if shutil.which("gcc") is None:
        pytest.fail("gcc is needed to build the FMUs' front end under the sanitizers")
    fmus = built_fmus()
    assert set(fmus) == set(FMUS)
    specs = [_sanitized_fmu(fmus[name], tmp_path / name) for name in sorted(fmus)]
    # The embedded Python finds NumPy and SciPy where this one does. Leaks are not checked: Python keeps its
    # interpreter and modules to the end of the process by design.
    site = os.pathsep.join(sorted({str(Path(numpy.__file__).parents[1]), sysconfig.get_paths()["purelib"]}))
    env = {**os.environ, "PYTHONPATH": site, "PYTHONNOUSERSITE": "1",
           "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=0:halt_on_error=1"}
    env.pop("PYTHONHOME", None)
    rows = run_state_fuzz(specs, tmp_path, env, len(fmus))
    print(f"\n{sys.executable}: " + "; ".join(" ".join(r) for r in rows))
