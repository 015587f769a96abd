"""The LQG's tables beside the paper's LQR and ours (issue 14): ``python -m scenarios.reports.lqg_report``.

Runs, through the FMUs and our master: ``table2`` (our γ = 0.1 LQR,
Gauss-Seidel), ``lqg`` (Gauss-Seidel) and ``lqg_jacobi`` (Jacobi stepping,
delay 2), the last with Table 2's and with Table 1's weights (noise
robustness), integral action off and on, each with both estimators (one
Kalman filter; the payload bank, cases ``*_bank``), and prints per Table 2
case the paper's LQR, our LQR and the LQG variants, then the acceptance
figures of the issue per estimator. The paper's numbers come from ``scenarios/paper_tables.toml`` and are
only printed beside ours.
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
import tomllib
from pathlib import Path

from flexarm.parameters import load_parameters
from scenarios.config import SCENARIO_DIR, load_scenario
from scenarios.run.fmus import DEFAULT_FMU_DIR
from scenarios.run.runner import run_scenario

CASES = ("none", "noise", "tip", "tip_noise")
ROWS = (("rms_position_error", "rms position error, deg"), ("rms_velocity_error", "rms velocity error, deg/s"),
        ("peak_position_error", "peak position error, deg"), ("peak_velocity_error", "peak velocity error, deg/s"),
        ("peak_tau1", "peak torque 1, N.m"), ("peak_tau2", "peak torque 2, N.m"))


def _with_gain_set(scenario, gain_set: str):
    sc = copy.deepcopy(scenario)
    for case in sc.cases:
        case.parameters.setdefault("controller", {})["gain_set"] = gain_set
    return sc


class LqgReportError(Exception):
    """A run of the report ended with an FMU error: it is no figure, so nothing is printed for it."""


def _run(scenario, out: Path, fmu_dir: Path) -> dict:
    """Case key -> metrics (None only for an unbounded run); an FMU error raises :class:`LqgReportError`."""
    results = run_scenario(scenario, out, fmu_dir, progress=False)
    failed = [f"{r.key}: {r.message}" for r in results if r.status == "error"]
    if failed:
        raise LqgReportError(f"scenario {scenario.name} had FMU errors: {'; '.join(failed)}")
    return {r.key: r.metrics for r in results}


def _verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"


def _fmt(v) -> str:
    return "unbounded" if v is None else f"{v:.4g}"


#: The LQG scenarios' case-key suffixes of each estimator (``controller_lqg``'s ``estimator``) and its short label.
ESTIMATORS = {"kalman": ("", "LQG"), "payload_bank": ("_bank", "bank")}
#: Columns after the paper's: (label, run, case-key suffix); runs 0 our LQR, 1 LQG Gauss-Seidel, 2 LQG Jacobi.
_LQG_COLUMNS = (("our LQR (GS)", 0, ""), ("{e} (GS)", 1, ""), ("{e}+I (GS)", 1, "_integral"),
                ("{e} (Jacobi)", 2, ""), ("{e}+I (Jacobi)", 2, "_integral"))


def columns(estimator: str = "kalman") -> tuple[str, ...]:
    """The comparison's column labels for one estimator."""
    label = ESTIMATORS[estimator][1]
    return ("paper LQR", *(c.format(e=label) for c, _, _ in _LQG_COLUMNS))


def comparison_cells(paper: dict, lqr: dict, lqg_gs: dict, lqg_jacobi: dict, case: str, key: str,
                     estimator: str = "kalman") -> list[str]:
    """One row's cells (:func:`columns`) for a Table 2 case, a metric and an estimator; runs are case key ->
    metrics."""
    p = paper["table2"].get(case)
    pv = None if p is None or isinstance(p, dict) else p[paper["metrics"].index(key)]
    runs, sfx = (lqr, lqg_gs, lqg_jacobi), ESTIMATORS[estimator][0]
    vals = [runs[r][case + (sfx if r else "") + i] for _, r, i in _LQG_COLUMNS]
    return [_fmt(pv)] + [_fmt(None if v is None else v[key]) for v in vals]


