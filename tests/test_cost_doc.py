"""docs/model.md's cost table is the render of the committed benchmark JSON (no re-timing)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from scenarios.reports.cost_doc import COST_JSON, DOC, render
from scenarios.reports.page_blocks import _MARKED

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


def test_the_cost_block_is_the_render_of_the_json():
    from bench_plant_step import COST_ROWS

    data = json.loads(COST_JSON.read_text(encoding="utf-8"))
    assert list(data["rows"]) == [f"{i}|{n}" for i, n in COST_ROWS]
    assert {"date", "commit", "machine", "load_average_before", "load_average_after"} <= set(data)
    for row in data["rows"].values():
        assert all(v > 0 for v in row.values()) and len(row) == 3
    blocks = {m.group(1): m.group(2).strip("\n") for m in _MARKED.finditer(DOC.read_text(encoding="utf-8"))}
    assert blocks["plant-step-cost"] == render(data)
