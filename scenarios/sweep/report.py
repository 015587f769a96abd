"""What a sweep shows: the progress bar, the text summary and the summary plots."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from ..metrics import METRICS
from .journal import STATUSES, _cell
from .plan import Plan
from .spec import _is_number

# ------------------------------------------------------------------------------------------- progress, plots


class Progress:
    """A text progress bar with an estimate of the time left, on stderr."""

    def __init__(self, label: str, total: int, already: int, enabled: bool = True, stream=None):
        self.label, self.total, self.done, self.enabled = label, total, already, enabled
        self.stream = stream or sys.stderr
        self.counts = dict.fromkeys(STATUSES, 0)
        self.t0 = time.perf_counter()
        self.t_first = None
        self.n_run = 0
        self._last = 0.0
        self._tty = hasattr(self.stream, "isatty") and self.stream.isatty()

    def update(self, record: dict) -> None:
        self.done += 1
        self.n_run += 1
        self.counts[record["status"]] = self.counts.get(record["status"], 0) + 1
        now = time.perf_counter()
        if self.t_first is None:
            self.t_first = now
        if not self.enabled:
            return
        if self._tty or now - self._last > 10 or self.done == self.total:
            self._last = now
            self.stream.write(("\r" if self._tty else "") + self.line(now) + ("" if self._tty else "\n"))
            if self._tty and self.done == self.total:
                self.stream.write("\n")
            self.stream.flush()

    def eta(self, now: float) -> float | None:
        """Seconds left: the rate since the first completion (excluding start-up), else None."""
        if self.n_run >= 2 and now > self.t_first:
            rate = (self.n_run - 1) / (now - self.t_first)
            return (self.total - self.done) / rate
        return None

    def line(self, now: float) -> str:
        frac = self.done / self.total if self.total else 1.0
        bar = "#" * int(25 * frac)
        eta = self.eta(now)
        left = "?" if eta is None else _hms(eta)
        c = self.counts
        return (f"{self.label} [{bar:25s}] {self.done}/{self.total} {100 * frac:3.0f}%  "
                f"{_hms(now - self.t0)} elapsed, ~{left} left  "
                f"(ok {c['ok']}, unbounded {c['unbounded']}, error {c['error']})")


def _hms(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def _short(field: str, v) -> str:
    name = field.split(".", 1)[1]
    return f"{name}={_cell(v)}"


def summary_plots(plan: Plan, rows: list[dict], folder: Path) -> list[Path]:
    """PNG summaries: each metric against the main numeric axis (payload by default), one line per
    combination of the other axes (mean over seeds, min-max band); and box plots of the rms errors'
    spread over the seeds. Written atomically; returns the paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from scenarios.run.plots import _save

    from ..metrics import LABELS

    axes = plan.sweep.axes
    ok = [r for r in rows if r["status"] == "ok"]
    n_bad = len(rows) - len(ok)
    if not ok:
        return []
    reps = [a for a in axes if a.is_replicate and len(a.values) > 1]
    numeric = [a for a in axes if not a.is_fmu and not a.is_replicate and len(a.values) > 1
               and all(_is_number(v) for v in a.values)]
    x_axis = next((a for a in numeric if a.field == "plant.payload_mass"), numeric[0] if numeric else None)
    groups_axes = [a for a in axes if a not in reps and a is not x_axis and len(a.values) > 1]
    gain = next((a for a in groups_axes if a.field == "controller.gain_set"), None)
    if gain is not None:  # gain set first in the labels
        groups_axes = [gain] + [a for a in groups_axes if a is not gain]

    def group_label(r):
        return ", ".join(_short(a.field, r[a.field]) for a in groups_axes) or "all"

    out = []
    note = f" ({n_bad} unbounded/error points left out)" if n_bad else ""
    if x_axis is not None:
        fig, subs = plt.subplots(2, 3, figsize=(14, 7.5), sharex=True)
        labels = list(dict.fromkeys(group_label(r) for r in ok))
        for ax, m in zip(subs.flat, METRICS):
            for lab in labels:
                xs = sorted({r[x_axis.field] for r in ok if group_label(r) == lab})
                vals = [[r[m] for r in ok if group_label(r) == lab and r[x_axis.field] == x] for x in xs]
                mean = [float(np.mean(v)) for v in vals]
                line, = ax.plot(xs, mean, "o-", ms=3, lw=1.2, label=lab)
                if reps:
                    ax.fill_between(xs, [min(v) for v in vals], [max(v) for v in vals], color=line.get_color(),
                                    alpha=0.15, lw=0)
            positive = [r[m] for r in ok if r[m] > 0]
            if positive and max(positive) / min(positive) > 100:
                ax.set_yscale("log")
            ax.set(title=LABELS[m], xlabel=x_axis.field + (f", {x_axis.unit}" if x_axis.unit else ""))
            ax.grid(alpha=0.3)
        subs.flat[0].legend(fontsize=7)
        what = " (mean over " + ", ".join(a.field for a in reps) + "; band: min-max)" if reps else ""
        fig.suptitle(f"sweep {plan.sweep.name}: metrics against {x_axis.field}{what}{note}", fontsize=10)
        fig.tight_layout()
        path = folder / f"metrics_vs_{x_axis.variable}.png"
        _save(fig, path)
        out.append(path)
    if reps:
        box_axes = [a for a in axes if a not in reps and len(a.values) > 1]
        if gain is not None:
            box_axes = [gain] + [a for a in box_axes if a is not gain]

        def box_label(r):
            return "\n".join(_short(a.field, r[a.field]) for a in box_axes) or "all"

        labels = list(dict.fromkeys(box_label(r) for r in sorted(ok, key=lambda r: [
            str(r[a.field]) if not _is_number(r[a.field]) else f"{r[a.field]:020.9f}" for a in box_axes])))
        fig, subs = plt.subplots(2, 1, figsize=(max(8, 0.55 * len(labels) + 2), 8), sharex=True)
        for ax, m in zip(subs, ("rms_position_error", "rms_velocity_error")):
            data = [[r[m] for r in ok if box_label(r) == lab] for lab in labels]
            ax.boxplot(data, showmeans=True)
            positive = [x for d in data for x in d if x > 0]
            if positive and max(positive) / min(positive) > 100:
                ax.set_yscale("log")
            ax.set(ylabel=LABELS[m])
            ax.grid(alpha=0.3, axis="y")
        subs[1].set_xticks(range(1, len(labels) + 1), labels, fontsize=6, rotation=90)
        fig.suptitle(f"sweep {plan.sweep.name}: spread of the rms errors over "
                     + ", ".join(f"{a.field} ({len(a.values)})" for a in reps) + note, fontsize=10)
        fig.tight_layout()
        path = folder / "rms_spread_over_seeds.png"
        _save(fig, path)
        out.append(path)
    return out


