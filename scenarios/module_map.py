"""docs/architecture.md's module map: every Python module of the project and its one concern, read from the code.

The map is the first sentence of each module's docstring, grouped by folder, so it cannot go stale: the
results page writes it (block ``module-map``), ``results-page --check`` compares it in CI, and
``tests/test_module_map.py`` compares it on every test run (fast: the code is parsed, not imported).
``python -m scenarios.module_map`` rewrites only this block.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

from .page_blocks import _MARKED, REPO, block, splice_blocks

#: The folders whose Python modules the map lists, in the import order the project keeps (tests/test_import_graph.py).
PACKAGES = ("flexarm", "fmus", "fmu_build", "scenarios", "benchmarks")
ARCHITECTURE = REPO / "docs" / "architecture.md"


def concern(path: Path) -> str:
    """The first sentence of the module's docstring (one line), or "" when it has none."""
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"), str(path))) or ""
    first = " ".join(doc.strip().split("\n\n")[0].split())
    end = re.search(r"\.\s+(?=[A-Z`*])", first)  # a sentence's end, not "Fig. 2" or "e.g. a"
    return (first[:end.start() + 1] if end else first).replace("|", "\\|")


def modules(root: Path = REPO) -> list[Path]:
    """Every ``.py`` file under :data:`PACKAGES` (relative to `root`), sorted; caches and build folders left out."""
    found = []
    for package in PACKAGES:
        for path in (root / package).rglob("*.py"):
            rel = path.relative_to(root)
            if not any(part.startswith((".", "__pycache__")) or part == "build" for part in rel.parts[:-1]):
                found.append(rel)
    return sorted(found)


def module_map_markdown(root: Path = REPO) -> str:
    """The map as a Markdown table per folder: module, lines, its concern (first sentence of its docstring)."""
    out, folder = [], None
    for rel in modules(root):
        if rel.parent != folder:
            folder = rel.parent
            out += ["", f"**`{folder.as_posix()}/`**", "", "| module | concern |", "|---|---|"]
        text = concern(root / rel)
        out.append(f"| `{rel.name}` | {text or '(no docstring)'} |")
    return "\n".join(out).strip()


@block("module-map")
def _module_map_block(runs) -> str:
    return module_map_markdown()


def main(argv: list[str] | None = None) -> int:
    """Rewrite (or with ``--check`` compare) only the module-map block of docs/architecture.md."""
    argv = sys.argv[1:] if argv is None else argv
    text = ARCHITECTURE.read_text(encoding="utf-8")
    # Only this block is rewritten: any other generated block keeps its committed text.
    others = {m.group(1): m.group(2).strip("\n") for m in _MARKED.finditer(text)}
    fresh = splice_blocks(text, {**others, "module-map": module_map_markdown()}, str(ARCHITECTURE))
    if "--check" in argv:
        if fresh != text:
            print("docs/architecture.md: the module map differs from the code; run python -m scenarios.module_map")
            return 1
        return 0
    if fresh != text:
        from flexarm.provenance import write_atomic
        write_atomic(ARCHITECTURE, fresh)
        print("docs/architecture.md: module map rewritten")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
