"""Export a scenario as an SSP 1.0 package (``.ssp``) that other co-simulation masters can run.

``python -m scenarios export-ssp table2`` writes ``build/ssp/table2.ssp``, a zip holding

* ``SystemStructure.ssd``: the system (SSP 1.0 SystemStructureDescription). One
  ``ssd:Component`` per FMU instance of the scenario, ``source="resources/<fmu>.fmu"``,
  with every input, output and parameter of the FMU as a typed ``ssd:Connector``
  (Reals with their unit, defined in ``ssd:Units``); ``ssd:Connections`` as the
  master wires them (:func:`scenarios.runner.connect_by_name`, or the scenario's
  explicit list); ``ssd:DefaultExperiment`` from 0 to the scenario's run length
  (``samples`` × ``step_size``), with the step in the Open Simulation Platform's
  annotation ``<osp:FixedStepAlgorithm baseStepSize="0.001"/>`` that libcosim reads;
* ``resources/<fmu>.fmu``: the FMUs, as built (stored, not recompressed);
* ``resources/<case>/<instance>.ssv``: one SSP ParameterValues file per case and
  FMU instance, ``<ssv:ParameterSet name="<case>">``: the case's parameters (the
  scenario's, with the case's overrides) and, for the plant, its start angles
  on the trajectory (:func:`scenarios.runner.start_parameters`).

**Choosing a case.** Each component lists one ``ssd:ParameterBinding`` per case, in
the scenario's order, each pointing at that case's ``.ssv``. This is the
convention of libcosim (Open Simulation Platform): the ParameterSets of all
components that share a name form one selectable parameter set ("none",
"noise", ...), and without a choice the *first* binding of each component
applies, i.e. the scenario's first case. libcosim's C API (and so libcosimpy
0.0.6) always applies the first; :mod:`scenarios.libcosim_runner` selects another
case by putting its bindings first in an unpacked copy. The parameter files are
per component because libcosim reads bindings only on components (not on the
system) and resolves the names in a set against that component.
(A generic SSP 1.0 tool applies *all* bindings in order, so the last case would
win there: select a case by deleting the other bindings.)

**Cases that swap FMUs** (``fmus.controller = "controller_ff"`` in a case) cannot
share a system structure with the others: each distinct FMU set gets its own
SSD in the same archive (SSP allows several; ``SystemStructure.ssd`` is the
default and holds the cases that use the scenario's ``[fmus]``), named
``SystemStructure_<swapped fmus>.ssd``. :func:`case_ssd` finds a case's SSD.

The archive is written to a temporary file beside the target and renamed, so a
reader never sees half a file. :func:`validate_ssp` checks every SSD and SSV
against the SSP 1.0 schemas that ship with fmpy (``fmpy/ssp/schema``).
"""

from __future__ import annotations

import io
import os
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

from fmpy import read_model_description
from lxml import etree

from . import runner
from .config import Scenario

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations",
}
DEFAULT_SSD = "SystemStructure.ssd"
DEFAULT_SSP_DIR = runner.REPO / "build" / "ssp"
#: FMI causality -> SSP 1.0 connector kind (other causalities are not exported).
_KINDS = {"input": "input", "output": "output", "parameter": "parameter", "calculatedParameter": "calculatedParameter"}
_BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # fixed timestamps: the same inputs give the same archive


class SSPExportError(ValueError):
    """The scenario cannot be expressed as an SSP, or an archive is not a valid one."""


@dataclass
class SystemPlan:
    """One SSD of the archive: the FMUs of a group of cases, their wiring and the cases' parameters."""

    ssd_name: str
    setup: runner.Setup
    #: instance -> resource path inside the archive ("resources/plant.fmu")
    sources: dict[str, str]
    #: case key -> {instance: {variable: value}} (plant start angles included)
    parameters: dict[str, dict[str, dict]]
    labels: dict[str, str]


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _fmt_real(x: float) -> str:
    """Shortest text that reads back as exactly the same double (xs:double)."""
    return repr(float(x))


def _var_type(v) -> str:
    return "Enumeration" if v.type == "Enumeration" else v.type


