"""Table 2's four cases with the native FMUs against the Python FMUs, in our master (closed loop)."""

from __future__ import annotations

import numpy as np
from fmu_harness import built_fmus
from native_fmus import native_fmus

from scenarios.config import load_scenario
from scenarios.metrics import METRICS
from scenarios.runner import CaseResult, format_table, prepare, simulate_case


def _run_table2(fmus: dict, tmp_path, label: str):
    folder = tmp_path / label
    folder.mkdir()
    for name in ("plant", "sensors", "controller"):
        (folder / f"{name}.fmu").write_bytes(fmus[name].read_bytes())
    sc = load_scenario("table2")
    results, signals = [], {}
    for case in sc.cases:
        setup = prepare(sc, folder, names=case.fmus or None, build=False)
        with setup.open_master("gauss-seidel") as m:
            out, metrics = simulate_case(setup, m, case.parameters)
            assert out["status"] == "ok", out.get("message")
        signals[case.key] = out["signals"]
        results.append(CaseResult(case.key, case.label, "ok", "", metrics, 0.0, {}))
    return results, signals


def test_table2_native_equals_python(tmp_path):
    """Every recorded signal of the four cases (noise included: the sensors draw NumPy's numbers) agrees to
    1e-10 of its peak, and the printed tables are identical."""
    python, native = built_fmus(), native_fmus()
    res_py, sig_py = _run_table2(python, tmp_path, "python")
    res_nat, sig_nat = _run_table2(native, tmp_path, "native")
    for key in sig_py:
        assert set(sig_py[key]) == set(sig_nat[key])
        for name, ref in sig_py[key].items():
            got = np.asarray(sig_nat[key][name])
            ref = np.asarray(ref)
            assert np.abs(got - ref).max() <= max(1e-10 * np.abs(ref).max(), 1e-12), (key, name)
    assert format_table(res_nat, None) == format_table(res_py, None)
    for r_py, r_nat in zip(res_py, res_nat):
        for m in METRICS:
            assert abs(r_nat.metrics[m] - r_py.metrics[m]) <= 1e-9 * abs(r_py.metrics[m]) + 1e-12, (r_py.key, m)
