"""docs/findings.md's generated blocks refuse stale inputs (issue 24 item 4; scenarios/reports/findings_doc.py).

The blocks read two committed result files; a file computed from other inputs, or whose RODAS4 tables a fresh
run no longer reproduces, must stop the results page instead of keeping an old figure alive. The fresh runs are
stood in for by the file's own figures (the page's real runs are results-page --check's job in CI).
"""

import json

import pytest

from scenarios.reports import findings_doc as fd
from scenarios.reports.results_page import ResultsPageError


class _Runs(dict):
    """The part of PageRuns the checks use: metrics(name) -> {case: metrics}."""

    def __init__(self, tables):
        super().__init__()
        self.tables = tables

    def metrics(self, name, algorithm=None):
        return self.tables[name]


def _runs_from(data, scale=1.0):
    tables = {t: {c: dict(data["tables"][f"{t}|rodas4|0.0|{c}"]["metrics"]) for c in fd.CASES} for t in fd.TABLES}
    tables["table2"]["noise"]["rms_position_error"] *= scale
    return _Runs(tables)


def test_findings_data_is_checked_against_the_fresh_runs():
    data = json.loads(fd.FINDINGS_DATA.read_text())
    assert fd._findings_data(_runs_from(data)) == data
    with pytest.raises(ResultsPageError, match="table2/noise rms_position_error.*scenarios.reports.reexamine"):
        fd._findings_data(_runs_from(data, scale=1.001))


def test_findings_data_from_other_inputs_is_refused(tmp_path, monkeypatch):
    data = json.loads(fd.FINDINGS_DATA.read_text())
    runs = _runs_from(data)
    data["trajectory_sha256"] = "0" * 64
    stale = tmp_path / "findings-data.json"
    stale.write_text(json.dumps(data))
    monkeypatch.setattr(fd, "FINDINGS_DATA", stale)
    with pytest.raises(ResultsPageError, match="another trajectory or parameter file"):
        fd._findings_data(runs)


def test_scheme_accuracy_from_other_inputs_is_refused(tmp_path, monkeypatch):
    data = json.loads(fd.SCHEME_ACCURACY.read_text())
    for prov in data.get("provenance", {}).values():
        prov["inputs_sha256"] = {k: "0" * 64 for k in prov["inputs_sha256"]}
    data["inputs_sha256"] = {k: "0" * 64 for k in data["inputs_sha256"]}
    stale = tmp_path / "scheme-accuracy.json"
    stale.write_text(json.dumps(data))
    monkeypatch.setattr(fd, "SCHEME_ACCURACY", stale)
    fd._scheme_accuracy.cache_clear()
    try:
        with pytest.raises(ResultsPageError, match="computed from other inputs"):
            fd._scheme_accuracy()
    finally:
        fd._scheme_accuracy.cache_clear()


def test_growth_table_is_the_sampled_loop_analysis():
    """The growth the blocks compute equals the re-examination's (the same linearised loop, another code path)."""
    data = json.loads(fd.FINDINGS_DATA.read_text())
    for name in ("gamma1", "eq32"):
        for ratio in (0.0, 0.005):
            assert fd.growth(name, ratio) == pytest.approx(
                data["linear"][f"{name}|{ratio}"]["growth_rate_per_s"], rel=1e-6, abs=1e-9)