def comparison_markdown(paper: dict, lqr: dict, lqg_gs: dict, lqg_jacobi: dict, estimator: str = "kalman") -> str:
    """The four Table 2 cases, every metric, as a Markdown table with the columns of :func:`columns`."""
    cols = columns(estimator)
    lines = ["| case | metric | " + " | ".join(cols) + " |", "|---|---|" + "---|" * len(cols)]
    for case in CASES:
        for n, (key, label) in enumerate(ROWS):
            cells = comparison_cells(paper, lqr, lqg_gs, lqg_jacobi, case, key, estimator)
            lines.append(f"| {case if n == 0 else ''} | {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    """Run the scenarios and print the comparison."""
    ap = argparse.ArgumentParser(prog="python -m scenarios.reports.lqg_report", description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=None, help="results folder (default: a temporary folder)")
    ap.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR)
    args = ap.parse_args(argv)
    try:
        return _report(args)
    except LqgReportError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


def gamma1_runs(out: Path, fmu_dir: Path) -> tuple[dict, dict]:
    """The noise-robustness runs with Table 1's weights: ``lqg_jacobi`` (both estimators) and our LQR
    (``table2``), each case key -> metrics."""
    t1 = _with_gain_set(load_scenario("lqg_jacobi"), "gamma1")
    t1.name = "lqg_jacobi_gamma1"
    lqr1 = _with_gain_set(load_scenario("table2"), "gamma1")
    lqr1.name = "table1_lqr"
    return _run(t1, out, fmu_dir), _run(lqr1, out, fmu_dir)


def acceptance_lines(lqr: dict, jacobi: dict, g1: dict, l1: dict) -> list[str]:
    """Issue 14's acceptance figures per estimator, with verdicts. Runs (case key -> metrics): our γ = 0.1
    LQR (``table2``), ``lqg_jacobi``, and the γ = 1 runs of :func:`gamma1_runs`."""
    lines = []
    tau_max = load_parameters().peak_torque
    half = 0.5 * lqr["tip"]["rms_position_error"] if lqr["tip"] else None
    for estimator, (sfx, label) in ESTIMATORS.items():
        lines.append(f"estimator = {estimator}:")
        for case in CASES:
            bound = max(1.5 * lqr[case]["rms_position_error"], 0.05) if lqr[case] else None
            ours = jacobi[case + sfx]["rms_position_error"] if jacobi[case + sfx] else None
            ok = ours is not None and bound is not None and ours <= bound
            lines.append(f"  Jacobi d=2, {case:10s}: rms position {_fmt(ours)} deg, bound max(1.5 x LQR, 0.05) = "
                         f"{_fmt(bound)} deg: {_verdict(ok)}")
        for name, r, s, integrals in ((f"{label} gamma1, Jacobi d=2", g1, sfx, (False, True)),
                                      ("our LQR gamma1, GS", l1, "", (False,))):
            for base, noisy in (("none", "noise"), ("tip", "tip_noise")):
                for integral in integrals:
                    i = "_integral" if integral else ""
                    a, b = r[base + s + i], r[noisy + s + i]
                    ratio = b["rms_position_error"] / a["rms_position_error"] if a and b else None
                    goal = f": ratio <= 2 {_verdict(ratio is not None and ratio <= 2.0)}" if r is g1 else ""
                    lines.append(f"  noise robustness, {name}, {base + i:13s}: rms position "
                                 f"{_fmt(a and a['rms_position_error'])} -> {_fmt(b and b['rms_position_error'])} "
                                 f"deg with noise, ratio {_fmt(ratio)}{goal}")
        for name, key in (("without", "tip"), ("with", "tip_integral")):
            m = jacobi[key.replace("tip", "tip" + sfx)]  # tip_bank, tip_bank_integral
            ok = (m is not None and half is not None and m["rms_position_error"] <= half
                  and m["peak_tau1"] < tau_max[0] and m["peak_tau2"] < tau_max[1])
            lines.append(
                f"  payload 0.275 kg, {label} Jacobi {name} integral action: rms position "
                f"{_fmt(m and m['rms_position_error'])} deg, rms velocity {_fmt(m and m['rms_velocity_error'])} "
                f"deg/s, peak torques {_fmt(m and m['peak_tau1'])} / {_fmt(m and m['peak_tau2'])} N.m (our LQR: "
                f"{_fmt(lqr['tip']['rms_position_error'])} deg, {_fmt(lqr['tip']['rms_velocity_error'])} deg/s): "
                f"at most half our LQR's within the torque limits {_verdict(ok)}")
    return lines


def _report(args) -> int:
    paper = tomllib.loads((SCENARIO_DIR / "paper_tables.toml").read_text())
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        lqr, gs, jac = (_run(load_scenario(n), out, args.fmu_dir) for n in ("table2", "lqg", "lqg_jacobi"))
        g1, l1 = gamma1_runs(out, args.fmu_dir)
    for case in CASES:
        for estimator in ESTIMATORS:
            print(f"\n== Table 2 case '{case}' (gamma = 0.1 weights), estimator = {estimator}")
            print(f"{'':28s}" + "".join(f"{c:>16s}" for c in columns(estimator)))
            for key, label in ROWS:
                cells = comparison_cells(paper, lqr, gs, jac, case, key, estimator)
                print(f"{label:28s}" + "".join(f"{c:>16s}" for c in cells))
    print("\n== Acceptance (issue 14)")
    print("\n".join(acceptance_lines(lqr, jac, g1, l1)))
    return 0

if __name__ == "__main__":
    raise SystemExit(main())
