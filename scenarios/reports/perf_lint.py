"""Typed performance figures in the docs: ``results-page --check`` refuses them (issue 35).

A performance figure in README.md or docs/*.md must come from a benchmark's output file that records its date,
commit, machine and load, rendered into a generated block (``<!-- results-page:NAME begin ... end -->``, as the
plant's cost table is from ``docs/plant-step-cost.json``). Typed ones went stale (a libcosim factor of 81.7× real
time measured at 6.7-8.0×, a 7.8 µs plant step at 20-26 µs, FMU sizes, the test suite's duration). This finds
the forms those figures took, outside generated blocks: real-time factors, microseconds per step or sample, file
sizes in KiB/MiB, runs per minute, and the minutes a test run or a build takes.
"""

from __future__ import annotations

import re
from pathlib import Path

#: The forms of a typed performance figure (each needs a number).
PATTERNS = {
    "real-time factor": re.compile(r"\d[\d.,]*\s*\**\s*[×x]\s*(?:faster than\s+)?real[- ]time"
                                   r"|real-time factor\s*\**\s*\d[\d.,]*\s*[×x]"),
    "time per step": re.compile(r"\d[\d.,]*\s*\**\s*µs\**\s*(?:per|a|each)\s+(?:1 ms\s+)?(?:step|sample|call)"),
    "file size": re.compile(r"\b\d[\d.,]*\s*[KMG]iB\b"),
    "throughput": re.compile(r"\d[\d.,]*\s*runs/min"),
    "duration of a run": re.compile(r"(?:about|a few|takes?)\s+(?:[\d.]+\s*|a\s+)?(?:minutes?|min)\b"),
}
_BLOCK = re.compile(r"<!-- results-page:([\w.-]+) begin.*?<!-- results-page:\1 end -->", re.S)


def typed_figures(text: str) -> list[tuple[int, str, str]]:
    """(line number, form, the line) of every typed performance figure in `text`, generated blocks left out."""
    blanked = _BLOCK.sub(lambda m: "\n" * m[0].count("\n"), text)
    found = []
    for number, line in enumerate(blanked.splitlines(), 1):
        for form, pattern in PATTERNS.items():
            if pattern.search(line):
                found.append((number, form, line.strip()))
    return found


def check_docs(root: Path) -> list[str]:
    """One message per typed performance figure in README.md and docs/*.md of the checkout at `root`."""
    out = []
    for path in [root / "README.md", *sorted((root / "docs").glob("*.md"))]:
        for number, form, line in typed_figures(path.read_text(encoding="utf-8")):
            out.append(f"{path.relative_to(root)}:{number}: a typed performance figure ({form}): generate it from "
                       f"a benchmark's output file (date, commit, machine, load) or remove it: {line[:160]}")
    return out
