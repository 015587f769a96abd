"""The generated results page: rendering and the README splice (the full --check runs in CI)."""

import numpy as np
import pytest

from scenarios.results_page import README_BEGIN, README_END, readme_table, scenario_table, splice_readme
from scenarios.runner import CaseResult

METRIC_VALUES = {"peak_tau1": 5.6, "peak_tau2": 0.82, "peak_position_error": 0.009,
                 "peak_velocity_error": 8.45, "rms_position_error": 0.002, "rms_velocity_error": 0.9}


def _result(key, metrics=METRIC_VALUES, status="ok"):
    return CaseResult(key, key, status, "" if status == "ok" else "diverged at t = 1.2 s in plant.theta3",
                      None if metrics is None else dict(metrics), 0.1, {"time": np.zeros(3)})


def test_cells_show_ours_the_papers_and_their_ratio():
    paper = {"none": [6.0, 1.0, 0.1, 10.0, 0.04, 1.8], "noise": {"unbounded": True}}
    table = scenario_table([_result("none"), _result("noise"), _result("extra")], paper)
    rows = table.splitlines()
    assert rows[0] == "| metric | none | noise | extra |"
    assert "| peak τ1, N·m | 5.600 / 6 (0.93×) | 5.600 / unbounded | 5.600 |" in rows
    assert "| rms velocity error, deg/s | 0.90 / 1.8 (0.50×) | 0.90 / unbounded | 0.90 |" in rows


def test_a_scenario_with_many_cases_has_one_row_per_case():
    """Beyond 8 cases the table turns: cases as rows, the six metrics as columns, the same cells."""
    from scenarios.results_page import MAX_CASE_COLUMNS

    keys = [f"c{i}" for i in range(MAX_CASE_COLUMNS + 1)]
    rows = scenario_table([_result(k, status="ok") for k in keys[:-1]] + [_result(keys[-1], None, "unbounded")],
                          {"c0": [6.0, 1.0, 0.1, 10.0, 0.04, 1.8]}).splitlines()
    assert rows[0] == ("| case | peak τ1, N·m | peak τ2, N·m | peak position error, deg | peak velocity error, deg/s "
                       "| rms position error, deg | rms velocity error, deg/s |")
    assert len(rows) == 2 + len(keys)
    assert rows[2].startswith("| c0 | 5.600 / 6 (0.93×) | ") and rows[2].endswith("| 0.90 / 1.8 (0.50×) |")
    assert rows[-1] == "| c8 |" + " unbounded |" * 6


def test_an_unbounded_run_is_shown_as_such_never_as_a_number():
    table = scenario_table([_result("none", metrics=None, status="unbounded")], None)
    assert all(line.endswith("| unbounded |") for line in table.splitlines()[2:])
    block = readme_table([_result("none", metrics=None, status="unbounded")], {"none": [1, 1, 1, 1, 1, 1]})
    assert "| peak τ1, N·m | unbounded / 1 |" in block


def test_readme_splice_replaces_only_the_marked_block():
    text = f"intro\n{README_BEGIN}\nold table\n{README_END}\nrest\n"
    out = splice_readme(text, "new table")
    assert out == f"intro\n{README_BEGIN}\nnew table\n{README_END}\nrest\n"
    assert splice_readme(out, "new table") == out
    with pytest.raises(ValueError, match="markers"):
        splice_readme("no markers here", "new table")


def test_the_printed_table_comes_in_blocks_of_four_cases():
    """`scenarios run` prints at most 4 cases side by side (16-case LQG scenarios stay readable); every case
    keeps its ours / paper / ratio cells."""
    from scenarios.runner import CASES_PER_BLOCK, format_table

    results = [_result(f"c{i}") for i in range(CASES_PER_BLOCK + 2)]
    blocks = format_table(results, {"c0": [6.0, 1.0, 0.1, 10.0, 0.04, 1.8]}).split("\n\n")
    assert [len(b.splitlines()) for b in blocks] == [8, 8]
    assert blocks[0].splitlines()[0].split() == [f"c{i}" for i in range(CASES_PER_BLOCK)]
    assert blocks[1].splitlines()[0].split() == ["c4", "c5"]
    assert "5.600    6.000     0.93" in blocks[0].splitlines()[2]
