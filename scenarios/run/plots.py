"""Figures of a scenario run (PNG): tip paths (paper Figs. 4-5) zoomed to the slew with its start, end and straight
line, torques (Fig. 6) with the motors' limits and t_f, errors (log axis when the cases span decades), joint angles
against the desired ones, the tip error against time (Figs. 5-6 style, with t_f marked). Each case has its own line
style and width, so identical curves (noise and no noise) stay visible.

Legends sit outside the axes (right of them), so they never cover data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # not pyplot: no GUI backend, no global state, a faster import

from flexarm.provenance import write_atomic

#: Line styles and widths per case: identical curves (noise and no noise often are) stay visible, the first
#: drawn widest underneath.
STYLES = ("-", "--", "-.", ":")
WIDTHS = (2.2, 1.6, 1.2, 0.9)


def _style(i: int) -> dict:
    return {"ls": STYLES[i % len(STYLES)], "lw": WIDTHS[i % len(WIDTHS)]}


def _figure(nrows: int = 1, ncols: int = 1, **kwargs):
    """(figure, axes) like ``pyplot.subplots``, on a figure of its own (drawn by Agg when saved)."""
    figsize = kwargs.pop("figsize", None)
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def _legend(ax, **kwargs) -> None:
    """The legend right of the axes (never over the data)."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, **kwargs)


def _save(fig, path: Path) -> None:
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    write_atomic(path, buf.getvalue())


def plot_scenario(name: str, results, desired: dict, traj, plant: str, driver: str, folder: Path) -> list[Path]:
    """Five PNGs in `folder`; returns their paths."""
    from flexarm.parameters import load_parameters

    limits = [float(x) for x in load_parameters().peak_torque]  # the parameter file's motors.peak_torque_Nm
    out = []
    tip_path(name, [(f"{r.label}{f' ({r.status})' if r.status != 'ok' else ''}",
                     {"tip_x": r.series[f"{plant}.tip_x"], "tip_y": r.series[f"{plant}.tip_y"]}
                     if f"{plant}.tip_x" in r.series else None) for r in results], traj, folder / "tip_path.png")
    out.append(folder / "tip_path.png")

    fig, axes = _figure(2, 1, figsize=(8, 6), sharex=True)
    for j, ax in enumerate(axes):
        for i, r in enumerate(results):
            ax.plot(r.series["time"], r.series[f"{driver}.tau{j + 1}"], label=r.label, **_style(i))
        ax.plot(traj.t, traj.tau[:, j], color="k", ls=(0, (1, 1)), lw=1.2, label="feedforward (optimiser)")
        for sign in (1, -1):
            label = f"motor limit ±{limits[j]:g} N·m" if sign > 0 else None
            ax.axhline(sign * limits[j], color="r", ls="--", lw=1, label=label)
        ax.axvline(traj.t_f, color="0.4", lw=1, ls=":", label=f"t_f = {traj.t_f:g} s")
        ax.set_ylabel(f"tau{j + 1}, N·m")
        _legend(ax, fontsize=7)
    axes[-1].set_xlabel("t, s")
    axes[0].set_title(f"{name}: joint torques")
    _save(fig, folder / "torques.png")
    out.append(folder / "torques.png")

    out.append(_errors(name, results, desired, plant, traj, folder))
    out.append(_joints(name, results, traj, folder))
    out.append(_tip_error(name, results, traj, folder))
    return out


def _errors(name: str, results, desired: dict, plant: str, traj, folder: Path) -> Path:
    """errors.png: the largest position and velocity error over the 11 elements, each case in its own style, on a
    log axis when the cases' peaks span more than a decade (no payload: 0.01 deg; 0.275 kg: 11.6 deg), t_f marked."""
    fig, axes = _figure(2, 1, figsize=(8, 6), sharex=True)
    peaks: list[list[float]] = [[], []]
    for i, r in enumerate(results):
        if r.metrics is None:  # a run that stopped early (unbounded, error): no errors to draw
            continue
        th = np.column_stack([r.series[f"{plant}.theta{i}"] for i in range(1, 12)])
        om = np.column_stack([r.series[f"{plant}.omega{i}"] for i in range(1, 12)])
        n = min(len(th), len(desired["theta"]))
        label = f"{r.label}{f' ({r.status})' if r.status != 'ok' else ''}"
        for k, err in enumerate((np.degrees(np.abs(th[:n] - desired["theta"][:n]).max(axis=1)),
                                 np.degrees(np.abs(om[:n] - desired["omega"][:n]).max(axis=1)))):
            axes[k].plot(r.series["time"][:n], err, label=label if k == 0 else None, **_style(i))
            peaks[k].append(float(err.max()))
    for ax, p in zip(axes, peaks):
        ax.axvline(traj.t_f, color="0.4", lw=1, ls=":", label=f"t_f = {traj.t_f:g} s" if ax is axes[0] else None)
        if p and min(p) > 0 and max(p) / min(p) > 10.0:
            ax.set_yscale("log")
            ax.set_ylim(bottom=1e-4 * max(p))  # the zero error at t = 0 would stretch the axis down
    axes[0].set_ylabel("max |position error|, deg")
    axes[1].set_ylabel("max |velocity error|, deg/s")
    axes[1].set_xlabel("t, s")
    _legend(axes[0], fontsize=7)
    axes[0].set_title(f"{name}: largest error over the 11 elements")
    _save(fig, folder / "errors.png")
    return folder / "errors.png"


