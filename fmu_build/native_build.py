"""Build the native (plain C, Python-free) FMUs into ``build/fmus-native/``.

Each native FMU has the interface of its Python twin: the variables of the
Python FMU's modelDescription.xml (names, value references, types, units,
ranges, start values, descriptions, dependencies) are copied, and the C table
of variables is generated from them, so both kinds stay one interface. What
differs is the ``<CoSimulation>`` element (model identifier ``<Python's>Native``,
no execution tool, ``<SourceFiles>``) and the GUID.

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

from .progress import say
from .registry import SOURCES

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


class NativeBuildError(RuntimeError):
    """A native FMU could not be generated, compiled or validated."""


# -- the variables, from the Python FMU ------------------------------------------------------
def _read_description(python_fmu: Path) -> bytes:
    with zipfile.ZipFile(python_fmu) as z:
        return z.read("modelDescription.xml")


#: The interface contract's enumerations (docs/fmu-interface.md) for the controllers' former String parameters:
#: old name -> (new name, declared type, {value: item name}, start value, description).
#: (A function: native_codegen, which needs CasADi and Numba, is imported only for a build, so that a run
#: that only asks which FMUs have a native build, or whether they are up to date, starts fast.)
def _string_to_enumeration() -> dict:
    from . import native_codegen

    return {
        "gain_set": ("gain_set", "GainSet", native_codegen.GAIN_SETS, 2,
                     "LQR gain set (Q = diag(10 I, gamma I) weights or eq. 32); controller_dlqr uses its "
                     "discrete-time design"),
        "omega7": ("omega7_estimate", "Omega7Estimate", native_codegen.OMEGA7_ESTIMATES, 1,
                   "How the theta7-rate error is formed: tachometer (qd2 error) or rigid (qd1 + qd2 errors)"),
    }


def interface_description(python_xml: bytes) -> bytes:
    """The Python FMU's description with the interface contract's Enumerations for String parameters.

    A Python FMU built before the contract's Enumerations landed still has ``gain_set`` and ``omega7`` as
    Strings; the native glue has no Strings, and the contract says: Enumeration ``GainSet`` (1 gamma1,
    2 gamma0.1, 3 gamma0, 4 eq32; start 2) and ``omega7_estimate`` of type ``Omega7Estimate`` (1 tachometer,
    2 rigid; start 1). A description that has them already is returned unchanged.
    """
    string_to_enumeration = _string_to_enumeration()
    root = ET.fromstring(python_xml)
    variables = root.find("ModelVariables")
    strings = [sv for sv in variables if next(iter(sv)).tag == "String"]
    if not strings:
        return python_xml
    types = root.find("TypeDefinitions")
    if types is None:
        types = ET.Element("TypeDefinitions")
        after = [i for i, el in enumerate(root) if el.tag in ("ModelExchange", "CoSimulation", "UnitDefinitions")]
        root.insert(max(after) + 1 if after else 0, types)
    for sv in strings:
        if sv.get("name") not in string_to_enumeration:
            raise NativeBuildError(f"{sv.get('name')}: a String variable with no Enumeration in the interface "
                                   "contract (the native glue has no Strings)")
        new, declared, items, start, description = string_to_enumeration[sv.get("name")]
        simple = ET.SubElement(types, "SimpleType", name=declared)
        enum = ET.SubElement(simple, "Enumeration")
        for value, item in items.items():
            ET.SubElement(enum, "Item", name=item, value=str(value))
        sv.set("name", new)
        sv.set("description", description + " (" + ", ".join(f"{v} {n}" for v, n in items.items()) + ")")
        sv.remove(next(iter(sv)))
        ET.SubElement(sv, "Enumeration", declaredType=declared, start=str(start))
    return ET.tostring(root, encoding="utf-8")


def _variables(root: ET.Element) -> list[dict]:
    enum_ranges = {}
    for td in root.iter("SimpleType"):
        items = [int(i.get("value")) for i in td.iter("Item")]
        if items:
            enum_ranges[td.get("name")] = (min(items), max(items))
    out = []
    for sv in root.find("ModelVariables"):
        t = next(iter(sv))
        kind = t.tag
        lo, hi = t.get("min"), t.get("max")
        if kind == "Enumeration" and (lo is None or hi is None):
            elo, ehi = enum_ranges[t.get("declaredType")]
            lo, hi = lo if lo is not None else elo, hi if hi is not None else ehi
        if kind == "Boolean":
            lo, hi = 0, 1
        if kind == "String":
            raise NativeBuildError(f"{sv.get('name')}: the native glue has no String variables (no FMU of ours "
                                   "has one: a tool that cannot set strings must use every FMU fully)")
        start = t.get("start", "0")
        if kind == "Boolean":
            start = "1" if start in ("true", "1") else "0"
        out.append({"name": sv.get("name"), "vr": int(sv.get("valueReference")), "type": kind,
                    "causality": sv.get("causality", "local"), "start": float(start),
                    "min": float(lo) if lo is not None else None, "max": float(hi) if hi is not None else None,
                    "unit": t.get("unit", "")})
    return out


def _c_double(x: float | None, default: str) -> str:
    return default if x is None else repr(float(x))


def _vars_c(model_identifier: str, guid: str, variables: list[dict], resources: dict[str, str]) -> tuple[str, str]:
    """model_vars.h and model_vars.c: the variable table, GUID and resource digests."""
    enum = ",\n    ".join(f"IDX_{v['name']} = {i}" for i, v in enumerate(variables))
    by_name = {v["name"]: i for i, v in enumerate(variables)}
    groups = ""
    for label, prefix, count in (("THETA", "theta", 11), ("OMEGA", "omega", 11), ("EPS", "eps", 6)):
        names = [f"{prefix}{k}" for k in range(1, count + 1)]
        if all(n in by_name for n in names):
            groups += f"static const int IDX_{label}[{count}] = {{{', '.join(str(by_name[n]) for n in names)}}};\n"
    has = "\n".join(f"#define HAS_VAR_{v['name']} 1" for v in variables)
    header = f"""/* GENERATED by fmu_build/native_build.py from the Python FMU's modelDescription.xml: do not edit. */
