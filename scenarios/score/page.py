"""The score's page: ``index.html`` with its PNG figures beside it (no network: no script, no remote style or
font) and ``score.json`` with every number. Verdicts first, then the six table metrics and the settling time
beside our baselines, then the robustness sweep and the figures."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from flexarm.provenance import write_atomic, write_json
from scenarios.run.plots import _figure, _legend, _save, _style, tip_path

from ..metrics import METRICS, UNITS
from . import battery

#: The figures of the page, in its order (file name, caption).
FIGURES = (("errors.png", "Largest error over the 11 elements per paper case, log axis (t_f dotted)"),
           ("torques.png", "Joint torques of the paper cases (Gauss-Seidel), the motors' limits dashed, t_f dotted"),
           ("tip_path.png", "Tip path over the slew (Gauss-Seidel): start, end and the straight line between them"),
           ("robustness.png", "Robustness: payload 0-0.5 kg, noise seeds 1-3, against our baselines"))


def _fmt(v, digits: int = 4) -> str:
    if v is None:
        return "–"
    if isinstance(v, float) and not np.isfinite(v):
        return str(v)
    return f"{v:.{digits}g}"


def _verdict_cell(rec: dict | None) -> str:
    if rec is None:
        return "<td>–</td>"
    status = rec["status"]
    word = "stable" if status == "ok" else status
    extra = f"<br><small>{rec['growth_rate_per_s']:.3g} /s from {rec['onset_s']:.2f} s</small>" \
        if rec.get("growth_rate_per_s") else ""
    return f'<td class="{html.escape(word)}" title="{html.escape(rec.get("message") or "")}">{word}{extra}</td>'


def _settle(rec: dict | None) -> str:
    if rec is None or rec.get("metrics") is None:
        return "–"
    return f"> {battery.SETTLE_S:g}" if rec["settle_s"] is None else f"{rec['settle_s']:.2f}"


def render(name: str, result: dict, baseline: dict, meta: dict, folder: Path) -> Path:
    """Write the page, its figures and score.json into `folder`; returns the HTML's path."""
    folder.mkdir(parents=True, exist_ok=True)
    cases = battery.cases()
    recs = result["cases"]
    bases = baseline["controllers"]
    names = [name] + [b for b in bases if b != name]
    _figures(name, cases, recs, bases, folder)
    rows = []
    head = "".join(f"<th>{html.escape(n)}</th>" for n in names)
    for c in cases:
        cells = [_verdict_cell(recs[c.key])] + [_verdict_cell(bases[b].get(c.key)) for b in names[1:]]
        rows.append(f"<tr><td>{html.escape(c.key)}</td><td>{html.escape(c.label)}</td>{''.join(cells)}</tr>")
    verdicts = (f'<table id="verdicts"><caption>Verdicts (from each run\'s own samples)</caption><tr><th>case</th>'
                f"<th>set-up</th>{head}</tr>{''.join(rows)}</table>")
    mrows = []
    for c in (c for c in cases if c.group == "paper"):
        for m in METRICS:
            vals = [recs[c.key]] + [bases[b].get(c.key) for b in names[1:]]
            cells = "".join(f"<td>{_fmt(v['metrics'][m]) if v and v.get('metrics') else '–'}</td>" for v in vals)
            mrows.append(f"<tr><td>{c.key}</td><td>{m} ({UNITS[m]})</td>{cells}</tr>")
        cells = "".join(f"<td>{_settle(v)}</td>" for v in [recs[c.key]] + [bases[b].get(c.key) for b in names[1:]])
        mrows.append(f"<tr class='settle'><td>{c.key}</td><td>settling after t_f to {battery.SETTLE_TOL_M * 1e3:g} "
                     f"mm (s)</td>{cells}</tr>")
    metrics = (f'<table id="metrics"><caption>The paper\'s cases: the six table metrics over the slew and the '
               f"settling time</caption><tr><th>case</th><th>metric</th>{head}</tr>{''.join(mrows)}</table>")
    figs = "".join(f'<figure><img src="{f}" alt="{html.escape(cap)}"><figcaption>{html.escape(cap)}</figcaption>'
                   "</figure>" for f, cap in FIGURES)
    info = "".join(f"<li>{html.escape(k)}: {html.escape(str(v))}</li>" for k, v in meta.items())
    counts = {}
    for c in cases:
        counts[recs[c.key]["status"]] = counts.get(recs[c.key]["status"], 0) + 1
    summary = ", ".join(f"{v} {'stable' if k == 'ok' else k}" for k, v in sorted(counts.items()))
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>score: {html.escape(name)}</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; }} table {{ border-collapse: collapse; margin: 1em 0; }}
td, th {{ border: 1px solid #bbb; padding: 2px 6px; text-align: right; }} caption {{ font-weight: bold; }}
.stable {{ background: #d8f0d8; }} .diverging, .unbounded, .error {{ background: #f4c8c8; }}
.saturated {{ background: #f6e3b8; }} img {{ max-width: 100%; }}
</style></head><body>
<h1>Score of {html.escape(name)}</h1>
<p id="summary">{len(cases)} runs of battery {battery.BATTERY_VERSION}: {summary}.
Beside it: our baselines from <code>scenarios/score/baseline.json</code>.</p>
{verdicts}
{metrics}
{figs}
<h2>Run</h2><ul>{info}</ul>
</body></html>
"""
    out = folder / "index.html"
    write_atomic(out, page)
    write_json(folder / "score.json", {"controller": name, **meta, "battery_version": battery.BATTERY_VERSION,
                                       "battery_sha256": battery.battery_sha256(),
                                       "cases": {k: {x: y for x, y in v.items() if x != "series"}
                                                 for k, v in recs.items()},
                                       "baselines": bases, "figures": [f for f, _ in FIGURES]})
    return out


def _figures(name: str, cases, recs: dict, bases: dict, folder: Path) -> None:
    from flexarm.parameters import load_parameters
    from flexarm.trajectory import load_trajectory

    traj = load_trajectory()
    limits = [float(x) for x in load_parameters().peak_torque]
    paper = [c for c in cases if c.group == "paper"]
    # errors: one panel per paper case (rows: stepping), log axis: the cases span decades (0.01 deg to 1e3 deg/s)
    fig, axes = _figure(2, 4, figsize=(15, 6), sharex=True)
    for ax, c in zip(axes.ravel(), paper):
        s = recs[c.key].get("series")
        if s:
            t = np.asarray(s["time"])
            for key, style, label in (("velocity_error", "-", "velocity, deg/s"),
                                      ("position_error", "--", "position, deg")):
                ax.plot(t, np.asarray(s[key]), style, lw=0.9, label=label)
            ax.set_yscale("log")
            top = max(np.nanmax(s["velocity_error"]), np.nanmax(s["position_error"]))
            ax.set_ylim(bottom=max(1e-6 * top, 1e-9))  # the zero error at t = 0 would stretch the axis down
        ax.axvline(traj.t_f, color="0.4", ls=":", lw=1)
        ax.set_title(f"{c.key}: {'stable' if recs[c.key]['status'] == 'ok' else recs[c.key]['status']}",
                     fontsize=9)
    axes[1, 0].set_xlabel("t, s (dotted: t_f)")
    _legend(axes[0, -1], fontsize=7)
    fig.suptitle(f"{name}: largest error over the 11 elements")
    _save(fig, folder / "errors.png")
    # torques: Gauss-Seidel paper cases, distinct styles, limits and t_f
    fig, axes = _figure(2, 1, figsize=(9, 6), sharex=True)
    for j, ax in enumerate(axes):
        for i, c in enumerate(c for c in paper if c.algorithm == "gauss-seidel"):
            s = recs[c.key].get("series")
            if s:
                ax.plot(s["time"], s[f"tau{j + 1}"], label=c.key, **_style(i))
        for sign in (1, -1):
            ax.axhline(sign * limits[j], color="r", ls="--", lw=1,
                       label=f"limit ±{limits[j]:g} N·m" if sign > 0 else None)
        ax.axvline(traj.t_f, color="0.4", ls=":", lw=1, label=f"t_f = {traj.t_f:g} s")
        ax.set_ylabel(f"tau{j + 1}, N·m")
        _legend(ax, fontsize=7)
    axes[-1].set_xlabel("t, s")
    axes[0].set_title(f"{name}: joint torques")
    _save(fig, folder / "torques.png")
    tip_path(name, [(c.key, recs[c.key].get("series")) for c in paper if c.algorithm == "gauss-seidel"], traj,
             folder / "tip_path.png")
    _robustness(name, cases, recs, bases, folder / "robustness.png")


def _robustness(name: str, cases, recs: dict, bases: dict, path: Path) -> None:
    robust = [c for c in cases if c.group == "robust"]
    payloads = sorted({c.payload_kg for c in robust})
    fig, axes = _figure(1, 2, figsize=(12, 4.5))
    for ax, m in zip(axes, ("peak_position_error", "rms_velocity_error")):
        for i, (who, table) in enumerate([(name, recs)] + [(b, v) for b, v in bases.items() if b != name]):
            mean, lo, hi = [], [], []
            for p in payloads:
                vals = [table[c.key]["metrics"][m] for c in robust if c.payload_kg == p
                        and table.get(c.key) and table[c.key].get("metrics")]
                mean.append(np.mean(vals) if vals else np.nan)
                lo.append(min(vals) if vals else np.nan)
                hi.append(max(vals) if vals else np.nan)
            line, = ax.plot(payloads, mean, marker="o", label=who, **_style(i))
            ax.fill_between(payloads, lo, hi, color=line.get_color(), alpha=0.15)
        ax.set_yscale("log")
        ax.set(xlabel="tip payload, kg", ylabel=f"{m.replace('_', ' ')}, {UNITS[m]}")
    _legend(axes[-1], fontsize=8)
    axes[0].set_title(f"{name}: over 3 noise seeds (band: min-max)")
    _save(fig, path)
