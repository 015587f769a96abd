"""Build the native (plain C, Python-free) FMUs into ``build/fmus-native/``.

Each native FMU has the interface of its Python twin: the variables of the
Python FMU's modelDescription.xml (names, value references, types, units,
ranges, start values, descriptions, dependencies) are copied, and the C table
of variables is generated from them, so both kinds stay one interface. What
differs is the ``<CoSimulation>`` element (model identifier ``<Python's>Native``,
no execution tool, ``<SourceFiles>``) and the GUID. (:mod:`fmu_build.native_description`).

Every FMU holds: ``binaries/{linux64,win64,darwin64}/`` (cross-compiled with
Zig's C compiler, from the ``ziglang`` package: Linux against glibc 2.17; darwin64 a
universal binary with an x86_64 and an arm64 slice),
``sources/`` (every C file, listed in ``<SourceFiles>``, so any tool can
compile it), ``resources/`` (constants as files; their SHA-256 is compiled in
and checked by ``fmi2Instantiate``) and the model description.

Usage::

    python -m fmu_build.native_build [--out DIR] [--only plant,...] [--platforms linux64,win64,darwin64]

or ``build_native_fmus(out_dir, python_fmus)`` from Python.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import uuid
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import fmpy

from .native_description import NativeBuildError as NativeBuildError  # re-exported: the build's error
from .native_description import (
    _check_handled,
    _model_description,
    _read_description,
    _variables,
    _vars_c,
    interface_description,
)
from .progress import heartbeat, say
from .registry import NATIVE_SUFFIX, SOURCES

#: The native FMUs' C sources (the installed ``fmus/native`` folder; the code that builds them lives here).
NATIVE_DIR = SOURCES / "native"
#: Under the current directory (as fmu_build's default): an installed package writes no FMU into site-packages.
DEFAULT_OUT = Path("build") / "fmus-native"
FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
COMMON_SOURCES = ("fmi2_glue.c", "fmi2_glue.h", "fmi2_glue_internal.h", "fmi2_glue_state.c", "fmi2_glue_resources.c",
                  "live_table.c", "live_table.h", "sha256.c", "sha256.h", "portable_math.c", "portable_math.h",
                  "libm.h", "libm_link.c", "libm_link.h", "loop_index.h")
#: musl's sin/cos kernels, copied from the ziglang package (MIT licence) so every platform computes the same bits.
MUSL_SOURCES = ("__sin.c", "__cos.c", "__tan.c", "__rem_pio2.c", "__rem_pio2_large.c")

#: platform -> (Zig target, binary suffix)
PLATFORMS = {
    "linux64": ("x86_64-linux-gnu.2.17", ".so"),
    "win64": ("x86_64-windows-gnu", ".dll"),
    "darwin64": ("x86_64-macos", ".dylib"),
}
#: Platforms whose binary is universal: one Mach-O slice per Zig target, joined by :func:`universal_macho`
#: (FMI 2.0's darwin64 folder then serves Intel and Apple-silicon Macs alike).
UNIVERSAL = {"darwin64": ("x86_64-macos", "aarch64-macos")}
#: Mach-O: the 64-bit magic (little-endian file), the fat magic (big-endian), and the CPU types we build.
MH_MAGIC_64, FAT_MAGIC = 0xFEEDFACF, 0xCAFEBABE
CPU_TYPES = {0x01000007: "x86_64", 0x0100000C: "arm64"}
_FAT_ALIGN = 14  # 2**14: the page size of arm64 macOS (and a multiple of x86_64's)


# -- compiling ----------------------------------------------------------------------------------
def zig_command() -> list[str]:
    """The command that runs Zig's C compiler (the ``ziglang`` package), or NativeBuildError."""
    try:
        import ziglang  # noqa: F401
    except ImportError:
        raise NativeBuildError("the native FMUs are cross-compiled with Zig: pip install ziglang") from None
    return [sys.executable, "-m", "ziglang", "cc"]