def plan_systems(scenario: Scenario, fmu_dir: Path = runner.DEFAULT_FMU_DIR, build: bool = True) -> list[SystemPlan]:
    """Group the scenario's cases by FMU set and prepare each group as the runner would (FMUs built if needed)."""
    groups: dict[tuple, list] = {}
    for case in scenario.cases:
        groups.setdefault(tuple(sorted((case.fmus or scenario.fmus).items())), []).append(case)
    default_key = tuple(sorted(scenario.fmus.items()))
    keys = sorted(groups, key=lambda k: (k != default_key, list(groups).index(k)))
    plans, resources, used_names = [], {}, set()
    for i, key in enumerate(keys):
        names = dict(key)
        setup = runner.prepare(scenario, fmu_dir, names=names, build=build)
        if i == 0:
            ssd_name = DEFAULT_SSD
        else:
            swapped = [Path(n).stem for inst, n in sorted(names.items()) if scenario.fmus.get(inst) != n]
            ssd_name = f"SystemStructure_{'_'.join(swapped) or i}.ssd"
            while ssd_name in used_names:
                ssd_name = ssd_name[:-4] + "_.ssd"
        used_names.add(ssd_name)
        sources = {}
        for inst in scenario.order:
            path = Path(setup.paths[inst]).resolve()
            if path not in resources:
                stem, taken = path.stem, set(resources.values())
                res = f"resources/{stem}.fmu"
                n = 2
                while res in taken:
                    res, n = f"resources/{stem}_{n}.fmu", n + 1
                resources[path] = res
            sources[inst] = resources[path]
        params = {c.key: setup.case_parameters(c.parameters) for c in groups[key]}
        plans.append(SystemPlan(ssd_name, setup, sources, params, {c.key: c.label for c in groups[key]}))
    return plans


def parameter_set_xml(name: str, values: dict, variables: dict, description: str | None = None) -> bytes:
    """An SSP 1.0 ParameterValues document (``.ssv``) for one FMU instance.

    `variables` (name -> fmpy ScalarVariable) gives each value its type; every
    name must be a parameter or input of the FMU.
    """
    root = etree.Element(_q("ssv", "ParameterSet"), nsmap={"ssv": NS["ssv"]}, version="1.0", name=name)
    if description:
        root.set("description", description)
    params = etree.SubElement(root, _q("ssv", "Parameters"))
    for var, value in values.items():
        v = variables.get(var)
        if v is None:
            raise SSPExportError(f"parameter set '{name}': the FMU has no variable '{var}'")
        if v.causality not in ("parameter", "input"):
            raise SSPExportError(f"parameter set '{name}': '{var}' is an {v.causality}, not a parameter or input")
        p = etree.SubElement(params, _q("ssv", "Parameter"), name=var)
        if v.type == "Real":
            e = etree.SubElement(p, _q("ssv", "Real"), value=_fmt_real(value))
            if v.unit:
                e.set("unit", v.unit)
        elif v.type == "Integer":
            etree.SubElement(p, _q("ssv", "Integer"), value=str(int(value)))
        elif v.type == "Boolean":
            etree.SubElement(p, _q("ssv", "Boolean"), value="true" if bool(value) else "false")
        elif v.type == "String":
            etree.SubElement(p, _q("ssv", "String"), value=str(value))
        else:
            raise SSPExportError(f"parameter set '{name}': '{var}' has type {v.type}, which the export does not write")
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def _ssv_path(case: str, instance: str) -> str:
    return f"resources/{case}/{instance}.ssv"


