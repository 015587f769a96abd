"""Build this project's FMUs into ``build/fmus/<name>.fmu``.

Usage::

    python build_fmus.py                 # build every FMU whose sources changed
    python build_fmus.py --only plant    # one FMU
    python build_fmus.py --out DIR       # another output folder
    python build_fmus.py --force         # rebuild even if up to date

Each FMU is built with pythonfmu's builder and bundles, in its ``resources``:

* its slave script (module name unique per FMU, e.g. ``flexarm_plant_fmu``),
* the shared glue ``fmus/common/*.py``,
* the ``flexarm`` package with its data files (no ``__pycache__``), and
* ``flexarm_bundle.json``: SHA-256 of the bundled sources, read by the glue
  to detect FMUs of different builds loaded into one interpreter.

so that the FMU runs when copied alone to another machine with only NumPy
and SciPy installed (Numba optional). The builder's output is then finished:

* ``binaries/linux64/<modelIdentifier>.so`` becomes the FMI front end
  ``fmus/common/fmi2_shim.c``, compiled here with the C compiler (``$CC``,
  default ``gcc``) against fmpy's FMI 2.0 headers, with the FMU's GUID
  built in; pythonfmu's binary moves beside it as
  ``libpythonfmu-export.so`` (see ``fmus/common/flexarm_fmu_base.py``,
  "Error statuses"). pythonfmu's Windows binary is left out: the shim is
  built for Linux x86-64 only.
* ``documentation/index.html`` is generated from the FMU's variable table
  (what it models, every variable with unit, causality, range and start
  value, how to connect and step it); ``docs/fmu-interface.md`` rides along.

Every FMU is checked with ``fmpy.validation.validate_fmu`` before it
replaces the previous file (build to a temporary file, then rename). Add an
FMU with one entry in :data:`FMUS`.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import html
import importlib
import importlib.util
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from xml.etree import ElementTree

ROOT = Path(__file__).resolve().parent
#: Default output folder (documented in README and docs/fmu-interface.md).
DEFAULT_OUT_DIR = ROOT / "build" / "fmus"
COMMON_DIR = ROOT / "fmus" / "common"
FLEXARM_DIR = ROOT / "flexarm"
DOC_FILE = ROOT / "docs" / "fmu-interface.md"
#: The FMI front end compiled into every FMU's binaries/linux64/<modelIdentifier>.so.
SHIM_SOURCE = COMMON_DIR / "fmi2_shim.c"
#: pythonfmu's own binary inside the FMU (loaded by the shim from its folder).
INNER_BINARY = "libpythonfmu-export.so"
_IGNORE = shutil.ignore_patterns("__pycache__", "*.pyc", "*.pyo", "*.tmp", ".*")


def _load_glue():
    # Under a private name: the FMUs import the glue as 'flexarm_fmu_base', and a
    # copy cached here from the project tree would shadow the bundled one.
    name = "_flexarm_fmu_base_for_build"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, COMMON_DIR / "flexarm_fmu_base.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # dataclasses look their module up here
        spec.loader.exec_module(module)
    return sys.modules[name]


_glue = _load_glue()
BUNDLE_MANIFEST, bundle_files, tree_sha256 = _glue.BUNDLE_MANIFEST, _glue.bundle_files, _glue.tree_sha256


@dataclass(frozen=True)
class FmuSpec:
    """One FMU of the project.

    Attributes
    ----------
    name : str
        Output file stem: ``<out_dir>/<name>.fmu``.
    script : Path
        Slave script; its stem is the Python module name inside the FMU and
        must be unique among all FMUs (they may share one interpreter).
    extra_files : tuple of Path
        Further files or folders bundled into this FMU's resources.
    """

    name: str
    script: Path
    extra_files: tuple[Path, ...] = field(default=())


#: The controller FMUs: one slave module each, sharing flexarm_controller_base.py.
CONTROLLER_DIR = ROOT / "fmus" / "controller"

#: Every FMU of the project. The glue in fmus/common (base, feedthrough) goes into every FMU.
FMUS: dict[str, FmuSpec] = {
    spec.name: spec for spec in (
        FmuSpec("plant", ROOT / "fmus" / "plant" / "flexarm_plant_fmu.py"),
        FmuSpec("sensors", ROOT / "fmus" / "sensors" / "flexarm_sensors_fmu.py"),
        *(FmuSpec(f"controller{suffix}", CONTROLLER_DIR / f"flexarm_controller{suffix}_fmu.py",
                  (CONTROLLER_DIR / "flexarm_controller_base.py",))
          for suffix in ("", "_ff", "_fb", "_dlqr", "_lqg")),
    )
}

#: Capabilities written into <CoSimulation> (pythonfmu option names).
FMU_OPTIONS = {
    "canHandleVariableCommunicationStepSize": True,
    "canGetAndSetFMUstate": True,
    "canSerializeFMUstate": True,
}


class BuildError(RuntimeError):
    """An FMU could not be built or failed validation."""


def _files(path: Path) -> list[Path]:
    return [path] if path.is_file() else bundle_files(path)


def _sources(spec: FmuSpec) -> list[Path]:
    """Every file the FMU is made from (for the up-to-date check)."""
    out = [spec.script, *[f for e in spec.extra_files for f in _files(e)]]
    return out + sorted(COMMON_DIR.glob("*.py")) + [SHIM_SOURCE] + bundle_files(FLEXARM_DIR)


def is_up_to_date(spec: FmuSpec, fmu: Path) -> bool:
    """True if `fmu` exists and is newer than every source (and this build script)."""
    if not fmu.is_file():
        return False
    newest = max(p.stat().st_mtime for p in [*_sources(spec), Path(__file__)] + ([DOC_FILE] * DOC_FILE.is_file()))
    return fmu.stat().st_mtime >= newest


@contextlib.contextmanager
def _import_sandbox(paths: list[Path]):
    """Let pythonfmu import the slave script, then undo sys.path and sys.modules changes.

    Without this, a later in-process load of the built FMU would find the
    project's copy of the slave module already in ``sys.modules`` instead
    of the one bundled in the FMU.
    """
    saved_path = list(sys.path)
    # The FMUs' own top-level modules (slave scripts and glue): by name, wherever they
    # were imported from (this tree, or an FMU's unpacked resources).
    ours = {p.stem for p in (ROOT / "fmus").glob("*/*.py")}
    # Those of FMUs already loaded in this process would shadow the project's sources:
    # set them aside while building, and put them back afterwards for those FMUs' sake.
    shadowing = {name: sys.modules.pop(name) for name in ours & set(sys.modules)}
    sys.path[:0] = [str(p) for p in paths]
    try:
        yield
    finally:
        sys.path[:] = saved_path
        for name in ours & set(sys.modules):
            del sys.modules[name]
        sys.modules.update(shadowing)


def c_compiler() -> str:
    """Path of the C compiler that builds the FMI front end (``$CC``, default ``gcc``); BuildError if none."""
    cc = os.environ.get("CC") or "gcc"
    path = shutil.which(cc)
    if path is None:
        raise BuildError(
            f"no C compiler: {cc!r} is not on PATH. Building the FMUs compiles their FMI front end "
            f"({SHIM_SOURCE.relative_to(ROOT)}) with a C compiler; install gcc (Debian/Ubuntu: "
            "'sudo apt-get install gcc') or set CC to a C compiler.")
    return path


def fmi_headers() -> Path:
    """Folder with the FMI 2.0 C headers (fmpy ships them)."""
    import fmpy

    folder = Path(fmpy.__file__).parent / "c-code"
    if not (folder / "fmi2Functions.h").is_file():
        raise BuildError(f"the FMI 2.0 headers are not in {folder} (fmpy {fmpy.__version__}); "
                         "install an fmpy that ships its c-code folder")
    return folder


def compile_shim(guid: str, model_identifier: str, dest: Path) -> Path:
    """Compile :data:`SHIM_SOURCE` for one FMU into `dest` (a .so); BuildError with the compiler's output."""
    if not all(c.isalnum() or c in "-{}" for c in guid) or not model_identifier.isidentifier():
        raise BuildError(f"unexpected GUID {guid!r} or model identifier {model_identifier!r}")
    cmd = [c_compiler(), "-std=c11", "-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-Wall", "-Wextra",
           f"-I{fmi_headers()}", f'-DFLEXARM_FMU_GUID="{guid}"', f'-DFLEXARM_MODEL_IDENTIFIER="{model_identifier}"',
           "-o", str(dest), str(SHIM_SOURCE), "-ldl", "-lpthread"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"compiling the FMI front end failed:\n  {' '.join(cmd)}\n{proc.stderr.strip()}")
    if proc.stderr.strip():
        warnings.warn(f"{SHIM_SOURCE.name}: compiler warnings:\n{proc.stderr.strip()}", stacklevel=2)
    return dest


