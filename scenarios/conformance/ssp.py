"""Export a scenario as SSP 1.0 packages (``.ssp``), one per case, that any SSP master runs as we do.

``python -m scenarios export-ssp table2`` writes ``build/ssp/table2/<case>.ssp``
(``none.ssp``, ``tip.ssp``, ...), each a zip holding

* ``SystemStructure.ssd``: the system (SSP 1.0 SystemStructureDescription). One
  ``ssd:Component`` per FMU instance of the case, ``source="resources/<instance>.fmu"``,
  with every input, output and parameter of the FMU as a typed ``ssd:Connector``
  (Reals with their unit, defined in ``ssd:Units``); ``ssd:Connections`` as the master wires them
  (:func:`scenarios.run.setup.connect_by_name`, or the scenario's explicit list), in evaluation order
  (by the source's place in the scenario's ``order``, the torques last: a Gauss-Seidel master that
  follows the SSD's connection order, as OMSimulator's does, adds no delay);
  ``ssd:DefaultExperiment`` from 0 to the scenario's run length (``samples`` ×
  ``step_size``), with the step in the Open Simulation Platform's annotation
  ``<osp:FixedStepAlgorithm baseStepSize="0.001"/>`` that libcosim reads, and on the system
  OpenModelica's ``org.openmodelica`` annotation ``<oms:FixedStepMaster description="oms-ma"
  stepSize="0.001"/>`` (OMSimulator builds no system without a master named on it); the SSD's
  description names the stepping (Gauss-Seidel or Jacobi) the archive is meant for;
* ``resources/<instance>.fmu``: **the case's own copy of each FMU**, whose
  default values are the case's parameter values: the ``start`` attributes of
  its modelDescription.xml are rewritten, and ``resources/flexarm_start_values.json``
  inside it, read by the FMU when it is instantiated, carries the same values.
  The plant's start angles on the trajectory are among them
  (:func:`scenarios.run.setup.start_parameters`). So a master that applies no
  parameter set at all (fmpy's ``simulate_ssp``, which ignores parameter
  bindings; a native SSP engine without a parameter set named on its command
  line) still runs the case;
* ``resources/<instance>.ssv``: the same values as an SSP ParameterValues file,
  bound to the component with one ``ssd:ParameterBinding`` (for masters that
  apply bindings: libcosim applies it, with the same result).

A predictive controller's ``loop_delay_samples`` (the LQG) stays automatic (-1, its start value) unless
the scenario sets it: the controller then measures the loop delay of whatever master runs the archive
(docs/control.md, "The loop measures its own delay"), so one archive serves every master (``lqg``).
A value the scenario sets is replaced by what the scenario's stepping puts in the loop, in all three
places (start value, ``resources/flexarm_start_values.*``, ``.ssv``): 0 for Gauss-Seidel, 2n for
Jacobi at n ms (``lqg_jacobi``: 2) (:func:`loop_delay_parameters`).

A case that swaps an FMU (``fmus.controller = "controller_ff"``) simply has
that FMU in its archive. Each archive is written to a temporary file beside
the target and renamed, so a reader never sees half a file.
:func:`validate_ssp` checks the SSD and SSV against the SSP 1.0 schemas that
ship with fmpy (``fmpy/ssp/schema``) and every reference they make.

The FMU copies keep their GUID: only start values change, which FMI lets a
tool override anyway; the GUID still identifies the interface (variables,
value references, types).
"""

from __future__ import annotations

import io
import zipfile
from dataclasses import dataclass
from pathlib import Path

from fmpy import read_model_description
from lxml import etree

