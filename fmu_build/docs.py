"""``documentation/index.html`` of each FMU, generated from its variable table and modelDescription.xml."""

from __future__ import annotations

import html
import math
import re
import sys
import textwrap
from xml.etree import ElementTree

from .compile import libpython_name

# -- documentation/index.html -------------------------------------------------------------------
#: How each kind of FMU is stepped and wired (the rest of the page comes from the variable table).
_USAGE = {
    "plant": ("Any finite communication step <code>h</code> &gt; 0 (variable steps allowed); the project uses "
              "1 ms. The outputs have no direct feedthrough: they depend on the state and on the torque held over "
              "the step that ended at the communication point, so the controller's torques can be set after the "
              "outputs are read without an algebraic loop."),
    "sensors": ("Every communication step must be a whole multiple n of the parameter <code>sample_period</code> "
                "(within 1e-9 s; 1 ms by default; the filters are discretised for it): the FMU then samples n times "
                "inside the step, at its own period, holding the inputs present at <code>fmi2DoStep</code>; a step "
                "of n = 0 (at most 1e-9 s) does nothing. Direct feedthrough: the outputs are a pure function of the "
                "committed state and the inputs present, so set the inputs at t<sub>k</sub>, then read; reads, any "
                "number of them, change nothing, and <code>fmi2DoStep</code> takes the sample of the inputs present "
                "then (one noise draw, one filter update)."),
    "controller": ("Communication steps of whole 1 ms samples (within 1e-9 s; a step of at most 1e-9 s does "
                   "nothing); the slew starts at t = 0. Direct feedthrough: the torques are a pure function of the "
                   "measurements present at t<sub>k</sub> (reads change nothing); the plant holds them over "
                   "[t<sub>k</sub>, t<sub>k</sub> + h). <code>controller_lqg</code> with "
                   "<code>loop_delay_samples</code> &gt; 0 has no direct feedthrough: <code>fmi2DoStep</code> "
                   "computes the torques from the inputs present and holds them until the next step."),
    "reference": ("Communication steps of whole 1 ms samples (within 1e-9 s; a step of at most 1e-9 s does "
                  "nothing); the slew starts at t = 0. No inputs: the outputs at t<sub>k</sub> are the trajectory's "
                  "sample k = round(t<sub>k</sub> / 1 ms) + <code>lead_samples</code>, the final state held after "
                  "t<sub>f</sub>; wire them by name into a controller's inputs (docs/own-controller.md). "
                  "<code>lead_samples</code>: 0 in a Gauss-Seidel master, the communication step in samples in a "
                  "Jacobi one (the controller's torques reach the plant one step late)."),
}


def _inline(text: str) -> str:
    text = html.escape(text, quote=False)
    text = re.sub(r"``(.+?)``", r"<code>\1</code>", text)
    return re.sub(r":(?:class|func|meth|mod|data|attr):`~?(.+?)`", r"<code>\1</code>", text)


def _docstring_html(doc: str) -> str:
    """Paragraphs, bullet lists and literal blocks of a (reST-flavoured) docstring as HTML."""
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
    PY, LIBPY = f"{sys.version_info.major}.{sys.version_info.minor}", html.escape(libpython_name())  # noqa: N806
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
        f"<tr><th>generated by</th><td>{esc(md.get('generationTool') or '')}, flexarm-fmi fmu_build, "
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
        f"<p>The FMU runs Python inside the host process: it needs the Python {PY} shared library "
        f"(<code>{LIBPY}</code>) with NumPy and SciPy importable (Numba optional: it makes the "
        "plant about 8 times faster; without it the same mathematics runs in NumPy). Everything else (the "
        "<code>flexarm</code> physics package, its data, pythonfmu's Python part) is in "
        "<code>resources/</code>. In a Python host (fmpy) nothing else is needed. In a native host on Linux, "
        f"if the host has not loaded Python, the FMU loads <code>{LIBPY}</code> itself (or the "
        "file named by <code>FLEXARM_FMU_LIBPYTHON</code>); or start the host with "
        f"<code>LD_PRELOAD=/path/to/{LIBPY}</code>. Point <code>PYTHONHOME</code> at that "
        "Python's prefix and <code>PYTHONPATH</code> at a site-packages folder with NumPy and SciPy:</p>"
        f"<pre>PY=python{PY}\n"
        "LIBPY=$($PY -c 'import sysconfig as s; print(s.get_config_var(\"LIBDIR\") + \"/\" + "
        "s.get_config_var(\"INSTSONAME\"))')\n"
        "LD_PRELOAD=$LIBPY PYTHONHOME=$($PY -c 'import sys; print(sys.base_prefix)') \\\n"
        f"PYTHONPATH=/path/to/venv/lib/python{PY}/site-packages  your-fmi-host " + esc(name) + ".fmu</pre>",
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