def _check_platform() -> None:
    if sys.platform != "linux" or platform.machine() not in ("x86_64", "AMD64"):
        raise BuildError(f"the FMUs are built for Linux x86-64 (binaries/linux64) only; this is {sys.platform} "
                         f"{platform.machine()}")


def _slave_class(module):
    """The FlexarmSlave subclass a slave module defines (the one pythonfmu instantiates)."""
    base = sys.modules["flexarm_fmu_base"].FlexarmSlave
    found = [c for c in vars(module).values()
             if isinstance(c, type) and issubclass(c, base) and c.__module__ == module.__name__]
    if len(found) != 1:
        raise BuildError(f"{module.__name__}: expected one FlexarmSlave subclass, found {[c.__name__ for c in found]}")
    return found[0]


def _import_paths(spec: FmuSpec) -> list[Path]:
    # Folders of extra modules too: importing the script may import them.
    return [COMMON_DIR, spec.script.parent, *[e.parent for e in spec.extra_files if e.suffix == ".py"]]


def interfaces() -> dict[str, dict]:
    """Every FMU's interface from its slave class: {name: {"cls", "module_doc", "variables"}}."""
    out = {}
    for name, spec in FMUS.items():
        with _import_sandbox(_import_paths(spec)):
            module = importlib.import_module(spec.script.stem)
            cls = _slave_class(module)
            defining = sys.modules[next(k.__module__ for k in cls.__mro__ if "VARIABLES" in vars(k))]
            docs = [d for d in dict.fromkeys((module.__doc__, defining.__doc__)) if d]
            out[name] = {"cls": cls, "docs": docs, "variables": tuple(cls.VARIABLES)}
    return out