from flexarm.loop_index import AUTOMATIC
from flexarm.lqg import with_loop_delay
from flexarm.provenance import write_atomic
from scenarios.config import Scenario
from scenarios.master.values import parse_choices
from scenarios.run.fmus import DEFAULT_FMU_DIR, DEFAULT_NATIVE_FMU_DIR, NATIVE_GENERATION_TOOL, check_kind
from scenarios.run.setup import REPO, Setup, prepare

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations",
    "oms": "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd",
}
#: Annotation types: the Open Simulation Platform's (libcosim) and OpenModelica's (OMSimulator).
OSP_ANNOTATION, OMS_ANNOTATION = "com.opensimulationplatform", "org.openmodelica"
DEFAULT_SSD = "SystemStructure.ssd"
#: In an FMU's resources: the case's start values (read by fmus/common/flexarm_fmu_base.py, START_VALUES).
START_VALUES = "flexarm_start_values.json"
#: The same for a native FMU (read by fmi2Instantiate, fmus/native/common/fmi2_glue_resources.c): lines
#: ``name bits``, the value's IEEE-754 double as 16 hex digits (exact on every platform).
NATIVE_START_VALUES = "flexarm_start_values.txt"
DEFAULT_SSP_DIR = REPO / "build" / "ssp"
#: FMI causality -> SSP 1.0 connector kind (other causalities are not exported).
_KINDS = {"input": "input", "output": "output", "parameter": "parameter", "calculatedParameter": "calculatedParameter"}
_BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # fixed timestamps: the same inputs give the same archive


class SSPExportError(ValueError):
    """The scenario cannot be expressed as an SSP, or an archive is not a valid one."""


@dataclass
class CasePlan:
    """One archive: a case's FMUs, their wiring and the case's parameter values."""

    key: str
    label: str
    setup: Setup
    #: instance -> {variable: value} (plant start angles included; Enumerations by item name)
    parameters: dict[str, dict]


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _fmt_real(x: float) -> str:
    """Shortest text that reads back as exactly the same double (xs:double)."""
    return repr(float(x))


def plan_cases(scenario: Scenario, fmu_dir: Path = DEFAULT_FMU_DIR, build: bool = True,
               cases: list[str] | None = None, kind: str | None = None,
               native_fmu_dir: Path = DEFAULT_NATIVE_FMU_DIR) -> list[CasePlan]:
    """Prepare each case as the runner would (FMUs built if needed); `cases` selects by key (default all).

    `kind` (default the scenario's): "python" or "native" FMUs (:func:`scenarios.run.fmus.resolve_fmus`).
    """
    keys = [c.key for c in scenario.cases]
    unknown = sorted(set(cases or ()) - set(keys))
    if unknown:
        raise SSPExportError(f"cases: {unknown} not in scenario {scenario.name} (has: {', '.join(keys)})")
    check_kind(scenario, kind)  # a case whose FMU has no native build: refused before any is written
    setups: dict[tuple, Setup] = {}
    plans = []
    for case in scenario.cases:
        if cases is not None and case.key not in cases:
            continue
        names = case.fmus or scenario.fmus
        key = tuple(sorted(names.items()))
        if key not in setups:
            setups[key] = prepare(scenario, fmu_dir, names=dict(names), build=build, kind=kind,
                                         native_fmu_dir=native_fmu_dir)
        setup = setups[key]
        plans.append(CasePlan(case.key, case.label, setup, setup.case_parameters(case.parameters)))
    return plans


def typed_values(values: dict, variables: dict, where: str) -> dict:
    """`values` as the FMU's types want them: choice names -> integers (from the description); unknown refused."""
    out = {}
    for var, value in values.items():
        v = variables.get(var)
        if v is None:
            raise SSPExportError(f"{where}: the FMU has no variable '{var}'")
        if v.causality not in ("parameter", "input"):
            raise SSPExportError(f"{where}: '{var}' is an {v.causality}, not a parameter or input")
        choices = parse_choices(v.description or "") if v.type == "Integer" else {}
        if choices:
            if isinstance(value, str):
                if value not in choices:
                    raise SSPExportError(f"{where}: {var} = {value!r} is not one of {', '.join(choices)}")
                value = choices[value]
            elif int(value) not in choices.values():
                raise SSPExportError(f"{where}: {var} = {value!r} is not one of {choices}")
            out[var] = int(value)
        elif v.type == "Real":
            out[var] = float(value)
        elif v.type == "Integer":
            out[var] = int(value)
        elif v.type == "Boolean":
            out[var] = bool(value)
        else:
            raise SSPExportError(f"{where}: '{var}' has type {v.type}, which the export does not write")
    return out


def _start_text(typ: str, value) -> str:
    if typ == "Real":
        return _fmt_real(value)
    if typ == "Boolean":
        return "true" if value else "false"
    return str(int(value))


