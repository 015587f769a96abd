"""Is the case's loop stable, and does this run's plant show it? The linearised sampled loop (issue 24 item 5).

The default plant scheme (RODAS4, L-stable) damps the kHz bracket modes, and Gauss at coarse substeps shifts their
frequencies, so a gain that destabilises a bracket mode through the 1 ms zero-order hold gives a quiet run with
them (γ = 1: 8 deg/s where the converged plant reaches 170 deg/s at 2 s and 3000 at 10 s; docs/model.md). Each case
whose controller is an LQR gain schedule (``controller``, ``controller_fb``, ``controller_dlqr``) stepped at whole
milliseconds is therefore checked here, twice, along the schedule's 11 operating points (the linearised arm with
the case's payload and modal damping, gains as implemented: rigid-bracket reconstruction, tachometers; under Jacobi
stepping the torque reaches the plant two communication steps after the state it came from):

* the **exact** sampled loop: Φ = e^{A·dt}, the exact zero-order hold, what a converged plant shows;
* the **run's plant** sampled loop: Φ and Γ from the plant scheme's own one-step map at its (nominal) substep,
  R(h·M)^n on the augmented linear system M = [[A, B], [0, 0]] (R the scheme's stability function: RODAS4's, the
  (2,2) Padé of Gauss, RK4's; the exponential scheme is exact on linear dynamics). This carries the scheme's
  numerical damping and frequency error on the modes that grow.

A loop that grows by more than :data:`E_FOLDS` e-folds over the run in either gets a note (one of the run's
warnings, printed with the results and in the case's JSON, beside ``loop_stability``). The note says this run
shows the growth only when the plant's sampled loop grows at the exact rate to within :data:`DEVIATION` over the
run (e^{|Δg|·T} − 1, ``predicted_deviation``); otherwise that the run hides it (damped) or misrepresents it.
Calibrated on the closed-loop table of docs/model.md: under 3 e-folds every scheme stays within 1.5 % of the
converged reference (RODAS4 on γ = 0.1 over the 2.058 s slew, 2.0 e-folds); above it the schemes more than 5 % off
(RODAS4, Gauss at 2 and 32 substeps per ms) are those whose sampled-loop growth is off by more than 5 % over the
horizon, and those within it (Gauss at 128 and 256 per ms, the RK4 references) are within 3.6 % of the reference.

The LQG controller with one Kalman filter per schedule point (``controller_lqg``, estimator = kalman, 1 ms, its
``loop_delay_samples`` equal to the master's delay) is linear too and checked the same way
(:func:`lqg_loop_growth`: plant, filter, predictor, gain), and so is the paper's law under Jacobi
stepping, where it measures the delay and predicts over it with the LQG's filter
(:func:`predicted_loop_growth`). Every other case is recorded as not checked
(:func:`unchecked`: the payload bank, a user's controller, a step of no whole number of milliseconds), and its
run warns when its plant scheme damps or misplaces a bracket mode beyond what the schemes the closed-loop table
shows within 5 % of the reference do to it (:func:`resolved_envelope`), on an arm whose structural decay of that
mode is below the growth this project's sampled controllers drive a bracket mode to (:func:`injected_growth`,
3.40 1/s): a loop that destabilises that mode would look quiet.
Feedforward only (``controller_ff``) is an open loop: no warning (:data:`OPEN_LOOP`).
"""

from __future__ import annotations

import math
from pathlib import Path

from scenarios.analysis.bracket_modes import OPEN_LOOP, unchecked
from scenarios.analysis.metric_deviation import DEVIATION, metric_deviations, metric_note
from scenarios.analysis.sampled_loop import (
    CONTROLLERS,
    GAIN_SET_NAMES,
    INTEGRATOR_NAMES,
    SCHEDULE_LABELS,
    lqg_loop_growth,
    predicted_loop_growth,
    sampled_loop_growth,
)

#: A growth over the run of more than this many e-folds (growth rate × duration), in the exact sampled loop or in
#: the run's plant's, gets a warning.
E_FOLDS = 3.0
#: Communication steps by which a master's stepping delays the torque behind the state it was computed from:
#: Gauss-Seidel none; Jacobi (and fmpy's SSP stepping) two, one through the sensors and one through the controller
#: (every value is read before any input is set; README, "Parallel (Jacobi) masters").
DELAY_STEPS = {"gauss-seidel": 0, "jacobi": 2, "fmpy-ssp": 2}