def format_summary(plan: Plan, rows: list[dict], max_rows: int = 60) -> str:
    """A text table: one line per point, or (with seed axes) per combination of the other axes, mean over seeds."""
    reps = [a for a in plan.sweep.axes if a.is_replicate and len(a.values) > 1]
    keys = [a for a in plan.sweep.axes if a not in reps]
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[a.field] for a in keys), []).append(r)
    short = {"peak_tau1": "pk_tau1", "peak_tau2": "pk_tau2", "peak_position_error": "pk_pos",
             "peak_velocity_error": "pk_vel", "rms_position_error": "rms_pos", "rms_velocity_error": "rms_vel"}
    widths = [max(len(a.field), *(len(_cell(v)) for v in a.values)) for a in keys]
    head = "  ".join(f"{a.field:>{w}s}" for a, w in zip(keys, widths))
    head += f"  {'ok/n':>7s}" + "".join(f"{short[m]:>10s}" for m in METRICS)
    lines = [("mean over " + ", ".join(a.field for a in reps) + " (ok points)") if reps else "", head]
    for i, (vals, rs) in enumerate(groups.items()):
        if i == max_rows:
            lines.append(f"... {len(groups) - max_rows} more (see the CSV)")
            break
        ok = [r for r in rs if r["status"] == "ok"]
        line = "  ".join(f"{_cell(v):>{w}s}" for v, w in zip(vals, widths))
        line += f"  {len(ok):>3d}/{len(rs):<3d}"
        for m in METRICS:
            line += f"{np.mean([r[m] for r in ok]):10.4g}" if ok else f"{'-':>10s}"
        if not ok:
            line += "  " + ", ".join(sorted({r["status"] for r in rs}))
        lines.append(line)
    return "\n".join(x for x in lines if x)
