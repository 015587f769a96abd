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


def test_the_run_speed_block_is_the_render_of_the_json_and_judges_each_goal():
    """docs/benchmarks.md's run-speed table (issue 34) renders docs/run-speed.json: every command the benchmark
    measures, a verdict per goal that follows from the figures (a made-up slow row is 'missed' on every goal)."""
    from bench_run_speed import COMMANDS

    from scenarios.reports import speed_doc

    data = json.loads(speed_doc.SPEED_JSON.read_text(encoding="utf-8"))
    assert [row["command"] for row in data["rows"]] == [c for _, c, _ in COMMANDS]
    assert {"date", "commit", "machine", "repeats", "load_average_before", "load_average_after"} <= set(data)
    blocks = {m.group(1): m.group(2).strip("\n") for m in _MARKED.finditer(speed_doc.DOC.read_text(encoding="utf-8"))}
    assert blocks["run-speed"] == speed_doc.render(data)
    slow = {**data, "rows": [{"kind": "native", "command": ["run", "x"], "start_up_cpu_s": 0.9, "run_cpu_s": 2.0,
                              "judge_cpu_s": 0.1, "write_cpu_s": 3.0, "simulated_s": 2.0}]}
    row = speed_doc.render(slow).splitlines()[2]
    assert row.count("missed") == 3 and "met" not in row.replace("missed", ""), row