def _value(params: dict, key: str, default):
    value = params.get(key, default)
    return value.item() if hasattr(value, "item") else value


def judge(exact: dict, plant: dict, duration_s: float, integrator: str, substeps: int, step_ms: int,
          delay: int = 0) -> tuple[str, float]:
    """The run's note ("" when neither loop grows by more than :data:`E_FOLDS` e-folds over `duration_s`) and the
    predicted deviation e^{|Δg|·T} − 1 of the plant's growth from the exact one over the run.

    `exact` and `plant` are :func:`sampled_loop_growth` of the converged plant and of the run's plant scheme."""
    e_exact, e_plant = exact["growth_per_s"] * duration_s, plant["growth_per_s"] * duration_s
    deviation = math.expm1(min(abs(e_plant - e_exact), 700.0))
    if max(e_exact, e_plant) <= E_FOLDS:
        return "", deviation
    scheme = f"the {integrator} plant at {substeps} substeps/ms"
    own = f"its own linearised sampled loop grows at {plant['growth_per_s']:+.3f} 1/s, {e_plant:.1f} e-folds"
    cure = "rerun with plant integrator = reference, substeps = 4"
    loop = f"{step_ms} ms sampled loop" + (f" (torque {delay} steps late: Jacobi stepping)" if delay else "")
    if e_exact <= E_FOLDS:
        return (f"{scheme} makes the linearised {loop} grow ({own}) where the exact one does not "
                f"({exact['growth_per_s']:+.3f} 1/s): growth in this run is numerical; {cure}"), deviation
    what = (f"the linearised {loop} is unstable (growth {exact['growth_per_s']:+.2f} 1/s, {e_exact:.1f} e-folds "
            f"over the run; the {exact['mode_frequency_hz']:.0f} Hz mode, aliased to "
            f"{exact['aliased_frequency_hz']:.0f} Hz, gain set of t = {exact['at_time_s']:g} s)")
    if deviation <= DEVIATION:
        return f"{what}: {scheme} shows that growth ({own}, within {deviation:.1%} over the run)", deviation
    if e_plant <= E_FOLDS:
        return (f"{what}, and {scheme} damps or misplaces the mode that carries it ({own}): this run does not "
                f"show the growth; {cure}"), deviation
    return (f"{what}, and {scheme} misrepresents it ({own}, {deviation:.0%} off over the run): this run's "
            f"figures are not the converged loop's; {cure}"), deviation


