"""The signal tables of ``docs/fmu-interface.md``, generated from the signal catalogue (``flexarm/data/signals.toml``).

Each table sits between a start marker naming the FMU and causality and an end
marker; :func:`render` replaces what is between them, :func:`write_interface_doc`
rewrites the file (``python build_fmus.py --write-doc``), and a test checks that
the committed document equals :func:`render` of itself.
"""

from __future__ import annotations

import re
from pathlib import Path

from flexarm.signals import FMUS, signals

from .registry import DOC_FILE

START = "<!-- generated from flexarm/data/signals.toml by `python build_fmus.py --write-doc`: {fmu} {causality}s -->"
END = "<!-- end of generated table -->"
_BLOCK = re.compile(re.escape(START).replace(r"\{fmu\}", r"(?P<fmu>\w+)").replace(r"\{causality\}",
                                                                                     r"(?P<causality>\w+)")
                    + r"\n.*?" + re.escape(END), re.S)
_USED = {"feedback": "yes", "unused": "**no**"}


def table(fmu: str, causality: str) -> str:
    """The markdown table of one FMU's inputs or outputs, in the FMU's order."""
    rows = signals(fmu, causality)
    if fmu == "controller" and causality == "input":
        head = "| name | unit | used by the law | meaning |\n|---|---|---|---|"
        body = [f"| `{s.name}` | {s.unit} | {_USED.get(s.group, s.group)} | {s.description} |" for s in rows]
    else:
        head = "| name | unit | meaning |\n|---|---|---|"
        body = [f"| `{s.name}` | {s.unit} | {s.description} |" for s in rows]
    return "\n".join([head, *body])


def render(text: str) -> str:
    """`text` with every generated block replaced by its table from the catalogue."""
    def block(m: re.Match) -> str:
        fmu, causality = m["fmu"], m["causality"]
        if fmu not in FMUS or causality not in ("input", "output"):
            raise ValueError(f"generated block for unknown FMU/causality {fmu!r}/{causality!r}")
        return f"{START.format(fmu=fmu, causality=causality)}\n{table(fmu, causality)}\n{END}"

    return _BLOCK.sub(block, text)


def blocks(text: str) -> list[tuple[str, str]]:
    """(fmu, causality) of every generated block of `text`, in order."""
    return [(m["fmu"], m["causality"]) for m in _BLOCK.finditer(text)]


def write_interface_doc(path: Path = DOC_FILE) -> Path:
    """Regenerate the tables of the interface document in place (atomically); return its path."""
    path = Path(path)
    text = render(path.read_text(encoding="utf-8"))
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    return path