#ifndef MODEL_VARS_H
#define MODEL_VARS_H
#include "fmi2_glue.h"
#define MODEL_IDENTIFIER_STRING "{model_identifier}"
#define MODEL_GUID_STRING "{guid}"
#define MODEL_N_VARS {len(variables)}
#define MODEL_N_RESOURCES {len(resources)}
enum {{
    {enum}
}};
{groups}{has}
extern const VarInfo MODEL_VARS[MODEL_N_VARS];
extern const ResourceInfo MODEL_RESOURCES[];
#endif
"""
    caus = {"parameter": "CA_PARAMETER", "input": "CA_INPUT", "output": "CA_OUTPUT"}
    types = {"Real": "VT_REAL", "Integer": "VT_INTEGER", "Boolean": "VT_BOOLEAN", "Enumeration": "VT_ENUMERATION"}
    rows = []
    for v in variables:
        if v["causality"] not in caus:
            raise NativeBuildError(f"{v['name']}: causality {v['causality']!r} is not supported by the native glue")
        rows.append(f'    {{"{v["name"]}", {v["vr"]}u, {types[v["type"]]}, {caus[v["causality"]]}, '
                    f'{v["start"]!r}, {_c_double(v["min"], "-HUGE_VAL")}, {_c_double(v["max"], "HUGE_VAL")}, '
                    f'"{v["unit"]}"}}')
    var_rows = ",\n".join(rows)
    res_rows = ",\n".join(f'    {{"{name}", "{digest}"}}' for name, digest in resources.items()) or '    {"", ""}'
    source = f"""/* GENERATED by fmu_build/native_build.py: do not edit. */
#include <math.h>

#include "model_vars.h"

const VarInfo MODEL_VARS[MODEL_N_VARS] = {{
{var_rows}
}};