def build_fmu(spec: FmuSpec, out_dir: Path, peers: dict[str, dict] | None = None) -> Path:
    """Build one FMU into ``out_dir/<spec.name>.fmu`` (temporary file, finish, validate, rename).

    `peers` (from :func:`interfaces`) names the other FMUs in the generated
    documentation's connection table; computed if not given.
    """
    from fmpy.validation import validate_fmu
    from pythonfmu.builder import FmuBuilder

    _check_platform()
    c_compiler()  # fail before building anything
    peers = interfaces() if peers is None else peers
    out_dir.mkdir(parents=True, exist_ok=True)
    final = out_dir / f"{spec.name}.fmu"
    with tempfile.TemporaryDirectory(prefix=f"build_{spec.name}_") as tmp:
        stage = Path(tmp)
        shutil.copytree(FLEXARM_DIR, stage / "flexarm", ignore=_IGNORE)
        for f in COMMON_DIR.glob("*.py"):
            shutil.copy2(f, stage / f.name)
        manifest = stage / BUNDLE_MANIFEST
        manifest.write_text(json.dumps({
            "fmu": spec.name, "slave_module": spec.script.stem, "flexarm_sha256": tree_sha256(stage / "flexarm"),
            "flexarm_files": [f.relative_to(stage / "flexarm").as_posix() for f in bundle_files(stage / "flexarm")],
            "shim_sha256": hashlib.sha256(SHIM_SOURCE.read_bytes()).hexdigest(),
        }, indent=1))
        project_files = [stage / "flexarm", manifest, *[stage / f.name for f in COMMON_DIR.glob("*.py")],
                         *spec.extra_files]
        raw_fmu = stage / "pythonfmu.fmu"
        fd, tmp_name = tempfile.mkstemp(dir=out_dir, prefix=f".{spec.name}-", suffix=".fmu")
        os.close(fd)
        tmp_fmu = Path(tmp_name)
        try:
            with _import_sandbox(_import_paths(spec)):
                FmuBuilder.build_FMU(spec.script, dest=raw_fmu, project_files=project_files, **FMU_OPTIONS)
            finish_fmu(raw_fmu, tmp_fmu, spec, peers, stage)
            problems = validate_fmu(str(tmp_fmu))
            if problems:
                raise BuildError(f"{spec.name}: fmpy.validate_fmu found {len(problems)} problem(s):\n  "
                                 + "\n  ".join(problems))
            os.replace(tmp_fmu, final)
        finally:
            tmp_fmu.unlink(missing_ok=True)
    return final


