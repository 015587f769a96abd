"""docs/architecture.md cannot go stale: its module map equals the code, and every file it names exists."""

from __future__ import annotations

import re

from scenarios.module_map import ARCHITECTURE, main, module_map_markdown
from scenarios.page_blocks import REPO


def test_the_module_map_in_architecture_md_equals_the_code():
    assert main(["--check"]) == 0, "run python -m scenarios.module_map and commit docs/architecture.md"


def test_the_map_lists_a_new_module_with_the_first_sentence_of_its_docstring(tmp_path):
    pkg = tmp_path / "scenarios" / "reports"
    pkg.mkdir(parents=True)
    (pkg / "page.py").write_text('"""The page: one concern (Fig. 3, e.g. a table). More text.\n\nDetails."""\n')
    (pkg / "bare.py").write_text("x = 1\n")
    (tmp_path / "scenarios" / "__pycache__").mkdir()
    (tmp_path / "scenarios" / "__pycache__" / "junk.py").write_text('"""Not a module."""\n')
    text = module_map_markdown(tmp_path)
    assert "**`scenarios/reports/`**" in text
    assert "| `page.py` | The page: one concern (Fig. 3, e.g. a table). |" in text
    assert "| `bare.py` | (no docstring) |" in text and "junk" not in text


def test_every_file_architecture_md_names_exists():
    # A path in backquotes that names a project file (a folder of the checkout, then a file or a folder).
    text = ARCHITECTURE.read_text(encoding="utf-8")
    top = {p.name for p in REPO.iterdir()} - {"build", "results"}  # outputs, absent from a fresh clone
    named = {m for m in re.findall(r"`([\w./<>-]+)`", text) if "/" in m and m.split("/")[0] in top and "<" not in m}
    assert len(named) > 20, named  # the table of where things live names dozens
    missing = sorted(m for m in named if not (REPO / m).exists())
    assert not missing, f"docs/architecture.md names files that do not exist: {missing}"