def system_structure_xml(scenario: Scenario, plan: SystemPlan) -> bytes:
    """The SSD (SSP 1.0 SystemStructureDescription) of one plan."""
    setup = plan.setup
    mds = {inst: read_model_description(str(setup.paths[inst])) for inst in scenario.order}
    root = etree.Element(_q("ssd", "SystemStructureDescription"), nsmap=NS, version="1.0", name=scenario.name,
                         generationTool="flexarm-fmi scenarios.ssp")
    if scenario.description:
        root.set("description", scenario.description)
    system = etree.SubElement(root, _q("ssd", "System"), name=scenario.name)
    elements = etree.SubElement(system, _q("ssd", "Elements"))
    units = {}
    for inst in scenario.order:
        md = mds[inst]
        for u in md.unitDefinitions:
            units.setdefault(u.name, u)
        comp = etree.SubElement(elements, _q("ssd", "Component"), name=inst, source=plan.sources[inst],
                                type="application/x-fmu-sharedlibrary", implementation="CoSimulation")
        connectors = etree.SubElement(comp, _q("ssd", "Connectors"))
        for v in md.modelVariables:
            kind = _KINDS.get(v.causality)
            if kind is None:
                continue
            c = etree.SubElement(connectors, _q("ssd", "Connector"), name=v.name, kind=kind)
            if v.description:
                c.set("description", v.description)
            t = etree.SubElement(c, _q("ssc", _var_type(v)))
            if v.type == "Real" and v.unit:
                t.set("unit", v.unit)
            elif v.type == "Enumeration":
                t.set("name", v.declaredType.name)
        bindings = etree.SubElement(comp, _q("ssd", "ParameterBindings"))
        for case in plan.parameters:
            etree.SubElement(bindings, _q("ssd", "ParameterBinding"), type="application/x-ssp-parameter-set",
                             source=_ssv_path(case, inst))
    conns = etree.SubElement(system, _q("ssd", "Connections"))
    for c in setup.connections:
        etree.SubElement(conns, _q("ssd", "Connection"), startElement=c.src_fmu, startConnector=c.src_var,
                         endElement=c.dst_fmu, endConnector=c.dst_var)
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
    h = scenario.step_size
    exp = etree.SubElement(root, _q("ssd", "DefaultExperiment"), startTime="0.0",
                           stopTime=_fmt_real(round(setup.n_steps * h, 12)))
    ann = etree.SubElement(etree.SubElement(exp, _q("ssd", "Annotations")), _q("ssc", "Annotation"),
                           type="com.opensimulationplatform")
    algo = etree.SubElement(ann, _q("osp", "Algorithm"))
    etree.SubElement(algo, _q("osp", "FixedStepAlgorithm"), baseStepSize=_fmt_real(h))
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def export_ssp(scenario: Scenario, out_path: str | Path, fmu_dir: str | Path = runner.DEFAULT_FMU_DIR,
               build: bool = True) -> Path:
    """Write the scenario as an SSP archive at `out_path` (a ``.ssp`` file, or a folder for ``<name>.ssp``).

    FMUs are built into `fmu_dir` if needed (as ``python -m scenarios run`` does).
    Returns the path written.
    """
    out = Path(out_path)
    if out.suffix != ".ssp":
        out = out / f"{scenario.name}.ssp"
    plans = plan_systems(scenario, Path(fmu_dir), build)
    members: dict[str, bytes | Path] = {}
    for plan in plans:
        members[plan.ssd_name] = system_structure_xml(scenario, plan)
        for inst in scenario.order:
            members.setdefault(plan.sources[inst], Path(plan.setup.paths[inst]))
            variables = {v.name: v for v in read_model_description(str(plan.setup.paths[inst])).modelVariables}
            for case, params in plan.parameters.items():
                members[_ssv_path(case, inst)] = parameter_set_xml(case, params.get(inst, {}), variables,
                                                                   plan.labels[case])
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=f".{out.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f, zipfile.ZipFile(f, "w") as zf:
            for name in sorted(members, key=lambda n: (not n.endswith(".ssd"), n)):
                data = members[name]
                info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
                info.external_attr = 0o644 << 16
                if isinstance(data, Path):
                    info.compress_type = zipfile.ZIP_STORED  # an FMU is already a zip
                    with zf.open(info, "w") as dst, open(data, "rb") as src:
                        while chunk := src.read(1 << 20):
                            dst.write(chunk)
                else:
                    info.compress_type = zipfile.ZIP_DEFLATED
                    zf.writestr(info, data)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp's 0600 would make the archive private
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return out


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


def parameter_sets(ssp_path: str | Path) -> dict[str, str]:
    """Case (parameter set name) -> the SSD in the archive that holds it."""
    out = {}
    with zipfile.ZipFile(ssp_path) as zf:
        for name in sorted(zf.namelist(), key=lambda n: n != DEFAULT_SSD):
            if not name.endswith(".ssd"):
                continue
            doc = etree.parse(io.BytesIO(zf.read(name)))
            for b in doc.iterfind("ssd:System/ssd:Elements/ssd:Component/ssd:ParameterBindings/"
                                  "ssd:ParameterBinding", NS):
                src = b.get("source")
                if src:
                    set_name = etree.parse(io.BytesIO(zf.read(src))).getroot().get("name")
                    out.setdefault(set_name, name)
    return out


def case_ssd(ssp_path: str | Path, case_key: str) -> str:
    """The SSD of the archive that holds the case's parameter set."""
    sets = parameter_sets(ssp_path)
    if case_key not in sets:
        raise SSPExportError(f"case '{case_key}': no such parameter set in {ssp_path} (has: {', '.join(sets)})")
    return sets[case_key]
