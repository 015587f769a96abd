"""The interface of a native FMU, taken from its Python twin: the model description and the C table of variables.

The variables of the Python FMU's modelDescription.xml (names, value references, types, units, ranges,
start values, descriptions, dependencies) are copied, and the C table of variables (``vars.c``/``vars.h``)
is generated from them, so both kinds stay one interface; the native description differs in its
``<CoSimulation>`` element and GUID. The build that uses them is :mod:`fmu_build.native_build`.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path


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
    "plant": {"payload_mass", "q1_0", "q2_0", "substeps", "integrator", "damping_ratio", "link_stiffness_scale"},
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