def _musl_dir() -> Path:
    zig_command()
    import ziglang

    musl = Path(ziglang.__file__).parent / "lib" / "libc" / "musl"
    if not (musl / "src" / "math" / MUSL_SOURCES[0]).is_file():
        raise NativeBuildError(f"{musl}: musl's math sources are missing from the ziglang package")
    return musl


def compile_binary(src_dir: Path, model_identifier: str, platform: str, out_dir: Path) -> Path:
    """Compile every .c in `src_dir` into out_dir/binaries/<platform>/<model_identifier><suffix>.

    darwin64 is universal (:data:`UNIVERSAL`): an x86_64 and an arm64 slice in one Mach-O file.
    """
    main_target, suffix = PLATFORMS[platform]
    dest = out_dir / "binaries" / platform
    dest.mkdir(parents=True, exist_ok=True)
    slices = []
    with tempfile.TemporaryDirectory(prefix="flexarm-zig-") as tmp:
        for target in UNIVERSAL.get(platform, (main_target,)):
            lib = Path(tmp) / target / (model_identifier + suffix)
            lib.parent.mkdir()
            # -ffile-prefix-map: the temporary folder's name never reaches the binary (reproducible builds)
            cmd = [*zig_command(), "-target", target, "-shared", "-O2", "-g0", "-s", "-ffp-contract=off",
                   "-fvisibility=hidden", "-std=c99", f"-ffile-prefix-map={src_dir}=sources",
                   "-I", str(src_dir), "-o", str(lib), *sorted(str(p) for p in src_dir.glob("*.c"))]
            if platform != "win64":
                cmd += ["-fPIC", "-lm"]
            if platform == "darwin64":  # the install name defaults to the -o path, a temporary folder's
                cmd += [f"-Wl,-install_name,@rpath/{model_identifier}{suffix}"]
            run = subprocess.run(cmd, capture_output=True, text=True, cwd=lib.parent)
            if run.returncode != 0 or not lib.is_file():
                raise NativeBuildError(f"{model_identifier} for {platform} ({target}): {' '.join(cmd)}\n"
                                       f"{run.stderr[-4000:]}")
            slices.append(lib.read_bytes())
    out = dest / (model_identifier + suffix)
    out.write_bytes(universal_macho(slices) if len(slices) > 1 else slices[0])
    return out


def macho_cpu(data: bytes) -> str:
    """The CPU of a 64-bit Mach-O file (``x86_64`` or ``arm64``); NativeBuildError for anything else."""
    import struct

    if len(data) < 32 or struct.unpack_from("<I", data)[0] != MH_MAGIC_64:
        raise NativeBuildError("not a 64-bit little-endian Mach-O file")
    cpu = struct.unpack_from("<i", data, 4)[0]
    if cpu not in CPU_TYPES:
        raise NativeBuildError(f"Mach-O CPU type {cpu:#x} is not one of {sorted(CPU_TYPES.values())}")
    return CPU_TYPES[cpu]