def loop_stability(paths: dict, plant: str, driver: str, params: dict, step_s: float,
                   duration_s: float, algorithm: str = "gauss-seidel", metrics: dict | None = None) -> dict:
    """The check for one case (``checked`` true), or the record of why it was not made (``checked`` false,
    :func:`unchecked`: a controller with no linear model here, a step of no whole number of milliseconds, the
    payload bank), whose note warns when this plant scheme could not show a bracket-mode instability anyway.

    Parameters
    ----------
    paths : dict
        FMU instance name -> its file (the controller's file name tells which law it runs).
    plant, driver : str
        The plant's and the torque-driving controller's instance names.
    params : dict
        The case's checked parameters per instance.
    step_s : float
        The communication step (s): the controller samples and holds at it.
    duration_s : float
        The run's length (s).
    algorithm : str
        The master's stepping (:data:`DELAY_STEPS`).
    metrics : dict, optional
        The run's table metrics: with them a checked loop also predicts each one's deviation from the converged
        plant's (``predicted_metric_deviation``, :func:`metric_deviations`) and the note names every one more than
        :data:`DEVIATION` off.
    """
    if algorithm not in DELAY_STEPS:
        raise ValueError(f"algorithm: must be one of {', '.join(DELAY_STEPS)}, got {algorithm!r}")
    stem = Path(str(paths.get(driver, ""))).stem
    ctrl, pl = params.get(driver, {}), params.get(plant, {})
    integ = _value(pl, "integrator", 1)
    integrator = INTEGRATOR_NAMES.get(int(integ), str(integ)) if not isinstance(integ, str) else integ
    substeps = int(_value(pl, "substeps", 2))
    ratio, payload = float(_value(pl, "damping_ratio", 0.0)), float(_value(pl, "payload_mass", 0.0))
    delay = DELAY_STEPS[algorithm]
    samples = round(step_s / 1e-3)

    def skip(reason):
        return unchecked(stem, reason, integrator, substeps, ratio, step_s)

    lqg = stem == "controller_lqg"
    if stem in OPEN_LOOP:
        return skip("feedforward only: an open loop, which no scheme can make grow")
    if stem not in CONTROLLERS and not lqg:
        return skip("no linear model of this controller here")
    if samples < 1 or abs(step_s - samples * 1e-3) > 1e-9:
        return skip(f"a {step_s * 1e3:g} ms step is no whole number of milliseconds")
    gain_set = _value(ctrl, "gain_set", 2)
    gain = GAIN_SET_NAMES.get(int(gain_set), None) if not isinstance(gain_set, str) else gain_set
    schedule = SCHEDULE_LABELS.get(round(float(_value(ctrl, "schedule_period", 0.2)), 9))
    if gain is None or schedule is None:
        return skip("gain set or schedule period not among the committed designs")
    common = {"checked": True, "controller": stem, "damping_ratio": ratio, "payload_mass": payload,
              "plant_integrator": integrator, "plant_substeps": substeps, "step_ms": samples,
              "algorithm": algorithm, "delay_steps": delay}
    if lqg:
        est = _value(ctrl, "estimator", 1)
        estimator = {1: "kalman", 2: "payload_bank"}.get(est, str(est)) if not isinstance(est, str) else est
        from flexarm.loop_index import AUTOMATIC

        loop_delay = int(_value(ctrl, "loop_delay_samples", AUTOMATIC))  # not set: the FMU's start, automatic
        if loop_delay == AUTOMATIC:  # it measures the master's delay and predicts over it (docs/control.md)
            loop_delay = delay
        if estimator != "kalman":
            return skip(f"estimator = {estimator}, not linear")
        if samples != 1:
            return skip(f"the LQG controller at a {samples} ms step (its linear loop is built at 1 ms)")
        if loop_delay != delay:
            return skip(f"loop_delay_samples = {loop_delay} where the {algorithm} master delays by {delay}")
        integral = bool(_value(ctrl, "integral_action", False))
        gain = gain.removeprefix("dlqr-")
        args = (gain, schedule, ratio, payload)
        exact = lqg_loop_growth(*args, delay=delay, integral=integral)
        own = lqg_loop_growth(*args, integrator=integrator, substeps=substeps, delay=delay, integral=integral)
        common.update(estimator=estimator, integral_action=integral)
    elif delay:  # the paper's law measures the master's delay and predicts over it (flexarm.lqg.PredictedTracking)
        if samples != 1:
            return skip(f"the paper's law predicting over a delay at a {samples} ms step (its loop is built at 1 ms)")
        gain = CONTROLLERS[stem] + gain
        args = (gain, schedule, ratio, payload)
        exact = predicted_loop_growth(*args, delay=delay)
        own = predicted_loop_growth(*args, integrator=integrator, substeps=substeps, delay=delay)
        common.update(predicted_over_delay=True)
    else:
        prefix = CONTROLLERS[stem]
        gain = prefix + gain
        args = (gain, schedule, ratio, payload, samples * 1e-3)
        exact = sampled_loop_growth(*args, delay=delay)
        own = sampled_loop_growth(*args, integrator=integrator, substeps=substeps, delay=delay)
    out = {**common, "gain_set": gain, "schedule": schedule, **exact,
           "e_folds_over_run": exact["growth_per_s"] * float(duration_s),
           "plant_growth_per_s": own["growth_per_s"],
           "plant_e_folds_over_run": own["growth_per_s"] * float(duration_s)}
    out["note"], out["predicted_deviation"] = judge(exact, own, float(duration_s), integrator, substeps, samples,
                                                    delay)
    if metrics:
        out["predicted_metric_deviation"] = metric_deviations(out, metrics, duration_s)
        extra = metric_note(out["predicted_metric_deviation"], out)
        out["note"] = "; ".join(n for n in (out["note"], extra) if n)
    return out
