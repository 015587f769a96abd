"""Sealed FMU states of the native FMUs, fuzzed under AddressSanitizer and UBSan (issue 26).

Every native FMU is compiled from the C sources it ships (``sources/``) with ``gcc -fsanitize=address,undefined``
and loaded, all together, by tests/native_host/state_fuzz.c (built the same way), which flips every bit of each
FMU's serialised state and of its in-memory state, gives each FMU's state, serialised bytes and instance to every
other FMU, uses freed states and frees each instance twice. Every attack must be refused with fmi2Error (0
accepted), no sanitizer may report anything (a report aborts the harness), and the FMU's own sound states must
still restore it exactly.
"""

from __future__ import annotations

import os
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from fmpy import read_model_description
from native_fmus import STATE_FUZZ_SANITIZE, native_fmus, run_state_fuzz, unpack_alone

from fmu_build.native_build import NATIVE_FMUS

SANITIZE = [*STATE_FUZZ_SANITIZE, "-O1"]


def _sanitized_library(fmu: Path, folder: Path) -> str:
    """The FMU's own sources compiled with the sanitizers: 'LIB,UNZIPPED_DIR,GUID' for the harness."""
    unz = unpack_alone(fmu, folder)
    md = read_model_description(str(fmu))
    lib = unz / f"{md.coSimulation.modelIdentifier}.so"
    sources = sorted(str(p) for p in (unz / "sources").glob("*.c"))
    subprocess.run(["gcc", "-std=c99", *SANITIZE, "-shared", "-fPIC", "-I", str(unz / "sources"), "-o", str(lib),
                    *sources, "-lm"], check=True, capture_output=True, text=True)
    return f"{lib},{unz},{md.guid}"


def test_every_corrupt_foreign_or_freed_state_is_refused_under_sanitizers(tmp_path):
    fmus = native_fmus()
    assert set(fmus) == set(NATIVE_FMUS)
    with ThreadPoolExecutor(max_workers=2) as pool:
        specs = list(pool.map(lambda kv: _sanitized_library(kv[1], tmp_path / kv[0]), sorted(fmus.items())))
    env = {**os.environ, "ASAN_OPTIONS": "detect_leaks=1:abort_on_error=0:halt_on_error=1"}
    rows = run_state_fuzz(specs, tmp_path, env, len(NATIVE_FMUS))
    # every bit of every serialised state: at least 8 tries per byte of the plant's state
    plant_flips = next(int(t) for f, c, t, _ in rows if f.startswith("FlexarmPlant") and c.startswith("serialised"))
    assert plant_flips > 8 * 500
