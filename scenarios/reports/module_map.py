"""docs/architecture.md's module map of ``scenarios/``: every module beside the first paragraph of its docstring, read
from the code: ``python -m scenarios.reports.module_map --write`` (or ``--check``); ``results-page`` writes it too.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

from scenarios.reports.page_blocks import _MARKED, REPO, block, splice_blocks

BLOCK = "module-map"
PACKAGE = REPO / "scenarios"
DOC_PATH = REPO / "docs" / "architecture.md"


def summary(path: Path) -> str:
    """The first paragraph of a module's docstring on one line ("(no docstring)" when it has none)."""
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8")))
    if not doc:
        return "(no docstring)"
    return " ".join(doc.split("\n\n")[0].split()).replace("|", "\\|")


def modules(package: Path = PACKAGE) -> list[Path]:
    """The package's modules: the top level's first, then each sub-package's (its ``__init__`` first)."""
    top = sorted(package.glob("*.py"))
    subs = sorted(p for p in package.iterdir() if (p / "__init__.py").is_file())
    inner = [m for sub in subs
             for m in [sub / "__init__.py", *sorted(x for x in sub.glob("*.py") if x.name != "__init__.py")]]
    return top + inner


def render(package: Path = PACKAGE) -> str:
    """The Markdown table: module (its path under the repository; a sub-package in bold) and its one concern."""
    lines = ["| module | its one concern (the docstring's first paragraph) |", "|---|---|"]
    for path in modules(package):
        rel = path.relative_to(package.parent).as_posix()
        name = f"**`{rel.removesuffix('/__init__.py')}/`**" if path.name == "__init__.py" else f"`{rel}`"
        lines.append(f"| {name} | {summary(path)} |")
    return "\n".join(lines)


def committed() -> str | None:
    """The map as docs/architecture.md holds it (None without the block)."""
    blocks = {m.group(1): m.group(2).strip("\n") for m in _MARKED.finditer(DOC_PATH.read_text(encoding="utf-8"))}
    return blocks.get(BLOCK)


@block(BLOCK)
def module_map_block(runs) -> str:
    """The module map of docs/architecture.md, from the code (no run)."""
    return render()


def main(argv: list[str] | None = None) -> int:
    import argparse

    from flexarm.provenance import refuse_outside_checkout, write_atomic

    ap = argparse.ArgumentParser(prog="python -m scenarios.reports.module_map", description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", action="store_true", help="rewrite the map in docs/architecture.md")
    mode.add_argument("--check", action="store_true", help="exit 1 if docs/architecture.md's map is not the code's")
    args = ap.parse_args(argv)
    if refuse_outside_checkout("python -m scenarios.reports.module_map", "docs/architecture.md's module map "
                               "(--check compares with it)", REPO):
        return 2
    if args.check:
        same = committed() == render()
        print(f"{DOC_PATH.relative_to(REPO)}: the module map " + ("matches the code" if same else
              "differs from the code: run python -m scenarios.reports.module_map --write"))
        return 0 if same else 1
    text = DOC_PATH.read_text(encoding="utf-8")
    blocks = {m.group(1): m.group(2).strip("\n") for m in _MARKED.finditer(text)}  # the others as they are
    write_atomic(DOC_PATH, splice_blocks(text, {**blocks, BLOCK: render()}, str(DOC_PATH)))
    print(f"wrote the module map of {DOC_PATH.relative_to(REPO)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
