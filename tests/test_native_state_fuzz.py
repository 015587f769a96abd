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
from native_fmus import FMI_HEADERS, ROOT, native_fmus, unpack_alone

from fmus.native.build_native import NATIVE_FMUS

SANITIZE = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer", "-g", "-O1"]
CHECKS = {"serialised_bit_flips_and_lengths", "in_memory_bit_flips", "foreign_state_bytes_instance",
          "freed_or_null_state", "sound_state_refused", "freed_instance"}


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
    harness = tmp_path / "state_fuzz"
    subprocess.run(["gcc", "-std=c11", *SANITIZE, "-I", str(FMI_HEADERS), "-o", str(harness),
                    str(ROOT / "tests" / "native_host" / "state_fuzz.c"), "-ldl"], check=True, capture_output=True,
                   text=True)
    env = {**os.environ, "ASAN_OPTIONS": "detect_leaks=1:abort_on_error=0:halt_on_error=1",
           "UBSAN_OPTIONS": "halt_on_error=1:print_stacktrace=1"}
    run = subprocess.run([str(harness), *specs], capture_output=True, text=True, env=env, timeout=600)
    assert "Sanitizer" not in run.stderr and "runtime error" not in run.stderr, run.stderr[-4000:]
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    rows = [line.split() for line in run.stdout.splitlines() if not line.startswith("messages")]
    seen: dict[str, set[str]] = {}
    for fmu, check, tried, accepted in rows:
        assert int(tried) > 0 and int(accepted) == 0, (fmu, check, tried, accepted)
        seen.setdefault(fmu, set()).add(check)
    assert len(seen) == len(NATIVE_FMUS) and all(checks == CHECKS for checks in seen.values()), seen
    # each FMU's state given to each of the others
    assert sum(check == "foreign_state_bytes_instance" for _, check, _, _ in rows) == len(fmus) * (len(fmus) - 1)
    # every bit of every serialised state: at least 8 tries per byte of the plant's state
    plant_flips = next(int(t) for f, c, t, _ in rows if f.startswith("FlexarmPlant") and c.startswith("serialised"))
    assert plant_flips > 8 * 500
