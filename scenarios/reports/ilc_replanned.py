"""The section of docs/ilc.md on learning along a re-planned slew (issue 32, items 2-4): the runs and their page.

Runs, through the Python FMUs: ``scenarios/ilc_replan.toml`` (the payload known, 50 trials),
``scenarios/ilc_identify.toml`` (the payload unknown: identified from trial 0, re-planned, learnt) and its variants
(:data:`VARIANTS`: other unknown payloads, and links 5 % stiffer than the model). :func:`render_replanned` renders
the section from their summaries; :mod:`scenarios.reports.ilc_report` calls both and keeps the summaries in
docs/ilc_results.json, so ``--check`` renders it again without running anything.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

REPLAN_SCENARIO = "ilc_replan"
IDENTIFY_SCENARIO = "ilc_identify"
#: Variants of ilc_identify: label, name, text replacements. The learning, the weights and the seeds as the file's.
VARIANTS = (
    ("0.2 kg, unknown", "ilc_identify_0p2",
     (('learn_case = "learn"', 'learn_case = "payload_0p2"'), ('evaluate_cases = ["learn"]', "evaluate_cases = []"))),
    ("0.35 kg, unknown", "ilc_identify_0p35",
     (('learn_case = "learn"', 'learn_case = "payload_0p35"'), ('evaluate_cases = ["learn"]', "evaluate_cases = []"))),
    ("0.5 kg, unknown", "ilc_identify_0p5",
     (('learn_case = "learn"', 'learn_case = "payload_0p5"'), ('evaluate_cases = ["learn"]', "evaluate_cases = []"))),
    ("0.275 kg, unknown, links 5 % stiffer than the model", "ilc_identify_stiff",
     (("[parameters.plant]\npayload_mass = 0.275", "[parameters.plant]\npayload_mass = 0.275\nlink_stiffness_scale = "
       "1.05"),)),
)
#: How far the rms position error moves from trial to trial with the sensors' noise alone on a re-planned slew, deg
#: (measured: 0.0076-0.0199 over 50 trials of ilc_replan); a rise larger than this is the learning's doing.
NOISE_SPREAD_DEG = 0.02
#: The true payload of each learn case, kg (the scenario files' cases).
TRUE_PAYLOAD = {"learn": 0.275, "payload_0p2": 0.2, "payload_0p35": 0.35, "payload_0p5": 0.5}


def run_replanned(out: Path, run_ilc, progress=print) -> dict:
    """Run ilc_replan, ilc_identify and :data:`VARIANTS` into `out`; returns {"replan": summary, "identify":
    [(label, summary), ...]}. The payload data the runs share (0.275 kg) is written once and copied."""
    progress(f"== learning along the re-planned slew: {REPLAN_SCENARIO}")
    replan = run_ilc(REPLAN_SCENARIO, out, plots=False, progress=progress)
    shared = Path(out) / REPLAN_SCENARIO / "payload_data"

    def seeded(name: str) -> None:  # the same payload re-plans to the same folder: copied, then checked when reused
        target = Path(out) / name / "payload_data"
        if not target.exists():
            shutil.copytree(shared, target)

    runs = []
    progress(f"== an unknown payload: {IDENTIFY_SCENARIO}")
    seeded(IDENTIFY_SCENARIO)
    runs.append(("0.275 kg, unknown", run_ilc(IDENTIFY_SCENARIO, out, plots=False, progress=progress)))
    from scenarios.config import SCENARIO_DIR

    text = (SCENARIO_DIR / f"{IDENTIFY_SCENARIO}.toml").read_text()
    tmp = Path(tempfile.mkdtemp(prefix="ilc_identify_"))
    try:
        for label, name, edits in VARIANTS:
            body = text.replace(f'name = "{IDENTIFY_SCENARIO}"', f'name = "{name}"')
            for old, new in edits:
                if old not in body:
                    raise RuntimeError(f"{IDENTIFY_SCENARIO}.toml: the variant {name!r} expects {old!r}")
                body = body.replace(old, new)
            if "stiff" in name:
                seeded(name)
            path = tmp / f"{name}.toml"
            path.write_text(body)
            progress(f"== an unknown payload: {label}")
            runs.append((label, run_ilc(path, out, plots=False, progress=progress)))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {"replan": replan, "identify": runs}


def _rms(s: dict) -> list[float]:
    return [r["metrics"]["slew_rms_position_error"] for r in s["trials"] if r.get("metrics")]


def _first_below(s: dict, limit: float = 0.1) -> int | None:
    return next((r["trial"] for r in s["trials"] if r.get("metrics")
                 and r["metrics"]["slew_rms_position_error"] < limit), None)


def _peaks(s: dict) -> tuple[float, float]:
    ok = [r["metrics"] for r in s["trials"] if r.get("metrics")]
    return max(m["slew_peak_tau1"] for m in ok), max(m["slew_peak_tau2"] for m in ok)


def _settling(s: dict) -> tuple[str, bool]:
    """The learn case's tip settling in the evaluation (final correction and none), and whether it is ≤ 0.5 s with
    the run long enough (t_f + 5 s)."""
    ev = s["evaluation"].get(s["settings"]["learn_case"], {})
    n_eval = s["settings"].get("evaluate_samples", s["samples"])
    after = (n_eval - s["slew_samples"]) / 1000
    parts, ok = [], after >= 5.0 - 1e-9
    for label in ("unlearned", "learned"):
        t = ev.get(label, {}).get("metrics", {}).get("tip_within_1mm_after_tf_s", "missing")
        parts.append(f"{label} " + ("not within 1 mm at its end" if t is None else
                                    "not run" if t == "missing" else f"{t:.2f} s"))
        ok = ok and isinstance(t, float) and t <= 0.5
    return f"{', '.join(parts)} (run to t_f + {after:.1f} s)", ok


def render_replanned(replan: dict, identify: list) -> list[str]:
    """The section's lines (markdown)."""
    r = _rms(replan)
    ok = [x for x in replan["trials"] if x.get("metrics")]
    ref = replan["reference"]
    p1, p2 = _peaks(replan)
    first10, last10 = float(np.mean(r[:10])), float(np.mean(r[-10:]))
    out = ["", "### Along the slew re-planned for the payload (issue 32)", "",
           f"`scenarios/{REPLAN_SCENARIO}.toml` (scenario SHA-256 `{replan['scenario_sha256'][:12]}`): the 0.275 kg "
           f"case with noise, but the slew re-planned for that payload (t_f {ref['t_f_s']:.3f} s) with the gains "
           "designed along it (`flexarm.payload_data`), packed into the Python controller FMU; the learning's model "
           "is the arm with the payload, along that slew. Every figure compares with the re-planned slew.", "",
           "| trial | rms pos. ° | peak pos. ° | rms q1 ° | rms q2 ° | rms tip mm | tip < 1 mm after t_f, s | "
           "peak τ1 N·m | peak τ2 N·m | ‖e‖₂ measured, rad |", "|---|---|---|---|---|---|---|---|---|---|"]
    for i in sorted({0, 1, 2, 3, 5, 10, 20, 30, 40, len(ok) - 1} & set(range(len(ok)))):
        m = ok[i]["metrics"]
        t_in = m["tip_within_1mm_after_tf_s"]
        out.append(f"| {ok[i]['trial']} | {m['slew_rms_position_error']:.4f} | {m['slew_peak_position_error']:.3f} | "
                   f"{m['rms_q1_error_deg']:.4f} | {m['rms_q2_error_deg']:.4f} | {m['rms_tip_error_mm']:.2f} | "
                   f"{'—' if t_in is None else f'{t_in:.2f}'} | {m['slew_peak_tau1']:.3f} | {m['slew_peak_tau2']:.3f} "
                   f"| {m['measured_error_2norm_rad']:.4f} |")
    ev = replan["evaluation"].get(replan["settings"]["learn_case"], {})
    a, b = (ev.get(k, {}).get("metrics", {}).get("slew_rms_position_error") for k in ("unlearned", "learned"))
    settle, settle_ok = _settling(replan)
    out += ["", f"Evaluation (another noise seed): unlearned {a:.4f}°, with the final correction {b:.4f}°. On this "
            "slew the error left is the sensors' noise: the learning has nothing systematic to remove and learns "
            "some of the noise.", "",
            "#### An unknown payload: identify, re-plan, learn", "",
            f"`scenarios/{IDENTIFY_SCENARIO}.toml` and variants: trial 0 runs the paper's slew; the payload is "
            "identified from its encoder angles and the torques it applied (output-error least squares, "
            "`flexarm.payload_fit`), the slew re-planned for it to the gram, and the learning starts on that slew "
            "with trial 1. Trial 0 compares with the paper's slew, the others with the re-planned one.", "",
            "| run | identified, kg (error) | re-planned t_f, s | rms pos. ° trials 0 / 1 / 2 / 5 / 10 / last | first "
            "trial below 0.1° | peak τ1 / τ2 max, N·m | rms tip mm, last trial |", "|---|---|---|---|---|---|---|"]
    for label, s in identify:
        rr, idf = _rms(s), s.get("identified")
        true = TRUE_PAYLOAD[s["settings"]["learn_case"]]
        ident = "—" if not idf else (f"{idf['payload_mass_kg']:.4f} "
                                     f"({100 * (idf['payload_mass_kg'] - true) / true:+.2f} %)")
        pick = [rr[i] for i in (0, 1, 2, 5, 10) if i < len(rr)] + [rr[-1]]
        q1, q2 = _peaks(s)
        last = [x for x in s["trials"] if x.get("metrics")][-1]["metrics"]
        out.append(f"| {label} | {ident} | {s['reference']['t_f_s']:.3f} | " + " / ".join(f"{x:.3f}" for x in pick)
                   + f" | {_first_below(s) if _first_below(s) is not None else 'none'} | {q1:.3f} / {q2:.3f} | "
                   f"{last['rms_tip_error_mm']:.2f} |" + ("" if not s["stopped"] else f" stopped: {s['stopped']}"))
    for label, s in identify:
        rr = _rms(s)
        tail = float(np.mean(rr[-5:]))
        if len(rr) > 6 and tail - rr[1] > NOISE_SPREAD_DEG:
            out += ["", f"{label}: the learning raised the error from {rr[1]:.3f}° at trial 1 (the re-planned slew, no "
                    f"correction yet) to {tail:.3f}° (mean of the last 5 trials). Its model (the design model with the "
                    "identified payload) mispredicts this plant, and the norm-optimal update on it converges to a "
                    "worse point than no correction."]
    # the verdicts (issue 32's acceptance, items 2-4)
    below10 = max(r[:10]) < 0.1
    out += ["", "| item | target | measured | verdict |", "|---|---|---|---|",
            f"| 0.275 kg with noise, along the re-planned slew | rms position error < 0.1° within 10 trials, the "
            f"first included | trial 0 {r[0]:.4f}°, largest of trials 0-9 {max(r[:10]):.4f}° | "
            f"{'met' if below10 else 'missed'} |",
            f"| peak torques | ≤ 7.0 / 2.25 N·m | max {p1:.3f} / {p2:.3f} N·m over {len(r)} trials | "
            f"{'met' if p1 <= 7.0 and p2 <= 2.25 else 'missed'} |",
            f"| no growth over {len(r)} trials | the error does not grow | mean of trials 0-9 {first10:.4f}°, of the "
            f"last 10 {last10:.4f}°, largest {max(r):.4f}° | {'met' if last10 <= first10 * 1.2 else 'missed'} |",
            f"| tip's rms error beside it | reported | {ok[min(10, len(ok) - 1)]['metrics']['rms_tip_error_mm']:.2f} "
            "mm at trial 10 | — |",
            f"| tip within 1 mm of its end point from t_f + 0.5 s, measured to t_f + 5 s, payload and noise | ≤ 0.5 s "
            f"| {settle} | {'met' if settle_ok else 'missed'} |"]
    for label, s in identify:
        idf, true = s.get("identified"), TRUE_PAYLOAD[s["settings"]["learn_case"]]
        err = None if not idf else abs(idf["payload_mass_kg"] - true) / true
        fb, rr = _first_below(s), _rms(s)
        at10 = rr[min(10, len(rr) - 1)]  # the result of 10 trials of learning (from trial 1 on the re-planned slew)
        verdict = "met" if err is not None and err <= 0.1 and at10 < 0.1 else "missed"
        out.append(f"| {label} | identified within 10 %, rms < 0.1° within 10 trials | "
                   + ("not identified" if err is None else f"{100 * err:.2f} % off") + ", first below 0.1°: "
                   + ("none" if fb is None else f"trial {fb}") + f"; trial {min(10, len(rr) - 1)}: {at10:.3f}°, "
                   f"trial {len(rr) - 1}: {rr[-1]:.3f}° | {verdict} |")
    ident = identify[0][1]
    settle, settle_ok = _settling(ident)
    out.append(f"| tip within 1 mm from t_f + 0.5 s, the payload unknown ({identify[0][0]}) | ≤ 0.5 s | {settle} | "
               f"{'met' if settle_ok else 'missed'} |")
    return out