def case_fmu(fmu: Path, values: dict) -> bytes:
    """A copy of `fmu` whose default values are `values` (typed, see :func:`typed_values`).

    The ``start`` attributes in modelDescription.xml are rewritten and the
    values written to ``resources/flexarm_start_values.json`` (a Python FMU) or
    ``resources/flexarm_start_values.txt`` (a native one), which the FMU
    applies when it is instantiated (and again at ``fmi2Reset``).
    """
    import json
    import struct

    out = io.BytesIO()
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        md = etree.fromstring(src.read("modelDescription.xml"))
        seen = set()
        for sv in md.iterfind("ModelVariables/ScalarVariable"):
            name = sv.get("name")
            if name in values:
                sv[0].set("start", _start_text(sv[0].tag, values[name]))
                seen.add(name)
        missing = sorted(set(values) - seen)
        if missing:
            raise SSPExportError(f"{fmu.name}: no variables {missing} in its modelDescription.xml")
        native = (md.get("generationTool") or "").startswith(NATIVE_GENERATION_TOOL)
        ours = f"resources/{NATIVE_START_VALUES if native else START_VALUES}"
        for info in src.infolist():
            if info.filename in ("modelDescription.xml", ours):
                continue
            dst.writestr(info, src.read(info))
        dst.writestr(_member("modelDescription.xml"),
                     etree.tostring(md, xml_declaration=True, encoding="UTF-8"))
        if native:
            text = "".join(f"{name} {struct.pack('>d', float(value)).hex()}\n" for name, value in values.items())
        else:
            text = json.dumps(values, indent=1) + "\n"
        dst.writestr(_member(ours), text)
    return out.getvalue()


def _member(name: str) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
    info.external_attr = 0o644 << 16
    info.compress_type = zipfile.ZIP_DEFLATED
    return info


def parameter_set_xml(name: str, values: dict, variables: dict, description: str | None = None) -> bytes:
    """An SSP 1.0 ParameterValues document (``.ssv``) for one FMU instance.

    `values` are typed (:func:`typed_values`); `variables` (name -> fmpy
    ScalarVariable) gives each its type.
    """
    root = etree.Element(_q("ssv", "ParameterSet"), nsmap={"ssv": NS["ssv"]}, version="1.0", name=name)
    if description:
        root.set("description", description)
    params = etree.SubElement(root, _q("ssv", "Parameters"))
    for var, value in values.items():
        v = variables[var]
        p = etree.SubElement(params, _q("ssv", "Parameter"), name=var)
        if v.type == "Real":
            e = etree.SubElement(p, _q("ssv", "Real"), value=_fmt_real(value))
            if v.unit:
                e.set("unit", v.unit)
        else:
            etree.SubElement(p, _q("ssv", v.type), value=_start_text(v.type, value))
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def _ssv_path(instance: str) -> str:
    return f"resources/{instance}.ssv"


def _fmu_path(instance: str) -> str:
    return f"resources/{instance}.fmu"


