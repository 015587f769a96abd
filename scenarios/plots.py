"""Figures of a scenario run (PNG): tip paths (paper Figs. 4-5), torques (Fig. 6), errors."""

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


def _save(fig, path: Path) -> None:
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    write_atomic(path, buf.getvalue())


def plot_scenario(name: str, results, desired: dict, traj, plant: str, driver: str, folder: Path) -> list[Path]:
    """Three PNGs in `folder`; returns their paths."""
    out = []
    fig, ax = _figure(figsize=(6, 6))
    ax.plot(traj.tip[:, 0], traj.tip[:, 1], "k--", lw=2, label="desired (optimiser)")
    for r in results:
        if f"{plant}.tip_x" in r.series:
            ax.plot(r.series[f"{plant}.tip_x"], r.series[f"{plant}.tip_y"], lw=1,
                    label=f"{r.label}{f' ({r.status})' if r.status != 'ok' else ''}")
    ax.set(xlabel="x, m", ylabel="y, m", title=f"{name}: tip path")
    ax.axis("equal")
    ax.legend(fontsize=8)
    _save(fig, folder / "tip_path.png")
    out.append(folder / "tip_path.png")

    fig, axes = _figure(2, 1, figsize=(8, 6), sharex=True)
    for j, ax in enumerate(axes):
        for r in results:
            ax.plot(r.series["time"], r.series[f"{driver}.tau{j + 1}"], lw=0.8, label=r.label)
        ax.plot(traj.t, traj.tau[:, j], "k--", lw=1.5, label="feedforward (optimiser)")
        ax.set_ylabel(f"tau{j + 1}, N·m")
    axes[0].legend(fontsize=7)
    axes[-1].set_xlabel("t, s")
    axes[0].set_title(f"{name}: joint torques")
    _save(fig, folder / "torques.png")
    out.append(folder / "torques.png")

    fig, axes = _figure(2, 1, figsize=(8, 6), sharex=True)
    for r in results:
        if r.status != "ok":
            continue
        th = np.column_stack([r.series[f"{plant}.theta{i}"] for i in range(1, 12)])
        om = np.column_stack([r.series[f"{plant}.omega{i}"] for i in range(1, 12)])
        axes[0].plot(r.series["time"], np.degrees(np.abs(th - desired["theta"]).max(axis=1)), lw=0.8, label=r.label)
        axes[1].plot(r.series["time"], np.degrees(np.abs(om - desired["omega"]).max(axis=1)), lw=0.8)
    axes[0].set_ylabel("max |position error|, deg")
    axes[1].set_ylabel("max |velocity error|, deg/s")
    axes[1].set_xlabel("t, s")
    axes[0].legend(fontsize=7)
    axes[0].set_title(f"{name}: largest error over the 11 elements")
    _save(fig, folder / "errors.png")
    out.append(folder / "errors.png")
    return out
