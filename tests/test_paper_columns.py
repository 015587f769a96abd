"""The paper's column beside a run is the paper's case with the run's actual parameters, or none at all."""

from __future__ import annotations

from scenarios.config import load_scenario, select_cases
from scenarios.run.paper import paper_columns, paper_tables
from scenarios.run.runner import CaseResult, format_table


def test_the_column_follows_the_parameters_not_the_case_key():
    table2 = paper_tables()["table2"]
    none = select_cases(load_scenario("table2"), ["none"])
    assert paper_columns(none) == {"none": ("none", table2["none"])}
    # the run: case none with the tip payload is the paper's tip case (ratio 175.69 against no-payload)
    assert paper_columns(none, {"plant": {"payload_mass": 0.275}}) == {"none": ("tip", table2["tip"])}
    assert paper_columns(none, {"plant": {"payload_mass": 0.275}, "sensors": {"noise_enabled": True}}) \
        == {"none": ("tip_noise", table2["tip_noise"])}
    # a payload, gain set or seed the paper did not run: no column
    for overrides in ({"plant": {"payload_mass": 0.2}}, {"controller": {"gain_set": "gamma1"}},
                      {"sensors": {"noise_seed": 2}}, {"plant": {"substeps": 4}}):
        assert paper_columns(none, overrides) == {}, overrides
    # every case of the file is its own column; a scenario without a paper table has none
    assert {k: v[0] for k, v in paper_columns(load_scenario("table3")).items()} == \
        {k: k for k in ("none", "noise", "tip", "tip_noise")}


def test_a_case_without_a_column_prints_no_paper_number():
    none = select_cases(load_scenario("table2"), ["none"])
    metrics = dict(zip(paper_tables()["metrics"], [5.7, 1.4, 11.6, 104.4, 3.6, 13.4]))
    res = [CaseResult("none", "no tip mass, no noise", "ok", "", metrics, 1.0, {}, None, [], None)]
    cols = paper_columns(none, {"plant": {"payload_mass": 0.2}})
    text = format_table(res, {k: c for k, (_, c) in cols.items()})
    assert "6.024" not in text and "0.95" not in text  # neither the paper's no-payload value nor a ratio to it
    text = format_table(res, {k: c for k, (_, c) in paper_columns(none, {"plant": {"payload_mass": 0.275}}).items()})
    assert "6.232" in text and "0.91" in text  # the paper's tip column: 5.7 / 6.232