def _joints(name: str, results, traj, folder: Path) -> Path:
    """joints.png: q1, q2 of each case against the desired (the CSV's joint.* and ref.* columns), deg."""
    fig, axes = _figure(2, 1, figsize=(8, 6), sharex=True)
    for j, ax in enumerate(axes, start=1):
        for i, r in enumerate(results):
            if f"joint.q{j}" in r.series:
                ax.plot(r.series["time"], np.degrees(r.series[f"joint.q{j}"]), label=r.label, **_style(i))
        ref = next((r.series for r in results if f"ref.q{j}_ref" in r.series), None)
        if ref is not None:
            ax.plot(ref["time"], np.degrees(ref[f"ref.q{j}_ref"]), "k--", lw=1.2, label="desired")
        ax.axvline(traj.t_f, color="0.6", lw=0.8, ls=":")
        ax.set_ylabel(f"q{j}, deg")
        _legend(ax, fontsize=7)
    axes[-1].set_xlabel("t, s (dotted: t_f)")
    axes[0].set_title(f"{name}: joint angles against the desired")
    _save(fig, folder / "joints.png")
    return folder / "joints.png"


def _tip_error(name: str, results, traj, folder: Path) -> Path:
    """tip_error.png: distance of the tip from the desired tip against time, mm, t_f marked (settling after it)."""
    fig, ax = _figure(figsize=(8, 4))
    for i, r in enumerate(results):
        if "err.tip_x" in r.series:
            ax.plot(r.series["time"], 1e3 * np.hypot(r.series["err.tip_x"], r.series["err.tip_y"]),
                    label=f"{r.label}{f' ({r.status})' if r.status != 'ok' else ''}", **_style(i))
    ax.axvline(traj.t_f, color="0.4", lw=1, ls=":", label=f"t_f = {traj.t_f:g} s")
    ax.set(xlabel="t, s", ylabel="|tip − desired tip|, mm", title=f"{name}: tip error")
    ax.set_yscale("symlog", linthresh=0.01)
    ax.set_ylim(bottom=0.0)
    _legend(ax, fontsize=7)
    _save(fig, folder / "tip_error.png")
    return folder / "tip_error.png"


def tip_path(name: str, runs, traj, path: Path) -> None:
    """The tip path zoomed to the slew: desired path, start, end, the straight line between them, each run in its
    own style. `runs`: (label, {"tip_x", "tip_y"} or None)."""
    fig, ax = _figure(figsize=(7, 6))
    start, end = traj.tip[0], traj.tip[-1]
    ax.plot(traj.tip[:, 0], traj.tip[:, 1], "k-", lw=3, alpha=0.3, label="desired (optimiser)")
    ax.plot([start[0], end[0]], [start[1], end[1]], color="0.5", ls=":", lw=1, label="straight line")
    for i, (label, s) in enumerate(runs):
        if s:
            ax.plot(s["tip_x"], s["tip_y"], label=label, **_style(i))
    ax.plot(*start, "go", ms=8, label="start")
    ax.plot(*end, "rs", ms=8, label="end")
    # zoomed to the slew: its bounding box plus a fifth of its length each way (a run that strays further, a
    # diverged one, leaves the frame rather than shrinking the slew to a line); x and y keep their own scales
    pad = 0.2 * float(np.hypot(*(end - start)))
    lo, hi = traj.tip.min(axis=0) - pad, traj.tip.max(axis=0) + pad
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set(xlabel="x, m", ylabel="y, m", title=f"{name}: tip path")
    _legend(ax, fontsize=7)
    _save(fig, path)
