"""What an ILC run shows of its trials: the printed line per trial, ``trials.csv`` and ``convergence.png``.
"""

from __future__ import annotations

from pathlib import Path

from flexarm.provenance import write_atomic

COLUMNS = (("trial", "trial", "{:d}"), ("seed", "seed", "{:d}"),
           ("rms pos°", "slew_rms_position_error", "{:.4f}"), ("peak pos°", "slew_peak_position_error", "{:.3f}"),
           ("rms q1°", "rms_q1_error_deg", "{:.4f}"), ("rms q2°", "rms_q2_error_deg", "{:.4f}"),
           ("rms tip mm", "rms_tip_error_mm", "{:.2f}"), ("tip<1mm s", "tip_within_1mm_after_tf_s", "{:.3f}"),
           ("τ1 N·m", "slew_peak_tau1", "{:.3f}"), ("τ2 N·m", "slew_peak_tau2", "{:.3f}"),
           ("sat", "saturated_samples", "{:d}"), ("‖e‖ rad", "measured_error_2norm_rad", "{:.4f}"),
           ("wall s", "wall_time_s", "{:.1f}"))


def trial_header() -> str:
    return " ".join(f"{h:>10s}" for h, _, _ in COLUMNS)


def trial_line(row: dict) -> str:
    m = dict(row.get("metrics") or {}, trial=row["trial"], seed=row["seed"], wall_time_s=row["wall_time_s"])
    if row["status"] != "ok":
        return f"{row['trial']:>10d} {row['seed']:>10d} {row['status']}: {row['message']}"
    cells = []
    for _, key, fmt in COLUMNS:
        v = m.get(key)
        cells.append(f"{'---' if v is None else fmt.format(v):>10s}")
    return " ".join(cells)


def write_trials_csv(path: Path, rows: list[dict]) -> None:
    keys = sorted({k for r in rows for k in (r.get("metrics") or {})})
    lines = [",".join(["trial", "seed", "status", "wall_time_s", *keys])]
    for r in rows:
        m = r.get("metrics") or {}
        lines.append(",".join([str(r["trial"]), str(r["seed"]), r["status"], repr(r["wall_time_s"])]
                              + ["" if m.get(k) is None else repr(m[k]) for k in keys]))
    write_atomic(path, "\n".join(lines) + "\n")


def plot_convergence(rows: list[dict], path: Path, name: str) -> Path:
    """rms / peak position error, tip error and peak torques against the trial number (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import io

    import matplotlib.pyplot as plt

    ok = [r for r in rows if r.get("metrics")]
    j = [r["trial"] for r in ok]
    g = lambda k: [r["metrics"][k] for r in ok]  # noqa: E731
    fig, ax = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    ax[0].semilogy(j, g("slew_rms_position_error"), "o-", label="rms, all 11 elements")
    ax[0].semilogy(j, g("slew_peak_position_error"), "s-", label="peak, all 11 elements")
    ax[0].semilogy(j, g("rms_q1_error_deg"), "^-", label="rms joint 1")
    ax[0].semilogy(j, g("rms_q2_error_deg"), "v-", label="rms joint 2")
    ax[0].axhline(0.1, color="k", ls=":", lw=1, label="0.1°")
    ax[0].set(ylabel="position error over the slew, °", title=f"{name}: convergence")
    ax[0].legend(fontsize=8)
    ax[1].semilogy(j, g("rms_tip_error_mm"), "o-", label="rms tip error over the slew")
    ax[1].semilogy(j, g("peak_tip_error_mm"), "s-", label="peak tip error over the run")
    ax[1].semilogy(j, [1e3 * v for v in g("measured_error_2norm_rad")], "d-", label="‖measured error‖₂, mrad")
    ax[1].set(ylabel="mm / mrad")
    ax[1].legend(fontsize=8)
    ax[2].plot(j, g("slew_peak_tau1"), "o-", label="peak τ1")
    ax[2].plot(j, g("slew_peak_tau2"), "s-", label="peak τ2")
    ax[2].axhline(7.0, color="C0", ls=":", lw=1)
    ax[2].axhline(2.25, color="C1", ls=":", lw=1)
    ax[2].set(xlabel="trial", ylabel="N·m")
    ax[2].legend(fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    write_atomic(path, buf.getvalue())
    return path