def universal_macho(slices: list[bytes]) -> bytes:
    """One universal ("fat") Mach-O file holding `slices` (64-bit Mach-O files, one per CPU), as ``lipo`` writes.

    The fat header is big-endian: magic, the number of slices, then per slice its CPU type and subtype
    (copied from the slice's own header), offset, size and alignment (2**14); each slice starts on a
    2**14 boundary.
    """
    import struct

    cpus = [macho_cpu(s) for s in slices]
    if len(set(cpus)) != len(cpus):
        raise NativeBuildError(f"universal binary: one slice per CPU, got {cpus}")
    align = 1 << _FAT_ALIGN
    header = struct.pack(">II", FAT_MAGIC, len(slices))
    offset = -(-(8 + 20 * len(slices)) // align) * align
    body, entries = b"", b""
    for s in slices:
        cputype, subtype = struct.unpack_from("<iI", s, 4)
        entries += struct.pack(">iIIII", cputype, subtype, offset, len(s), _FAT_ALIGN)
        pad = offset - (8 + 20 * len(slices)) - len(body)
        body += b"\0" * pad + s
        offset = -(-(offset + len(s)) // align) * align
    return header + entries + body


# -- one FMU --------------------------------------------------------------------------------------
#: name -> the C sources of its model (relative to fmus/native/)
NATIVE_FMUS = {
    "plant": ("plant/plant.c", "plant/plant_schemes.c", "plant/plant_damping.c", "plant/plant_linalg.h",
              "plant/plant_model.h"),
    "sensors": ("sensors/sensors.c", "sensors/pcg64.c", "sensors/pcg64.h"),
    **{name: ("controller/controller.c", "controller/lqg_core.c", "controller/controller_lqg.h",
              "controller/learned_ff.c", "controller/learned_ff.h")
       for name in ("controller", "controller_ff", "controller_fb", "controller_dlqr")},
    "controller_lqg": ("controller/controller_lqg.c", "controller/controller_lqg.h", "controller/lqg_core.c",
                       "controller/lqg_bank.c", "controller/learned_ff.c", "controller/learned_ff.h"),
    "reference": ("reference/reference.c",),
}
#: controller variants: (feedforward, feedback, discrete-time gains), as fmus/controller/*.py
CONTROLLER_VARIANTS = {"controller": (1, 1, False), "controller_ff": (1, 0, False), "controller_fb": (0, 1, False),
                       "controller_dlqr": (1, 1, True)}
#: The variants a payload data folder serves (its slew and continuous-time gains; fmu_build.learned.with_payload_data
#: for the Python kind).
PAYLOAD_DATA_VARIANTS = ("controller", "controller_ff")


def write_reference_resource(path: Path) -> None:
    """The reference FMU's table (:class:`flexarm.reference.ReferenceSignals`, bit patterns) for the native twin."""
    from flexarm.provenance import sha256_file
    from flexarm.reference import REFERENCE_OUTPUTS, ReferenceSignals
    from flexarm.trajectory import DEFAULT_TRAJECTORY_FILE, load_trajectory

    from . import native_codegen

    ref = ReferenceSignals(load_trajectory(DEFAULT_TRAJECTORY_FILE))
    entries = {"n_steps": [ref.n_steps], "dt": [ref.dt], "n_outputs": [len(REFERENCE_OUTPUTS)], "table": ref.table}
    native_codegen.write_resource(
        path, entries, "flexarm reference signals for the native reference FMU (IEEE-754 hex bit patterns)\n"
                       f"source: {DEFAULT_TRAJECTORY_FILE.name} sha256 {sha256_file(DEFAULT_TRAJECTORY_FILE)}\n"
                       f"columns: {', '.join(REFERENCE_OUTPUTS)}")


def _write_learned_ff_data(path: Path, name: str, trajectory_file: Path | None = None) -> None:
    """learned_ff_data.h: the SHA-256 of the trajectory and parameter files a controller FMU is built from, which a
    learned feedforward file must have been learnt on (its .json records them; flexarm.ilc, learned_ff.c)."""
    from flexarm.learned_feedforward import LEARNED_RESOURCE
    from flexarm.parameters import DEFAULT_PARAMETER_FILE
    from flexarm.trajectory.io import DEFAULT_TRAJECTORY_FILE

    slew = DEFAULT_TRAJECTORY_FILE if trajectory_file is None else Path(trajectory_file)  # the slew it is built on
    path.write_text(
        f"/* GENERATED by fmu_build/native_build.py for {name}: the data of a learned feedforward file. */\n"
        f'#define LEARNED_FF_RESOURCE "{LEARNED_RESOURCE}"\n'
        f'#define TRAJECTORY_SHA256 "{hashlib.sha256(slew.read_bytes()).hexdigest()}"\n'
        f'#define PARAMETER_SHA256 "{hashlib.sha256(DEFAULT_PARAMETER_FILE.read_bytes()).hexdigest()}"\n')


def _stage_sources(name: str, staging: Path, python_fmu: Path, data_dir: Path | None = None
                   ) -> tuple[str, str, list[str]]:
    """Write sources/ and resources/ of one FMU into `staging`; return (model identifier, GUID, source names).
    `data_dir`: a payload data folder (:mod:`flexarm.payload_data`) the controller is built on (controller and
    controller_ff only), default the committed data."""
    from . import law_codegen, native_codegen, native_resources  # CasADi, Numba, SciPy: only when one is built

    if data_dir is not None and name not in PAYLOAD_DATA_VARIANTS:
        raise NativeBuildError(f"{name}: only {', '.join(PAYLOAD_DATA_VARIANTS)} are built on a payload data folder "
                               "(it holds the slew and its continuous-time gains)")
    trajectory = None if data_dir is None else Path(data_dir) / "trajectory.npz"

    src, res = staging / "sources", staging / "resources"
    src.mkdir(parents=True)
    res.mkdir(parents=True)
    fmpy_headers = Path(fmpy.__file__).parent / "c-code"
    for h in FMI_HEADERS:
        shutil.copy2(fmpy_headers / h, src / h)
    for f in COMMON_SOURCES:
        shutil.copy2(NATIVE_DIR / "common" / f, src / f)
    musl = _musl_dir()
    for f in MUSL_SOURCES:
        shutil.copy2(musl / "src" / "math" / f, src / f"musl{f}")
    shutil.copy2(musl / "COPYRIGHT", src / "musl_COPYRIGHT.txt")
    for model_source in NATIVE_FMUS[name]:
        shutil.copy2(NATIVE_DIR / model_source, src / Path(model_source).name)
    if name == "plant":
        native_codegen.generate_physics(src)
        native_codegen.write_arm_resource(res / native_codegen.ARM_RESOURCE)
    elif name == "sensors":
        law_codegen.generate_sensor_law(src)
        native_codegen.write_sensor_resource(res / native_codegen.SENSOR_RESOURCE)
    elif name == "controller_lqg":
        law_codegen.generate_control_law(src)
        native_resources.write_resources_header(src / "lqg_resources.h")
        native_resources.write_lqg_resources(res)
        _write_learned_ff_data(src / "learned_ff_data.h", name)
    elif name == "reference":
        write_reference_resource(res / "reference.txt")
    else:
        ff, fb, discrete = CONTROLLER_VARIANTS[name]
        law_codegen.generate_control_law(src)
        native_resources.write_resources_header(src / "lqg_resources.h")
        (src / "controller_mode.h").write_text(
            f"/* GENERATED by fmu_build/native_build.py: the {name} variant. */\n"
            f"#define CONTROLLER_FEEDFORWARD {ff}\n#define CONTROLLER_FEEDBACK {fb}\n")
        _write_learned_ff_data(src / "learned_ff_data.h", name, trajectory)
        native_codegen.write_trajectory_resource(res / native_codegen.TRAJECTORY_RESOURCE, trajectory)
        if fb:
            native_codegen.write_gains_resource(res / native_codegen.GAINS_RESOURCE, discrete,
                                                None if data_dir is None else Path(data_dir) / "gains")
            # the predictor over a measured delay
            native_resources.write_lqg_resources(res, bank=False, data_dir=data_dir)
    resources = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(res.iterdir())}
    python_xml = interface_description(_read_description(python_fmu))
    root = ET.fromstring(python_xml)
    model_identifier = root.find("CoSimulation").get("modelIdentifier") + NATIVE_SUFFIX
    digest = hashlib.sha256(python_xml)
    for p in sorted(src.iterdir()):
        digest.update(p.name.encode() + p.read_bytes())
    for name_, h in resources.items():
        digest.update((name_ + h).encode())
    guid = "{" + str(uuid.UUID(digest.hexdigest()[:32])) + "}"
    variables = _variables(root)
    _check_handled(name, variables)
    header, source = _vars_c(model_identifier, guid, variables, resources)
    (src / "model_vars.h").write_text(header)
    (src / "model_vars.c").write_text(source)
    return model_identifier, guid, sorted(p.name for p in src.iterdir())


def build_native_fmu(name: str, python_fmu: Path, out_dir: Path, platforms=tuple(PLATFORMS),
                     data_dir: Path | None = None, file_name: str | None = None) -> Path:
    """Build native FMU `name` (a key of NATIVE_FMUS) next to its Python twin `python_fmu`; returns the .fmu
    (``<out_dir>/<file_name or name>.fmu``). `data_dir`: a payload data folder the controller is built on
    (:func:`_stage_sources`)."""
    if name not in NATIVE_FMUS:
        raise NativeBuildError(f"{name}: no native FMU of that name (known: {', '.join(NATIVE_FMUS)})")
    unknown = set(platforms) - set(PLATFORMS)
    if unknown:
        raise NativeBuildError(f"platforms: unknown {sorted(unknown)} (allowed: {', '.join(PLATFORMS)})")
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f"flexarm-native-{name}-") as tmp:
        staging = Path(tmp) / "fmu"
        say(f"native {name}.fmu: generating its C sources and resources")
        with heartbeat(f"native {name}.fmu, sources"):
            model_identifier, guid, sources = _stage_sources(name, staging, Path(python_fmu), data_dir)
        (staging / "modelDescription.xml").write_bytes(_model_description(
            interface_description(_read_description(Path(python_fmu))), model_identifier, guid, sources))
        for platform in platforms:  # a line per step: the first build of Zig's C libraries takes minutes
            say(f"native {name}.fmu: compiling for {platform}")
            with heartbeat(f"native {name}.fmu, {platform}"):
                compile_binary(staging / "sources", model_identifier, platform, staging)
        tmp_fmu = Path(tmp) / f"{name}.fmu"
        with zipfile.ZipFile(tmp_fmu, "w", zipfile.ZIP_DEFLATED) as z:
            for p in sorted(staging.rglob("*")):
                if p.is_file():
                    info = zipfile.ZipInfo(p.relative_to(staging).as_posix(), date_time=(2020, 1, 1, 0, 0, 0))
                    info.external_attr = 0o644 << 16
                    info.compress_type = zipfile.ZIP_DEFLATED
                    z.writestr(info, p.read_bytes())
        from fmpy.validation import validate_fmu

        problems = validate_fmu(str(tmp_fmu)) if "linux64" in platforms else []
        if problems:
            raise NativeBuildError(f"{name}: fmpy.validate_fmu found problems:\n" + "\n".join(problems))
        stem = file_name or name
        final = out_dir / f"{stem}.fmu"
        os.replace(shutil.copy2(tmp_fmu, out_dir / f".{stem}.fmu.tmp"), final)
        os.chmod(final, 0o644)
    return final