const ResourceInfo MODEL_RESOURCES[] = {{
{res_rows}
}};
"""
    return header, source


#: The parameters each native model implements. A parameter of the Python FMU not listed here stops the build:
#: the native FMU would silently ignore it.
HANDLED_PARAMETERS = {
    "plant": {"payload_mass", "q1_0", "q2_0", "substeps", "integrator", "damping_ratio"},
    "sensors": {"noise_enabled", "noise_seed", "encoder_noise_deg", "encoder_quantization", "encoder_counts_per_rev",
                "tachometer_noise_deg_per_s", "tachometer_full_scale_deg_per_s", "strain_gauge_noise_deg",
                "strain_gauge_filter", "strain_gauge_cutoff_hz", "strain_gauge_filter_order",
                "strain_gauge_full_scale_curvature_per_m_link1", "strain_gauge_full_scale_curvature_per_m_link2",
                "accelerometer_noise_m_per_s2", "accelerometer_filter", "accelerometer_cutoff_hz",
                "accelerometer_filter_order", "accelerometer_full_scale_m_per_s2", "adc_quantization", "adc_bits",
                "sample_period"},
    **{name: {"gain_set", "schedule_period", "tau1_max", "tau2_max", "omega7_estimate"}
       for name in ("controller", "controller_ff", "controller_fb", "controller_dlqr")},
    # omega7_estimate: accepted and not used, as by the Python FMU (the Kalman filter estimates every velocity)
    "controller_lqg": {"gain_set", "schedule_period", "tau1_max", "tau2_max", "omega7_estimate",
                       "loop_delay_samples", "integral_action", "estimator"},
    "reference": {"lead_samples"},
}


def _check_handled(name: str, variables: list[dict]) -> None:
    unknown = sorted(v["name"] for v in variables if v["causality"] == "parameter"
                     and v["name"] not in HANDLED_PARAMETERS[name])
    if unknown:
        raise NativeBuildError(f"{name}: the Python FMU has parameter(s) {', '.join(unknown)} that the native model "
                               f"does not implement (fmus/native/): implement them there, or the native FMU would "
                               "ignore them")


def _model_description(python_xml: bytes, model_identifier: str, guid: str, sources: list[str]) -> bytes:
    root = ET.fromstring(python_xml)
    root.set("guid", guid)
    root.set("generationTool", "flexarm-fmi native build (fmu_build/native_build.py, CasADi code generation)")
    root.set("description", root.get("description", "") + " [native C build]")
    cs = root.find("CoSimulation")
    for key, value in (("modelIdentifier", model_identifier), ("needsExecutionTool", "false"),
                       ("canHandleVariableCommunicationStepSize", "true"),
                       ("canBeInstantiatedOnlyOncePerProcess", "false"), ("canGetAndSetFMUstate", "true"),
                       ("canSerializeFMUstate", "true"), ("canNotUseMemoryManagementFunctions", "true")):
        cs.set(key, value)
    for old in cs.findall("SourceFiles"):
        cs.remove(old)
    files = ET.SubElement(cs, "SourceFiles")
    for name in sources:
        if name.endswith(".c"):
            ET.SubElement(files, "File", name=name)
    ET.indent(root, "\t")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")


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
    "plant": ("plant/plant.c", "plant/plant_linalg.h"),
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


def _write_learned_ff_data(path: Path, name: str) -> None:
    """learned_ff_data.h: the SHA-256 of the trajectory and parameter files a controller FMU is built from, which a
    learned feedforward file must have been learnt on (its .json records them; flexarm.ilc, learned_ff.c)."""
    from flexarm.learned_feedforward import LEARNED_RESOURCE
    from flexarm.parameters import DEFAULT_PARAMETER_FILE
    from flexarm.trajectory.io import DEFAULT_TRAJECTORY_FILE

    path.write_text(
        f"/* GENERATED by fmu_build/native_build.py for {name}: the data of a learned feedforward file. */\n"
        f'#define LEARNED_FF_RESOURCE "{LEARNED_RESOURCE}"\n'
        f'#define TRAJECTORY_SHA256 "{hashlib.sha256(DEFAULT_TRAJECTORY_FILE.read_bytes()).hexdigest()}"\n'
        f'#define PARAMETER_SHA256 "{hashlib.sha256(DEFAULT_PARAMETER_FILE.read_bytes()).hexdigest()}"\n')


def _stage_sources(name: str, staging: Path, python_fmu: Path) -> tuple[str, str, list[str]]:
    """Write sources/ and resources/ of one FMU into `staging`; return (model identifier, GUID, source names)."""
    from . import native_codegen, native_resources  # CasADi, Numba, SciPy: only when a native FMU is built

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
        native_codegen.write_sensor_resource(res / native_codegen.SENSOR_RESOURCE)
    elif name == "controller_lqg":
        native_resources.write_lqg_resources(res)
        _write_learned_ff_data(src / "learned_ff_data.h", name)
    elif name == "reference":
        write_reference_resource(res / "reference.txt")
    else:
        ff, fb, discrete = CONTROLLER_VARIANTS[name]
        (src / "controller_mode.h").write_text(
            f"/* GENERATED by fmu_build/native_build.py: the {name} variant. */\n"
            f"#define CONTROLLER_FEEDFORWARD {ff}\n#define CONTROLLER_FEEDBACK {fb}\n")
        _write_learned_ff_data(src / "learned_ff_data.h", name)
        native_codegen.write_trajectory_resource(res / native_codegen.TRAJECTORY_RESOURCE)
        if fb:
            native_codegen.write_gains_resource(res / native_codegen.GAINS_RESOURCE, discrete)
            native_resources.write_lqg_resources(res, bank=False)  # the predictor over a measured delay
    resources = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(res.iterdir())}
    python_xml = interface_description(_read_description(python_fmu))
    root = ET.fromstring(python_xml)
    model_identifier = root.find("CoSimulation").get("modelIdentifier") + "Native"
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


def build_native_fmu(name: str, python_fmu: Path, out_dir: Path, platforms=tuple(PLATFORMS)) -> Path:
    """Build native FMU `name` (a key of NATIVE_FMUS) next to its Python twin `python_fmu`; returns the .fmu."""
    if name not in NATIVE_FMUS:
        raise NativeBuildError(f"{name}: no native FMU of that name (known: {', '.join(NATIVE_FMUS)})")
    unknown = set(platforms) - set(PLATFORMS)
    if unknown:
        raise NativeBuildError(f"platforms: unknown {sorted(unknown)} (allowed: {', '.join(PLATFORMS)})")
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f"flexarm-native-{name}-") as tmp:
        staging = Path(tmp) / "fmu"
        say(f"native {name}.fmu: generating its C sources and resources")
        model_identifier, guid, sources = _stage_sources(name, staging, Path(python_fmu))
        (staging / "modelDescription.xml").write_bytes(_model_description(
            interface_description(_read_description(Path(python_fmu))), model_identifier, guid, sources))
        for platform in platforms:  # a line per step: the first build of Zig's C libraries takes minutes, silently
            say(f"native {name}.fmu: compiling for {platform}")
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
        final = out_dir / f"{name}.fmu"
        os.replace(shutil.copy2(tmp_fmu, out_dir / f".{name}.fmu.tmp"), final)
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
