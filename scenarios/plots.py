"""Figures of a scenario run (PNG): tip paths (paper Figs. 4-5), torques (Fig. 6) with the motors' limits, errors,
joint angles against the desired ones, the tip error against time (Figs. 5-6 style, with t_f marked).

Legends sit outside the axes (right of them), so they never cover data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # not pyplot: no GUI backend, no global state, a faster import

from flexarm.provenance import write_atomic


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
    fig, ax = _figure(figsize=(6, 6))
    ax.plot(traj.tip[:, 0], traj.tip[:, 1], "k--", lw=2, label="desired (optimiser)")
    for r in results:
        if f"{plant}.tip_x" in r.series:
            ax.plot(r.series[f"{plant}.tip_x"], r.series[f"{plant}.tip_y"], lw=1,
                    label=f"{r.label}{f' ({r.status})' if r.status != 'ok' else ''}")
    ax.set(xlabel="x, m", ylabel="y, m", title=f"{name}: tip path")
    ax.axis("equal")
    _legend(ax, fontsize=8)
    _save(fig, folder / "tip_path.png")
    out.append(folder / "tip_path.png")

    fig, axes = _figure(2, 1, figsize=(8, 6), sharex=True)
    for j, ax in enumerate(axes):
        for r in results:
            ax.plot(r.series["time"], r.series[f"{driver}.tau{j + 1}"], lw=0.8, label=r.label)
        ax.plot(traj.t, traj.tau[:, j], "k--", lw=1.5, label="feedforward (optimiser)")
        for sign in (1, -1):
            label = f"motor limit ±{limits[j]:g} N·m" if sign > 0 else None
            ax.axhline(sign * limits[j], color="r", ls=":", lw=1, label=label)
        ax.set_ylabel(f"tau{j + 1}, N·m")
        _legend(ax, fontsize=7)
    axes[-1].set_xlabel("t, s")
    axes[0].set_title(f"{name}: joint torques")
    _save(fig, folder / "torques.png")
    out.append(folder / "torques.png")

    fig, axes = _figure(2, 1, figsize=(8, 6), sharex=True)
    for r in results:
        if r.metrics is None:  # a run that stopped early (unbounded, error): no errors to draw
            continue
        th = np.column_stack([r.series[f"{plant}.theta{i}"] for i in range(1, 12)])
        om = np.column_stack([r.series[f"{plant}.omega{i}"] for i in range(1, 12)])
        axes[0].plot(r.series["time"], np.degrees(np.abs(th - desired["theta"]).max(axis=1)), lw=0.8, label=r.label)
        axes[1].plot(r.series["time"], np.degrees(np.abs(om - desired["omega"]).max(axis=1)), lw=0.8)
    axes[0].set_ylabel("max |position error|, deg")
    axes[1].set_ylabel("max |velocity error|, deg/s")
    axes[1].set_xlabel("t, s")
    _legend(axes[0], fontsize=7)
    axes[0].set_title(f"{name}: largest error over the 11 elements")
    _save(fig, folder / "errors.png")
    out.append(folder / "errors.png")
    out.append(_joints(name, results, traj, folder))
    out.append(_tip_error(name, results, traj, folder))
    return out


def _joints(name: str, results, traj, folder: Path) -> Path:
    """joints.png: q1, q2 of each case against the desired (the CSV's joint.* and ref.* columns), deg."""
    fig, axes = _figure(2, 1, figsize=(8, 6), sharex=True)
    for j, ax in enumerate(axes, start=1):
        for r in results:
            if f"joint.q{j}" in r.series:
                ax.plot(r.series["time"], np.degrees(r.series[f"joint.q{j}"]), lw=0.8, label=r.label)
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
    for r in results:
        if "err.tip_x" in r.series:
            ax.plot(r.series["time"], 1e3 * np.hypot(r.series["err.tip_x"], r.series["err.tip_y"]), lw=0.8,
                    label=f"{r.label}{f' ({r.status})' if r.status != 'ok' else ''}")
    ax.axvline(traj.t_f, color="0.4", lw=1, ls=":", label=f"t_f = {traj.t_f:g} s")
    ax.set(xlabel="t, s", ylabel="|tip − desired tip|, mm", title=f"{name}: tip error")
    ax.set_yscale("symlog", linthresh=0.01)
    ax.set_ylim(bottom=0.0)
    _legend(ax, fontsize=7)
    _save(fig, folder / "tip_error.png")
    return folder / "tip_error.png"