def finish_fmu(raw_fmu: Path, dest: Path, spec: FmuSpec, peers: dict[str, dict], work: Path) -> None:
    """Turn pythonfmu's FMU into ours: the shim as the FMU's binary, pythonfmu's beside it, documentation."""
    with zipfile.ZipFile(raw_fmu) as raw:
        md = ElementTree.fromstring(raw.read("modelDescription.xml"))
        cosim = md.find("CoSimulation")
        model_id, guid = cosim.get("modelIdentifier"), md.get("guid")
        inner = raw.read(f"binaries/linux64/{model_id}.so")
        shim = compile_shim(guid, model_id, work / f"{model_id}.so").read_bytes()
        page = render_documentation(spec.name, md, peers)
        with zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as out:
            for info in raw.infolist():
                if not info.filename.startswith(("binaries/", "documentation/")):
                    out.writestr(info.filename, raw.read(info), zipfile.ZIP_DEFLATED)
            for name, data in ((f"binaries/linux64/{model_id}.so", shim), (f"binaries/linux64/{INNER_BINARY}", inner)):
                info = zipfile.ZipInfo(name, date_time=(2024, 1, 1, 0, 0, 0))
                info.external_attr = 0o755 << 16
                out.writestr(info, data, zipfile.ZIP_DEFLATED)
            out.writestr("documentation/index.html", page)
            if DOC_FILE.is_file():
                out.write(DOC_FILE, f"documentation/{DOC_FILE.name}")


# -- documentation/index.html -------------------------------------------------------------------
#: How each kind of FMU is stepped and wired (the rest of the page comes from the variable table).
_USAGE = {
    "plant": ("Any finite communication step <code>h</code> &gt; 0 (variable steps allowed); the project uses "
              "1 ms. The outputs have no direct feedthrough: they depend on the state and on the torque held over "
              "the step that ended at the communication point, so the controller's torques can be set after the "
              "outputs are read without an algebraic loop."),
    "sensors": ("Every communication step must equal the parameter <code>sample_period</code> (1 ms by default; "
                "the filters are discretised for it). Direct feedthrough: set the inputs at t<sub>k</sub>, then "
                "read the outputs, which are the sample of those inputs; exactly one sample (one noise draw, one "
                "filter update) per communication point, whatever the number of reads."),
    "controller": ("Communication points on the trajectory's 1 ms grid (any multiple of 1 ms as the step); the "
                   "slew starts at t = 0. Direct feedthrough: set the measurements at t<sub>k</sub>, read the "
                   "torques computed from them, hand them to the plant, which holds them over "
                   "[t<sub>k</sub>, t<sub>k</sub> + h)."),
}


