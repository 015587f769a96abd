"""A run's verdict from its own samples: ``stable``, ``diverging`` or ``saturated`` (issue 35, item 1).

The master's outcome (:class:`scenarios.master.cosim.Outcome`) only says whether every step completed and every
recorded value stayed finite and below the divergence limit. A loop that is unstable but has not yet left
that limit by the end of the run finishes "ok" there; this module looks at the run's error series itself.

**Diverging.** The envelope of the error (its largest magnitude over the recorded columns, per window of
:data:`WINDOW_S`, counted back from the run's last sample) is followed back from the last window for as long
as it keeps rising towards the end (:func:`rising_tail`; :data:`RISE_SLACK` lets the beat of two modes and
noise through). That rise sets in (``onset_s``) where the envelope last sat at the rise's starting level; a
straight line through its log gives the growth rate (``growth_rate_per_s``, 1/s). A run diverges when

* the run's largest envelope is in its last window (still growing when the run ends);
* the rise lasts at least :data:`MIN_RISE_S` and grows by at least :data:`MIN_EFOLDS` e-folds: more than
  the forced error of a stable loop does towards the end of the slew (the thresholds' comment says how they
  were set against the measured runs);
* the rise's second half still carries :data:`LATE_SHARE` of its growth (it has not levelled off); and
* that growth is at least :data:`SIGNIFICANCE` times the rms scatter of the log-envelope about the line:
  a threshold from the run's own data, so a rise made of noise (whose log-envelope scatters as much as it
  rises) is not called growth, while an unstable mode's envelope lies on its line.

A decaying oscillation (its largest envelope comes first), a bounded large error (a rise that stops: the
largest envelope lies before the end, or the last rise is short and small) and stationary noise (no rise
of 1.5 e-folds: the largest of 100 noisy samples barely varies from window to window) are not diverging.
The *energy* of the error (its square) grows at twice the amplitude's rate, so the velocity-error amplitude
says the same; the position error is checked the same way.

**Saturated.** A joint torque at or beyond its motor's peak torque on more than :data:`SATURATED_FRACTION`
of the samples ("most of the time"): the loop is then open, and its figures are those of the motors' limits,
not of the controller. Diverging wins over saturated (an unstable loop saturates on its way up).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scenarios.analysis.stability import loop_stability
from scenarios.master import cosim as master
from scenarios.results import analysis_columns

#: Window of the envelope, s: longer than the period of the arm's slowest closed-loop oscillation seen in an
#: unstable run (about 0.03-0.1 s; the first flexible mode is at a few Hz), so each window holds a peak.
WINDOW_S = 0.1
#: Growth of the rise, e-folds (x 4.5), and its length, s, that a diverging run must show at least. A stable loop's
#: error is bounded by what forces it: during the slew it rises and falls with the torque profile's phases, and
#: the rises that reach the end of a stable run measured here are at most 1.3 e-folds over 0.4 s (a PD's position
#: error in the slew's last deceleration) and, over the 66 cases of every shipped scenario, 0.82 e-folds (table3
#: "none", position error). An unstable mode grows at a constant rate for as long as the run lasts: the unstable
#: PD of issue 35, 2.0 e-folds over 1.5 s at 1.3 /s.
MIN_EFOLDS = 1.5
MIN_RISE_S = 0.5
#: The tail's growth must be at least this many times the rms scatter of the log-envelope around its line.
SIGNIFICANCE = 4.0
#: The rise's second half must still carry this share of its growth (e-folds): an exponential carries half, an
#: unstable loop whose torques saturate (growth turning linear) about a quarter (the unstable PD in a Jacobi master:
#: 26 %), an error approaching a plateau next to nothing.
LATE_SHARE = 0.2
#: Fewest windows a tail fit uses (a line through 3 points of a noisy envelope says little).
MIN_WINDOWS = 4
#: A rise goes on backwards through a window whose envelope is at most this factor above the smallest after it.
RISE_SLACK = 1.25
#: A run is "saturated" when a joint torque sits at its limit on more than this share of the samples.
SATURATED_FRACTION = 0.5
#: An envelope below this share of its largest value is taken as this share (log of zero: a run that starts
#: exactly on the trajectory has zero error at t = 0).
FLOOR = 1e-6


def envelope(time, values, window_s: float = WINDOW_S) -> tuple[np.ndarray, np.ndarray]:
    """Largest magnitude of `values` in consecutive windows of `window_s`.

    Parameters
    ----------
    time : ndarray, shape (n,)
        Sample times, s (increasing).
    values : ndarray, shape (n,) or (n, m)
        The error series; with m columns, the largest magnitude over the columns per sample.
    window_s : float
        The window's length, s.

    Returns
    -------
    starts, peaks : ndarray, shape (w,)
        Each window's first sample time (s) and the largest |value| in it. Windows are counted back from the
        last sample, so the first window may be shorter.
    """
    t = np.asarray(time, dtype=float)
    v = np.abs(np.asarray(values, dtype=float))
    if v.ndim == 2:
        v = v.max(axis=1)
    # counted back from the run's end, so the last window (the one that says whether the run still grows) is whole
    back = np.floor((t[-1] - t) / window_s + 1e-9).astype(int)
    n = int(back[0]) + 1
    idx = n - 1 - back
    peaks = np.zeros(n)
    np.maximum.at(peaks, idx, v)
    starts = np.full(n, np.inf)
    np.minimum.at(starts, idx, t)
    return starts, peaks


def growth(time, values, window_s: float = WINDOW_S, min_efolds: float = MIN_EFOLDS,
           significance: float = SIGNIFICANCE) -> dict | None:
    """The sustained growth of a series' envelope up to the run's end, or None.

    Parameters
    ----------
    time : ndarray, shape (n,)
        Sample times, s.
    values : ndarray, shape (n,) or (n, m)
        The error series (any unit: only ratios matter).
    window_s, min_efolds, significance : float
        See :data:`WINDOW_S`, :data:`MIN_EFOLDS`, :data:`SIGNIFICANCE`.

    Returns
    -------
    dict or None
        ``growth_rate_per_s`` (the envelope's fitted rate over the rise, 1/s), ``onset_s`` (the start of the
        window where the rise starts), ``rise_s`` (from that window to the last), ``efolds`` (ln of the
        envelope's ratio, end over onset), ``late_efolds`` (the same over the rise's second half),
        ``scatter_efolds`` (rms of the log-envelope about its line), ``envelope_start``, ``envelope_end``
        (in the series' unit). None when the envelope does not grow without bound by the rules of the
        module docstring.
    """
    rise = rising_tail(time, values, window_s)
    if rise is None:
        return None
    ok = (rise["growth_rate_per_s"] > 0.0 and rise["efolds"] >= min_efolds and rise["rise_s"] >= MIN_RISE_S - 1e-9
          and rise["efolds"] >= significance * rise["scatter_efolds"]
          and rise["late_efolds"] >= LATE_SHARE * rise["efolds"])
    return rise if ok else None


def rising_tail(time, values, window_s: float = WINDOW_S) -> dict | None:
    """The rise of the envelope that reaches the run's end (the measurements :func:`growth` judges), or None.

    Walking back from the last window, the rise goes on while the earlier window is below
    :data:`RISE_SLACK` times the smallest envelope after it (slack for the beat of two modes and for noise);
    its onset is the last window still within that slack of the rise's smallest envelope. None when the run's
    largest envelope lies before its last window or when the rise has fewer than :data:`MIN_WINDOWS` windows.
    """
    starts, peaks = envelope(time, values, window_s)
    if len(peaks) < MIN_WINDOWS or not np.all(np.isfinite(peaks)) or peaks.max() <= 0.0:
        return None
    if peaks[-1] < peaks.max():  # the largest envelope lies before the run's end: not growing now
        return None
    i = len(peaks) - 1
    low = peaks[i]
    while i > 0 and peaks[i - 1] <= RISE_SLACK * low:
        i -= 1
        low = min(low, peaks[i])
    floor = RISE_SLACK * peaks[i:].min()  # the rise's starting level; it sets in where the envelope last sat there
    s = i + int(np.flatnonzero(peaks[i:] <= floor)[-1])
    if len(peaks) - s < MIN_WINDOWS:
        return None
    logs = np.log(np.maximum(peaks[s:], FLOOR * peaks.max()))
    x = starts[s:]
    slope, icpt = np.polyfit(x, logs, 1)
    half = len(logs) // 2
    return {"growth_rate_per_s": float(slope), "onset_s": float(starts[s]), "rise_s": float(x[-1] - x[0]),
            "late_efolds": float(logs[-1] - logs[half]),
            "efolds": float(logs[-1] - logs[0]),
            "scatter_efolds": float(np.sqrt(np.mean((logs - (slope * x + icpt)) ** 2))),
            "envelope_start": float(peaks[s]), "envelope_end": float(peaks[-1])}


def saturation_share(tau, limits) -> list[float]:
    """Per joint, the share of samples (0..1) whose torque is at or beyond its limit (1e-9 relative slack)."""
    tau = np.abs(np.asarray(tau, dtype=float))
    limits = np.asarray(limits, dtype=float)
    return [float(np.mean(tau[:, j] >= limits[j] * (1.0 - 1e-9))) if len(tau) else 0.0 for j in range(len(limits))]


def verdict(time, velocity_error, position_error, tau, limits, unit_velocity: str = "deg/s",
            unit_position: str = "deg") -> dict:
    """The run's verdict from its samples.

    Parameters
    ----------
    time : ndarray, shape (n,)
        Sample times, s.
    velocity_error, position_error : ndarray, shape (n,) or (n, m)
        The tracking errors (actual − desired), e.g. of the 11 element rates and angles.
    tau : ndarray, shape (n, 2)
        The torques applied to the plant, N·m.
    limits : sequence of 2 floats
        The motors' peak torques, N·m.
    unit_velocity, unit_position : str
        Units of the error series, for the message.

    Returns
    -------
    dict
        ``verdict``: "diverging", "saturated" or "stable"; ``message``: one sentence (empty when stable);
        ``growth``: the :func:`growth` of the diverging series (with ``series``: "velocity error" or
        "position error"), else None; ``saturated_share``: per joint, the share of samples at the limit.
    """
    share = saturation_share(tau, limits)
    for name, series, unit in (("velocity error", velocity_error, unit_velocity),
                               ("position error", position_error, unit_position)):
        g = growth(time, series)
        if g is not None:
            g["series"] = name
            msg = (f"the {name} envelope grows at {g['growth_rate_per_s']:.3g} /s from t = "
                   f"{g['onset_s']:.2f} s ({g['envelope_start']:.3g} -> {g['envelope_end']:.3g} {unit}, "
                   f"{g['efolds']:.1f} e-folds to the run's end)")
            return {"verdict": "diverging", "message": msg, "growth": g, "saturated_share": share}
    worst = int(np.argmax(share)) if share else 0
    if share and share[worst] > SATURATED_FRACTION:
        msg = (f"tau{worst + 1} at its motor's limit ({limits[worst]:g} N·m) on "
               f"{100 * share[worst]:.0f} % of the samples (> {100 * SATURATED_FRACTION:g} %)")
        return {"verdict": "saturated", "message": msg, "growth": None, "saturated_share": share}
    return {"verdict": "stable", "message": "", "growth": None, "saturated_share": share}


def series_verdict(series: dict, driver: str, limits) -> dict:
    """:func:`verdict` of a case's CSV columns (:func:`scenarios.results.analysis_columns`).

    Parameters
    ----------
    series : dict
        ``time`` (s) and ``err.omega1..11`` (rad/s), ``err.theta1..11`` (rad), ``<driver>.tau1``,
        ``<driver>.tau2`` (N·m), each shape (n,).
    driver : str
        The instance whose torques drive the plant.
    limits : sequence of 2 floats
        The motors' peak torques, N·m.

    Returns
    -------
    dict
        As :func:`verdict`, on the errors in degrees and deg/s.
    """
    vel = np.degrees(np.column_stack([series[f"err.omega{i}"] for i in range(1, 12)]))
    pos = np.degrees(np.column_stack([series[f"err.theta{i}"] for i in range(1, 12)]))
    tau = np.column_stack([series[f"{driver}.tau1"], series[f"{driver}.tau2"]])
    return verdict(series["time"], vel, pos, tau, limits)


def judge(out: dict, series: dict, driver: str) -> tuple[str, str, dict | None]:
    """A case's status, message and verdict (its :class:`CaseResult`'s).

    The master's outcome (``out["status"]``: ok, unbounded, error), unless the run finished ("ok") and its own
    samples say ``diverging`` or ``saturated`` (:func:`series_verdict`, against the parameter file's motor
    limits): that then is its status, with the growth rate or the saturated share in the message. So "ok"
    means finished and stable.
    """
    if out["status"] != "ok":
        return out["status"], out["message"], None
    from flexarm.parameters import load_parameters

    judged = series_verdict(series, driver, load_parameters().peak_torque)
    if judged["verdict"] == "stable":
        return "ok", out["message"], judged
    return judged["verdict"], judged["message"], judged


@dataclass
class CaseResult:
    """A case run and judged: what :func:`scenarios.run.runner.run_scenario` returns, one per case."""

    key: str
    label: str
    status: str
    message: str
    metrics: dict[str, float] | None
    wall_time_s: float
    series: dict[str, np.ndarray]
    outcome: master.Outcome = field(default_factory=lambda: master.Outcome("ok"))
    #: What the run did not do well (e.g. torque saturation, :func:`scenarios.metrics.saturation_warnings`; an
    #: unstable sampled loop the plant scheme cannot show, :func:`scenarios.analysis.stability.loop_stability`).
    warnings: list[str] = field(default_factory=list)
    #: The linearised sampled loop's stability (:func:`scenarios.analysis.stability.loop_stability`: the check, or
    #: why it was not made and whether the plant scheme could show a bracket-mode instability anyway).
    loop_stability: dict | None = None
    #: The run's verdict from its own samples (:func:`verdict`); None when it did not finish.
    verdict: dict | None = None


def judge_case(case, out: dict, metrics: dict | None, wall_time_s: float, algorithm: str, reference) -> CaseResult:
    """The judge stage of a run: a planned case's (:class:`scenarios.run.plan.PlannedCase`) master result `out`
    with its table `metrics`, its sampled loop's stability, the analysis columns (errors against `reference`,
    :func:`scenarios.results.analysis_columns`) and its verdict (:func:`judge`)."""
    fs = case.fmu_set
    step = fs.scenario.step_size
    series = {"time": out["time"], **out["signals"]}
    stab = loop_stability(fs.paths, fs.plant, fs.driver, case.parameters, step, fs.n_steps * step, algorithm,
                          metrics=metrics)
    notes = list(out.get("warnings", [])) + ([stab["note"]] if stab and stab["note"] else [])
    series.update(analysis_columns(series, fs.plant, reference))
    status, message, judged = judge(out, series, fs.driver)
    return CaseResult(case.key, case.label, status, message, metrics, wall_time_s, series, out["outcome"], notes,
                      stab, judged)