def system_structure_xml(scenario: Scenario, plan: CasePlan) -> bytes:
    """The SSD (SSP 1.0 SystemStructureDescription) of one case."""
    setup = plan.setup
    mds = {inst: read_model_description(str(setup.paths[inst])) for inst in setup.scenario.order}
    root = etree.Element(_q("ssd", "SystemStructureDescription"), nsmap=NS, version="1.0",
                         name=f"{scenario.name}_{plan.key}", generationTool="flexarm-fmi scenarios.conformance.ssp")
    root.set("description", f"{scenario.description} -- case {plan.key}: {plan.label} -- for a {scenario.algorithm} "
             f"master stepping {_fmt_real(scenario.step_size)} s".strip(" -"))
    system = etree.SubElement(root, _q("ssd", "System"), name=scenario.name)
    elements = etree.SubElement(system, _q("ssd", "Elements"))
    units = {}
    for inst in setup.scenario.order:  # with a reference FMU the runner added
        md = mds[inst]
        for u in md.unitDefinitions:
            units.setdefault(u.name, u)
        comp = etree.SubElement(elements, _q("ssd", "Component"), name=inst, source=_fmu_path(inst),
                                type="application/x-fmu-sharedlibrary", implementation="CoSimulation")
        connectors = etree.SubElement(comp, _q("ssd", "Connectors"))
        for v in md.modelVariables:
            kind = _KINDS.get(v.causality)
            if kind is None:
                continue
            c = etree.SubElement(connectors, _q("ssd", "Connector"), name=v.name, kind=kind)
            if v.description:
                c.set("description", v.description)
            t = etree.SubElement(c, _q("ssc", v.type))
            if v.type == "Real" and v.unit:
                t.set("unit", v.unit)
        bindings = etree.SubElement(comp, _q("ssd", "ParameterBindings"))
        etree.SubElement(bindings, _q("ssd", "ParameterBinding"), type="application/x-ssp-parameter-set",
                         source=_ssv_path(inst))
    conns = etree.SubElement(system, _q("ssd", "Connections"))
    # In evaluation order (by the source's place in the scenario's order: plant -> sensors -> controller ->
    # plant): a Gauss-Seidel master that follows the SSD's connection order then puts no delay in the loop.
    rank = {inst: i for i, inst in enumerate(setup.scenario.order)}
    for c in sorted(setup.connections, key=lambda c: rank.get(c.src_fmu, len(rank))):
        etree.SubElement(conns, _q("ssd", "Connection"), startElement=c.src_fmu, startConnector=c.src_var,
                         endElement=c.dst_fmu, endConnector=c.dst_var)
    h = scenario.step_size
    # OMSimulator builds a system only with a master named on it: its fixed-step master at the scenario's step.
    oms = etree.SubElement(etree.SubElement(etree.SubElement(system, _q("ssd", "Annotations")), _q("ssc", "Annotation"),
                                            type=OMS_ANNOTATION), _q("oms", "Annotations"))
    etree.SubElement(etree.SubElement(oms, _q("oms", "SimulationInformation")), _q("oms", "FixedStepMaster"),
                     description="oms-ma", stepSize=_fmt_real(h))
    if units:
        ue = etree.SubElement(root, _q("ssd", "Units"))
        for name, u in units.items():
            unit = etree.SubElement(ue, _q("ssc", "Unit"), name=name)
            base = etree.SubElement(unit, _q("ssc", "BaseUnit"))
            bu = u.baseUnit
            if bu is not None:
                for k in _BASE_UNITS:
                    if getattr(bu, k, 0):
                        base.set(k, str(int(getattr(bu, k))))
                if bu.factor != 1.0:
                    base.set("factor", _fmt_real(bu.factor))
                if bu.offset != 0.0:
                    base.set("offset", _fmt_real(bu.offset))
    exp = etree.SubElement(root, _q("ssd", "DefaultExperiment"), startTime="0.0",
                           stopTime=_fmt_real(round(setup.n_steps * h, 12)))
    ann = etree.SubElement(etree.SubElement(exp, _q("ssd", "Annotations")), _q("ssc", "Annotation"),
                           type=OSP_ANNOTATION)
    algo = etree.SubElement(ann, _q("osp", "Algorithm"))
    etree.SubElement(algo, _q("osp", "FixedStepAlgorithm"), baseStepSize=_fmt_real(h))
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def export_ssp(scenario: Scenario, out_dir: str | Path = DEFAULT_SSP_DIR,
               fmu_dir: str | Path = DEFAULT_FMU_DIR, build: bool = True,
               cases: list[str] | None = None, kind: str | None = None,
               native_fmu_dir: str | Path = DEFAULT_NATIVE_FMU_DIR) -> dict[str, Path]:
    """Write one archive per case, ``<out_dir>/<scenario>/<case>.ssp``; return {case key: path}.

    FMUs are built into `fmu_dir` (and `native_fmu_dir`) if needed (as ``python -m scenarios run`` does).
    `cases` selects cases by key (default: all). `kind` (default the scenario's ``kind``): "python" puts
    the Python FMUs in the archives, "native" the plain-C ones (a case whose FMU has no native build is
    refused naming it).
    """
    folder = Path(out_dir) / scenario.name
    written = {}
    for plan in plan_cases(scenario, Path(fmu_dir), build, cases, kind, Path(native_fmu_dir)):
        members: dict[str, bytes] = {DEFAULT_SSD: system_structure_xml(scenario, plan)}
        for inst in plan.setup.scenario.order:
            path = Path(plan.setup.paths[inst])
            variables = {v.name: v for v in read_model_description(str(path)).modelVariables}
            params = loop_delay_parameters(scenario, plan.parameters.get(inst, {}), variables)
            values = typed_values(params, variables, f"case {plan.key}, {inst}")
            members[_fmu_path(inst)] = case_fmu(path, values)
            members[_ssv_path(inst)] = parameter_set_xml(plan.key, values, variables, plan.label)
        written[plan.key] = _write_zip(folder / f"{plan.key}.ssp", members)
    return written