def _inline(text: str) -> str:
    import re

    text = html.escape(text, quote=False)
    text = re.sub(r"``(.+?)``", r"<code>\1</code>", text)
    return re.sub(r":(?:class|func|meth|mod|data|attr):`~?(.+?)`", r"<code>\1</code>", text)


def _docstring_html(doc: str) -> str:
    """Paragraphs, bullet lists and literal blocks of a (reST-flavoured) docstring as HTML."""
    import re
    import textwrap

    lines = doc.strip().splitlines()
    body = lines[0] + "\n" + textwrap.dedent("\n".join(lines[1:]))
    out = []
    for para in re.split(r"\n\s*\n", body.strip()):
        rows = para.splitlines()
        if rows[0].lstrip().startswith(("* ", "- ")):
            items: list[str] = []
            for row in rows:
                if row.lstrip().startswith(("* ", "- ")):
                    items.append(row.lstrip()[2:])
                else:
                    items[-1] += " " + row.strip()
            out.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in items) + "</ul>")
        elif rows[0].startswith(("===", "    ")) or para.endswith("::"):
            out.append(f"<pre>{html.escape(para)}</pre>")
        else:
            out.append(f"<p>{_inline(' '.join(r.strip() for r in rows))}</p>")
    return "\n".join(out)


def _fmt_value(var, value) -> str:
    if value is None:
        return "–"
    if var.type == "Boolean":
        return "true" if value else "false"
    if var.type == "String":
        return f'"{value}"'
    if var.type == "Real":
        v = float(value)
        for k, label in ((1, "π"), (2, "2π"), (0.5, "π/2")):
            if abs(abs(v) - k * math.pi) < 1e-15:
                return f"{'-' if v < 0 else ''}{label} ({v:.16g})"
        return f"{v:.16g}"
    return str(value)


def _range(var) -> str:
    if var.type in ("Boolean", "String"):
        return "–" if var.type == "Boolean" else "see the description"
    if var.min is None and var.max is None:
        return "any finite value" if var.type == "Real" else "any value"
    lo = "−∞" if var.min is None else _fmt_value(var, var.min)
    hi = "∞" if var.max is None else _fmt_value(var, var.max)
    return f"[{lo}, {hi}]"