def build_native_fmus(out_dir: Path | None = None, python_fmus: dict[str, Path] | None = None, only=None,
                      platforms=tuple(PLATFORMS)) -> dict[str, Path]:
    """Build the native set into `out_dir` (default build/fmus-native/), file names as the Python FMUs'.

    Parameters
    ----------
    out_dir : Path, optional
    python_fmus : dict name -> Path, optional
        The Python FMUs whose interface the native ones copy (default: build_fmus.build_all into a temporary
        folder).
    only : iterable of str, optional
        Names of NATIVE_FMUS to build (default: all, or all of `python_fmus` when given).
    platforms : iterable of str
        Keys of PLATFORMS.
    """
    out_dir = Path(out_dir) if out_dir is not None else DEFAULT_OUT
    names = list(only) if only else [n for n in NATIVE_FMUS if python_fmus is None or n in python_fmus]
    with tempfile.TemporaryDirectory(prefix="flexarm-python-fmus-") as tmp:
        if python_fmus is None:
            from .package import build_all  # the project's Python FMU build

            python_fmus = build_all(Path(tmp), only=names)
        return {name: build_native_fmu(name, python_fmus[name], out_dir, platforms) for name in names}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--only", default="", help="comma-separated names (default: all)")
    parser.add_argument("--platforms", default=",".join(PLATFORMS))
    args = parser.parse_args(argv)
    try:
        built = build_native_fmus(args.out, only=[s for s in args.only.split(",") if s],
                                  platforms=[s for s in args.platforms.split(",") if s])
    except NativeBuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for name, path in built.items():
        print(f"{name}: {path} ({path.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