def loop_delay_parameters(scenario: Scenario, params: dict, variables: dict) -> dict:
    """A controller's case parameters with the ``loop_delay_samples`` the scenario's master puts in the loop.

    The archive is for a master that steps as the scenario says (``algorithm``, ``step_size_s``):
    :func:`flexarm.lqg.required_loop_delay` for that stepping, 0 for Gauss-Seidel (``lqg``, as its
    file says), 2n for Jacobi at n ms with the sensors FMU (``lqg_jacobi``: 2 at 1 ms). An FMU without
    the parameter is unchanged.
    """
    if "loop_delay_samples" not in variables:
        return params
    if int(params.get("loop_delay_samples", variables["loop_delay_samples"].start)) == AUTOMATIC:
        return params  # it measures the delay of whatever master runs the archive: one archive for every master
    return with_loop_delay(params, scenario.algorithm, _feedthrough_fmus(scenario), scenario.step_size)


def _feedthrough_fmus(scenario: Scenario) -> int:
    """Direct-feedthrough FMUs between the plant and the torques: the sensors (if any) and the controller.

    A Jacobi-stepping master (libcosim, most SSP engines) adds one sample of delay through each.
    """
    return 1 + int("sensors" in scenario.order)


def _write_zip(out: Path, members: dict[str, bytes]) -> Path:
    """Write the archive atomically (:func:`flexarm.provenance.write_atomic`: readable by everyone)."""
    def write(f) -> None:
        with zipfile.ZipFile(f, "w") as zf:
            for name in sorted(members, key=lambda n: (not n.endswith(".ssd"), n)):
                info = _member(name)
                if name.endswith(".fmu"):
                    info.compress_type = zipfile.ZIP_STORED  # an FMU is already a zip
                zf.writestr(info, members[name])

    return write_atomic(out, write)


def _schema(name: str) -> etree.XMLSchema:
    import fmpy.ssp

    return etree.XMLSchema(file=str(Path(fmpy.ssp.__file__).parent / "schema" / name))


def validate_ssp(ssp_path: str | Path) -> list[str]:
    """Check an archive: every SSD and SSV against the SSP 1.0 schemas, and every reference it makes.

    Returns the list of problems (empty when valid): schema errors with file and
    line, Component sources and ParameterBinding sources that are not in the archive,
    Connections naming unknown components or connectors.
    """
    ssd_schema, ssv_schema = _schema("SystemStructureDescription.xsd"), _schema("SystemStructureParameterValues.xsd")
    problems = []
    with zipfile.ZipFile(ssp_path) as zf:
        names = set(zf.namelist())
        if DEFAULT_SSD not in names:
            problems.append(f"no {DEFAULT_SSD} in the archive")
        for name in sorted(names):
            schema = ssd_schema if name.endswith(".ssd") else ssv_schema if name.endswith(".ssv") else None
            if schema is None:
                continue
            doc = etree.parse(io.BytesIO(zf.read(name)))
            if not schema.validate(doc):
                problems += [f"{name}:{e.line}: {e.message}" for e in schema.error_log]
            if not name.endswith(".ssd"):
                continue
            connectors = {}
            for comp in doc.iterfind("ssd:System/ssd:Elements/ssd:Component", NS):
                cname, source = comp.get("name"), comp.get("source")
                if source not in names:
                    problems.append(f"{name}: component {cname}: source {source} not in the archive")
                connectors[cname] = {c.get("name") for c in comp.iterfind("ssd:Connectors/ssd:Connector", NS)}
                for b in comp.iterfind("ssd:ParameterBindings/ssd:ParameterBinding", NS):
                    if b.get("source") is not None and b.get("source") not in names:
                        problems.append(f"{name}: component {cname}: parameter source {b.get('source')} "
                                        "not in the archive")
            for c in doc.iterfind("ssd:System/ssd:Connections/ssd:Connection", NS):
                for el, con in (("startElement", "startConnector"), ("endElement", "endConnector")):
                    if c.get(con) not in connectors.get(c.get(el), ()):
                        problems.append(f"{name}: connection names unknown connector {c.get(el)}.{c.get(con)}")
    return problems