def render_documentation(name: str, md: ElementTree.Element, peers: dict[str, dict]) -> str:
    """``documentation/index.html`` of FMU `name` from its variable table and modelDescription.xml."""
    info = peers[name]
    variables = info["variables"]
    cosim = md.find("CoSimulation")
    model_id = cosim.get("modelIdentifier")
    vrs = {sv.get("name"): sv.get("valueReference") for sv in md.find("ModelVariables")}
    kind = "controller" if name.startswith("controller") else name
    esc = html.escape

    def sources(var) -> str:  # where an input comes from / an output goes to, by name
        want = "output" if var.causality == "input" else "input"
        hits = [f"{other}.{var.name}" for other, o in peers.items()
                if other != name and any(v.name == var.name and v.causality == want for v in o["variables"])]
        return ", ".join(hits) if hits else "–"

    def table(rows, columns) -> str:
        head = "".join(f"<th>{c}</th>" for c in columns)
        return f"<table>\n<tr>{head}</tr>\n" + "\n".join(rows) + "\n</table>"

    def row(var, cells) -> str:
        return (f'<tr id="var-{esc(var.name)}"><td><code>{esc(var.name)}</code></td>'
                + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")

    unit = lambda v: esc(v.unit) if v.unit and v.unit != "1" and v.type == "Real" else "–"  # noqa: E731
    inputs = [row(v, [vrs[v.name], v.type, unit(v), _fmt_value(v, v.start), _range(v), esc(sources(v)),
                      esc(v.description)]) for v in variables if v.causality == "input"]
    params = [row(v, [vrs[v.name], v.type, unit(v), v.variability, _fmt_value(v, v.start), _range(v),
                      esc(v.description)]) for v in variables if v.causality == "parameter"]
    outputs = [row(v, [vrs[v.name], v.type, unit(v), "none" if v.depends_on == () else
                       ", ".join(v.depends_on) if v.depends_on else "every input", esc(sources(v)),
                       esc(v.description)]) for v in variables if v.causality == "output"]
    others = [row(v, [vrs[v.name], v.causality, v.variability, v.type, unit(v), _fmt_value(v, v.start),
                      esc(v.description)]) for v in variables if v.causality not in ("input", "parameter", "output")]
    experiment = md.find("DefaultExperiment")
    default_h = experiment.get("stepSize") if experiment is not None else None
    caps = ", ".join(f"{k}={v}" for k, v in sorted(cosim.attrib.items()) if k != "modelIdentifier")
    sections = [
        f"<h1>{esc(name)}.fmu: {esc(md.get('description') or '')}</h1>",
        "<table class='facts'>"
        f"<tr><th>FMI</th><td>2.0, co-simulation</td></tr>"
        f"<tr><th>model identifier</th><td><code>{esc(model_id)}</code></td></tr>"
        f"<tr><th>GUID</th><td><code>{esc(md.get('guid'))}</code></td></tr>"
        f"<tr><th>generated by</th><td>{esc(md.get('generationTool') or '')}, flexarm-fmi build_fmus.py, "
        f"version {esc(md.get('version') or '')}</td></tr>"
        f"<tr><th>platform</th><td>binaries/linux64 (Linux x86-64)</td></tr>"
        f"<tr><th>capabilities</th><td>{esc(caps)}</td></tr></table>",
        "<h2>What it models</h2>",
        *(_docstring_html(d) for d in info["docs"]),
        "<h2>How to use it</h2>",
        "<ul>"
        "<li>Sequence: <code>fmi2Instantiate</code> → <code>fmi2SetupExperiment</code> → "
        "<code>fmi2EnterInitializationMode</code> → set parameters and inputs → "
        "<code>fmi2ExitInitializationMode</code> → repeat {read outputs, set inputs, "
        "<code>fmi2DoStep(t, h)</code>} → <code>fmi2Terminate</code> → <code>fmi2FreeInstance</code>. "
        "Parameters (variability fixed) can be set only before <code>fmi2ExitInitializationMode</code>.</li>"
        "<li>After <code>fmi2DoStep(t, h)</code> the outputs describe t + h; every input is held over the step "
        "(zero-order hold).</li>"
        f"<li>Step size: {_USAGE[kind]} Default experiment step: {esc(default_h or '–')} s.</li>"
        "<li>Connections are by name: the plant's outputs feed the sensors' inputs of the same name, the "
        "sensors' outputs the controller's inputs, the controller's <code>tau1</code>, <code>tau2</code> the "
        "plant's. Evaluate in the order plant → sensors → controller at each communication point (see the "
        "tables below and <a href='fmu-interface.md'>fmu-interface.md</a>).</li>"
        "<li>Errors: a call made in the wrong state, a NaN/inf or out-of-range value, a refused step returns "
        "<code>fmi2Error</code> with a log message naming the call or the variable and its allowed range, and "
        "changes nothing (set a valid value and go on). <code>fmi2Discard</code> means a step that a smaller "
        "one may complete (the FMU stays at t). <code>fmi2GetFMUstate</code>/<code>fmi2SetFMUstate</code>, "
        "serialisation and <code>fmi2Reset</code> are supported.</li></ul>",
        "<h2>Running it</h2>",
        "<p>The FMU runs Python inside the host process: it needs the Python 3.11 shared library "
        "(<code>libpython3.11.so.1.0</code>) with NumPy and SciPy importable (Numba optional: it makes the "
        "plant about 8 times faster; without it the same mathematics runs in NumPy). Everything else (the "
        "<code>flexarm</code> physics package, its data, pythonfmu's Python part) is in "
        "<code>resources/</code>. In a Python host (fmpy) nothing else is needed. In a native host on Linux, "
        "if the host has not loaded Python, the FMU loads <code>libpython3.11.so.1.0</code> itself (or the "
        "file named by <code>FLEXARM_FMU_LIBPYTHON</code>); or start the host with "
        "<code>LD_PRELOAD=/path/to/libpython3.11.so.1.0</code>. Point <code>PYTHONHOME</code> at that "
        "Python's prefix and <code>PYTHONPATH</code> at a site-packages folder with NumPy and SciPy:</p>"
        "<pre>PY=python3.11\n"
        "LIBPY=$($PY -c 'import sysconfig as s; print(s.get_config_var(\"LIBDIR\") + \"/\" + "
        "s.get_config_var(\"INSTSONAME\"))')\n"
        "LD_PRELOAD=$LIBPY PYTHONHOME=$($PY -c 'import sys; print(sys.base_prefix)') \\\n"
        "PYTHONPATH=/path/to/venv/lib/python3.11/site-packages  your-fmi-host " + esc(name) + ".fmu</pre>",
        "<h2>Inputs</h2>",
        table(inputs, ["name", "vr", "type", "unit", "start", "range", "connect from", "description"])
        if inputs else "<p>None.</p>",
        "<h2>Parameters</h2>",
        table(params, ["name", "vr", "type", "unit", "variability", "start", "range", "description"])
        if params else "<p>None.</p>",
        "<h2>Outputs</h2>",
        table(outputs, ["name", "vr", "type", "unit", "depends directly on", "connect to", "description"])
        if outputs else "<p>None.</p>",
    ]
    if others:
        sections += ["<h2>Other variables</h2>",
                     table(others, ["name", "vr", "causality", "variability", "type", "unit", "start",
                                    "description"])]
    style = ("body{font-family:sans-serif;max-width:70em;margin:2em auto;line-height:1.4}"
             "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:.2em .5em;"
             "text-align:left;vertical-align:top}th{background:#eee}code{font-size:95%}pre{background:#f6f6f6;"
             "padding:.5em;overflow-x:auto}")
    return ("<!DOCTYPE html>\n<html lang='en'>\n<head><meta charset='utf-8'>"
            f"<title>{esc(name)}.fmu ({esc(model_id)})</title><style>{style}</style></head>\n<body>\n"
            + "\n".join(sections) + "\n</body>\n</html>\n")


def build_all(out_dir: str | os.PathLike | None = None, only=None, force: bool = False) -> dict[str, Path]:
    """Build the project's FMUs; return {name: path of the .fmu}.

    Parameters
    ----------
    out_dir : path-like, optional
        Output folder (default ``build/fmus``).
    only : str or iterable of str, optional
        Names from :data:`FMUS` to build (default: all).
    force : bool
        Rebuild even if the FMU is newer than all its sources.
    """
    out_dir = Path(out_dir) if out_dir is not None else DEFAULT_OUT_DIR
    names = list(FMUS) if only is None else ([only] if isinstance(only, str) else list(only))
    unknown = [n for n in names if n not in FMUS]
    if unknown:
        raise BuildError(f"unknown FMU name(s) {unknown}; choose from {sorted(FMUS)}")
    result, peers = {}, None
    for name in names:
        spec = FMUS[name]
        target = out_dir / f"{name}.fmu"
        if not force and is_up_to_date(spec, target):
            result[name] = target
            continue
        peers = interfaces() if peers is None else peers  # once per build, for the documentation
        result[name] = build_fmu(spec, out_dir, peers)
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", action="append", choices=sorted(FMUS), help="build only this FMU (repeatable)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT_DIR, help=f"output folder (default {DEFAULT_OUT_DIR})")
    parser.add_argument("--force", action="store_true", help="rebuild even if up to date")
    args = parser.parse_args(argv)
    try:
        before = {n: (args.out / f"{n}.fmu").stat().st_mtime if (args.out / f"{n}.fmu").exists() else None
                  for n in (args.only or FMUS)}
        built = build_all(args.out, args.only, args.force)
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for name, path in built.items():
        state = "up to date" if before[name] == path.stat().st_mtime else "built"
        print(f"{name}: {path} ({state})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
