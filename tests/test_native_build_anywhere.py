"""Native FMU sources that build anywhere (issue 21, item 6).

* A binary rebuilt from an FMU's ``<SourceFiles>`` by FMPy (``fmpy compile``: CMake, no libraries linked)
  loads and runs in a plain C host that has no libm (tests/native_host/fmi2_host.c built without
  ``-lm``, run under ``env -i``): the sources reach libm's functions through libm_link.c (weak references,
  own implementations when the process has no libm).
* darwin64 is a universal binary: an x86_64 and an arm64 slice, checked by parsing the Mach-O headers
  (no macOS here).
"""

from __future__ import annotations

import shutil
import struct
import subprocess
import zipfile

import numpy as np
import pytest
from fmpy import read_model_description
from native_fmus import FMI_HEADERS, HOST_SOURCE, native_fmus, read_host_csv, unpack_alone

from fmu_build.native_build import CPU_TYPES, FAT_MAGIC, MH_MAGIC_64

N_STEPS = 300
EXPORTS = (b"_fmi2Instantiate", b"_fmi2DoStep", b"_fmi2GetReal", b"_fmi2SetFMUstate")


def fat_slices(data: bytes) -> dict[str, bytes]:
    """{cpu: slice} of a universal Mach-O file, checking its header (big-endian) and every slice's."""
    magic, n = struct.unpack_from(">II", data)
    assert magic == FAT_MAGIC, hex(magic)
    out = {}
    for i in range(n):
        cputype, subtype, offset, size, align = struct.unpack_from(">iIIII", data, 8 + 20 * i)
        assert offset % (1 << align) == 0 and offset + size <= len(data), (i, offset, size, align)
        piece = data[offset:offset + size]
        assert struct.unpack_from("<I", piece)[0] == MH_MAGIC_64
        assert struct.unpack_from("<iI", piece, 4) == (cputype, subtype)  # the slice's own header agrees
        out[CPU_TYPES[cputype]] = piece
    return out


def test_darwin64_binaries_are_universal_x86_64_and_arm64():
    for name, fmu in native_fmus().items():
        model_id = read_model_description(str(fmu)).coSimulation.modelIdentifier
        with zipfile.ZipFile(fmu) as z:
            lib = z.read(f"binaries/darwin64/{model_id}.dylib")
        slices = fat_slices(lib)
        assert set(slices) == {"x86_64", "arm64"}, name
        for cpu, piece in slices.items():
            assert all(symbol in piece for symbol in EXPORTS), (name, cpu)


def _host_without_libm(folder) -> str:
    exe = folder / "fmi2_host_nolibm"
    subprocess.run(["gcc", "-std=c11", "-O2", "-I", str(FMI_HEADERS), "-o", str(exe), str(HOST_SOURCE), "-ldl"],
                   check=True, capture_output=True, text=True)
    needed = subprocess.run(["readelf", "-d", str(exe)], capture_output=True, text=True).stdout
    assert "libm.so" not in needed  # a plain C host without the math library
    return str(exe)


def _run(exe: str, unz, csv) -> tuple[list[str], np.ndarray]:
    run = subprocess.run(["env", "-i", exe, str(unz), "--steps", str(N_STEPS), "--inputs", str(csv), "--quiet",
                          "--check-errors"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    return read_host_csv(run.stdout[run.stdout.index("time,"):])


@pytest.mark.parametrize("name", ["plant", "sensors"])
def test_binary_rebuilt_by_fmpy_compile_loads_in_a_c_host_without_libm(name, tmp_path):
    """plant (sqrt, fmax) and sensors (pow, hypot, nearbyint): fmpy.build, then a run in a libm-free host."""
    build = pytest.importorskip("fmpy.build")
    if shutil.which("cmake") is None or shutil.which("gcc") is None or shutil.which("readelf") is None:
        pytest.skip("cmake, gcc and readelf are needed to rebuild from sources and inspect the result")
    fmu = native_fmus()[name]
    shipped = unpack_alone(fmu, tmp_path / "shipped")
    rebuilt = unpack_alone(fmu, tmp_path / "rebuilt")
    shutil.rmtree(rebuilt / "binaries")
    (tmp_path / "cmake-build").mkdir()
    build.build_platform_binary(rebuilt.resolve(), build_dir=tmp_path / "cmake-build")  # what `fmpy compile` runs
    model_id = read_model_description(str(fmu)).coSimulation.modelIdentifier
    lib = rebuilt / "binaries" / "linux64" / f"{model_id}.so"
    assert "libm.so" not in subprocess.run(["readelf", "-d", str(lib)], capture_output=True, text=True).stdout
    inputs = [v.name for v in read_model_description(str(fmu)).modelVariables if v.causality == "input"]
    k = np.arange(N_STEPS)[:, None]
    values = 0.3 * np.sin(k / (20.0 + np.arange(len(inputs)))) + 0.01 * np.arange(len(inputs))
    csv = tmp_path / "inputs.csv"
    csv.write_text(",".join(inputs) + "\n" + "".join(",".join(repr(float(x)) for x in row) + "\n" for row in values))
    exe = _host_without_libm(tmp_path)
    header, got = _run(exe, rebuilt, csv)
    header_s, ref = _run(exe, shipped, csv)
    assert header == header_s
    assert np.abs(ref[:, 1:]).max() > 0.01  # the outputs move
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9 * np.abs(ref).max())
