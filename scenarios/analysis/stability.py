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

import functools
import math
from pathlib import Path

import numpy as np

INTEGRATOR_NAMES = {1: "rodas4", 2: "exponential", 3: "gauss", 4: "reference"}
GAIN_SET_NAMES = {1: "gamma1", 2: "gamma0.1", 3: "gamma0", 4: "eq32"}
SCHEDULE_LABELS = {0.2: "200ms", 0.02: "20ms", 0.0: "single"}
CONTROLLERS = {"controller": "", "controller_fb": "", "controller_dlqr": "dlqr-"}
#: A growth over the run of more than this many e-folds (growth rate × duration), in the exact sampled loop or in
#: the run's plant's, gets a warning.
E_FOLDS = 3.0
#: The largest difference between the plant's and the exact sampled loop's growth over the run, e^{|Δg|·T} − 1,
#: at which the note says the run shows the growth (the issue's bound on an unannounced deviation).
DEVIATION = 0.05
#: Communication steps by which a master's stepping delays the torque behind the state it was computed from:
#: Gauss-Seidel none; Jacobi (and fmpy's SSP stepping) two, one through the sensors and one through the controller
#: (every value is read before any input is set; README, "Parallel (Jacobi) masters").
DELAY_STEPS = {"gauss-seidel": 0, "jacobi": 2, "fmpy-ssp": 2}


def stability_matrix(X: np.ndarray, integrator: str) -> np.ndarray:
    """R(X): the scheme's one-substep map of the linear system y' = (X/h) y (X = h·M), its stability function
    evaluated on a matrix. All terms are polynomials in X, so they commute and the scalar formulas carry over."""
    from flexarm.model import numpy_kernels

    kern = numpy_kernels()  # RODAS4's coefficients, without loading Numba at a run's start

    eye = np.eye(len(X))
    if integrator == "gauss":  # 2-stage Gauss-Legendre: the (2,2) Padé approximant of exp
        x2 = X @ X / 12
        return np.linalg.solve(eye - X / 2 + x2, eye + X / 2 + x2)
    if integrator == "reference":  # classical RK4
        x2 = X @ X
        return eye + X + x2 / 2 + x2 @ X / 6 + x2 @ x2 / 24
    if integrator == "rodas4":  # as flexarm.integrator.rodas4_stability, stage by stage
        a, c, g = kern.RODAS4_A, kern.RODAS4_C, 1.0 / kern.RODAS4_GAMMA
        inv = np.linalg.inv(g * eye - X)
        ks, u = [], eye
        for stage in range(6):
            if stage:
                u = (eye + sum(a[stage, j] * ks[j] for j in range(stage))) if stage < 5 else u + ks[4]
            f = X @ u + sum(c[stage, j] * ks[j] for j in range(stage))
            ks.append(inv @ f)
        return u + ks[5]
    raise ValueError(f"integrator: no stability function for {integrator!r}")


def plant_zoh(A, B, dt: float, integrator: str = "exact", substeps: int = 2, expm=None):
    """(Φ, Γ) of the linear plant over one step `dt` with the torque held: exact (``exact``, and ``exponential``,
    which is exact on linear dynamics) or the scheme's own map at its nominal substep (RODAS4's error control only
    ever shortens it)."""
    from flexarm.lqr import zoh
    from flexarm.substeps import substep_count

    if integrator in ("exact", "exponential"):
        return zoh(A, B, dt, expm=expm)
    n = substep_count(dt, substeps, integrator)
    nx, nu = B.shape
    aug = np.zeros((nx + nu, nx + nu))
    aug[:nx, :nx], aug[:nx, nx:] = A, B
    step = np.linalg.matrix_power(stability_matrix(aug * (dt / n), integrator), n)
    return step[:nx, :nx], step[:nx, nx:]


def closed_loop(phi, gam, gain, delay: int = 0) -> np.ndarray:
    """The sampled closed loop x⁺ = Φx − ΓK x(k − delay) as one matrix on (x_k, x_{k−1}, …, x_{k−delay})."""
    nx = len(phi)
    if delay == 0:
        return phi - gam @ gain
    m = np.zeros((nx * (delay + 1), nx * (delay + 1)))
    m[:nx, :nx] = phi
    m[:nx, nx * delay:] -= gam @ gain
    m[nx:, :-nx] = np.eye(nx * delay)
    return m


def _growth_at(worst: dict, loop: np.ndarray, A: np.ndarray, dt: float, t_k: float) -> dict:
    """`worst`, or the growth of the sampled `loop` (its state starting with the arm's, A's) at operating point
    `t_k` when it grows faster: rate (1/s), time, aliased frequency and the arm mode that carries it."""
    ev, vec = np.linalg.eig(loop)
    i = int(np.argmax(np.abs(ev)))
    rate = float(np.log(np.abs(ev[i])) / dt)
    if rate <= worst["growth_per_s"]:
        return worst
    lam, modes = np.linalg.eig(A)
    weight = np.abs(np.linalg.lstsq(modes, vec[:len(A), i], rcond=None)[0])
    return {"growth_per_s": rate, "at_time_s": float(t_k),
            "aliased_frequency_hz": float(abs(np.angle(ev[i])) / (2 * np.pi * dt)),
            "mode_frequency_hz": float(abs(lam[int(np.argmax(weight))].imag) / (2 * np.pi))}


@functools.lru_cache(maxsize=128)
def sampled_loop_growth(gain_name: str, schedule: str, damping_ratio: float, payload_mass: float,
                        dt: float = 1e-3, integrator: str = "exact", substeps: int = 2, delay: int = 0) -> dict:
    """Largest ln ρ(closed loop)/dt (1/s) over the schedule's gain sets, where, the mode's aliased frequency (Hz) and
    the frequency of the arm's mode that carries it (Hz, ``mode_frequency_hz``: the eigenvalue of A whose
    eigenvector weighs most in the growing one), for a controller sampling and holding every `dt` (s), with the
    plant's step map :func:`plant_zoh` (`integrator` ``exact``: the converged plant) and `delay` steps of delay."""
    from flexarm.lqr import GainSchedule, effective_gain
    from flexarm.model import ArmModel, numpy_kernels
    from flexarm.parameters import load_parameters
    from flexarm.trajectory import load_trajectory
    from flexarm.trajectory.io import SAMPLE_TIME

    traj = load_trajectory()
    sched = GainSchedule.load(gain_name, schedule)
    # NumPy kernels: eleven linearisations and exponentials do not pay for loading Numba or scipy.linalg (more
    # than half a second of a run's start-up).
    kernels = numpy_kernels()
    model = ArmModel(load_parameters(payload_mass=payload_mass), damping_ratio=damping_ratio, kernels=kernels)
    worst = {"growth_per_s": -np.inf}
    for t_k, gain in zip(sched.times, sched.gains):
        k = min(int(round(t_k / SAMPLE_TIME)), traj.n_samples)  # the trajectory's sample at t_k
        A, B = model.linearize(traj.state(k))
        phi, gam = plant_zoh(A, B, dt, integrator, substeps, expm=kernels.expm)
        worst = _growth_at(worst, closed_loop(phi, gam, effective_gain(gain), delay), A, dt, t_k)
    return worst


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
        loop_delay = int(_value(ctrl, "loop_delay_samples", 0))
        from flexarm.loop_index import AUTOMATIC

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


# -- what a run cannot check: its plant scheme on the bracket modes ----------------------------------------------
#: Controllers whose loop is open (feedforward only): nothing feeds the bracket modes back, and every scheme gives
#: the open-loop plant's own growth along the slew (at most +1.98 1/s, a slow joint mode of the frozen
#: linearisation; +1.74 with the 0.275 kg payload) to within 1e-5 1/s (1e-3 on near-zero rates: round-off;
#: tests/test_loop_warning.py), so no warning.
OPEN_LOOP = ("controller_ff",)


def bracket_mode_errors(integrator: str, substeps: int, damping_ratio: float = 0.0, dt: float = 1e-3) -> dict:
    """Per bracket mode (the arm's three kHz modes, docs/model.md's damping table): its frequency (Hz), its
    structural decay rate ζω (1/s), the decay rate the scheme adds to it (1/s, −ln|R(hλ)^n|/dt − ζω) and the
    scheme's relative frequency error on it (arg R(hλ)^n / (ω_d·dt) − 1, phase per substep unwrapped), from the
    scheme's own stability function at `substeps` per ms over a step `dt` (exponential: exact on linear modes)."""
    from flexarm.substeps import substep_count

    out = {}
    for name, f in _bracket_frequencies().items():
        w = 2 * math.pi * f
        lam = complex(-damping_ratio * w, w * math.sqrt(max(1.0 - damping_ratio ** 2, 0.0)))
        if integrator in ("exact", "exponential"):
            decay, freq = 0.0, 0.0
        else:
            n = substep_count(dt, substeps, integrator)
            r = complex(stability_matrix(np.array([[lam * dt / n]]), integrator)[0, 0])
            decay = -n * math.log(max(abs(r), 1e-300)) / dt + lam.real
            freq = n * float(np.angle(r)) / (lam.imag * dt) - 1.0
        out[name] = {"frequency_hz": f, "structural_decay_per_s": -lam.real, "numerical_decay_per_s": decay,
                     "frequency_error": freq}
    return out


@functools.lru_cache(maxsize=1)
def _bracket_frequencies() -> dict:
    """The three bracket modes' frequencies (Hz) at rest at q = (0, 90°), named as
    :func:`scenarios.reports.scheme_accuracy.mode_frequencies` names them, from NumPy alone (its modal analysis loads
    Numba and scipy.linalg: about a second of a run's start)."""
    from flexarm.model import ArmModel, N, numpy_kernels, rigid_configuration
    from flexarm.parameters import load_parameters

    model = ArmModel(load_parameters(), kernels=numpy_kernels())
    z = np.concatenate([rigid_configuration(0.0, np.pi / 2), np.zeros(N)])
    omega_sq = -np.linalg.eigvals(model.jacobian(z)[N:, :N]).real  # at rest: θ̈ = A_θ θ, eigenvalues −ω²
    freqs = np.sort(np.sqrt(np.maximum(omega_sq, 0.0))) / (2 * np.pi)
    return {f"bracket mode {i + 1}": float(f) for i, f in enumerate(freqs[-3:])}


#: (integrator, substeps per ms) of the schemes the closed-loop table (docs/scheme-accuracy.json, ``loops``) shows
#: within :data:`DEVIATION` of the reference at every horizon on every loop: Gauss at 128 and 256 per ms, RK4 at
#: 2.5, 1.25 and 0.625 µs. Written here because an installed package has no docs/; tests/test_loop_warning.py
#: derives the set from the table and checks it equals this one.
RESOLVING_SCHEMES = (("gauss", 128), ("gauss", 256), ("reference", 2), ("reference", 4), ("reference", 8))


@functools.lru_cache(maxsize=1)
def resolved_envelope() -> dict:
    """Per bracket mode, the largest numerical decay rate and |relative frequency error| of the
    :data:`RESOLVING_SCHEMES`: what a scheme may do to a bracket mode and still give the reference's result."""
    env = {m: {"numerical_decay_per_s": 0.0, "frequency_error": 0.0} for m in _bracket_frequencies()}
    for integrator, sub in RESOLVING_SCHEMES:
        for m, e in bracket_mode_errors(integrator, sub).items():
            env[m]["numerical_decay_per_s"] = max(env[m]["numerical_decay_per_s"], e["numerical_decay_per_s"])
            env[m]["frequency_error"] = max(env[m]["frequency_error"], abs(e["frequency_error"]))
    return env


@functools.lru_cache(maxsize=1)
def injected_growth() -> dict:
    """The largest growth (1/s) a 1 ms sampled controller of this project drives a bracket mode to on the undamped
    arm: the exact sampled loops of every committed LQR gain schedule (``gamma*``, ``eq32``, their ``dlqr-``
    designs; 200 ms, 20 ms, single), Gauss-Seidel. The scale against which a bracket mode's structural decay
    ζω counts as little (3.40 1/s, eq. 32 at 20 ms, the 5.7 kHz mode; the LQG loops inject none)."""
    lowest = min(_bracket_frequencies().values())
    worst = {"growth_per_s": 0.0}
    for gain in GAIN_SET_NAMES.values():
        for prefix in set(CONTROLLERS.values()):
            for schedule in SCHEDULE_LABELS.values():
                g = sampled_loop_growth(prefix + gain, schedule, 0.0, 0.0)
                if g["mode_frequency_hz"] > lowest / 2 and g["growth_per_s"] > worst["growth_per_s"]:
                    worst = dict(g, gain_set=prefix + gain, schedule=schedule)
    return worst


def unresolved_bracket_modes(integrator: str, substeps: int, damping_ratio: float, dt: float = 1e-3) -> dict:
    """The bracket modes this plant scheme damps or misplaces beyond what the agreeing schemes of the table do
    (:func:`resolved_envelope`, 1e-9 relative slack for round-off) on an arm whose structural decay of that mode,
    ζω, is below the growth a sampled controller here drives a bracket mode to (:func:`injected_growth`): with
    more damping than that the structure, not the scheme, keeps such a loop stable. {mode: errors}."""
    env = resolved_envelope()
    out = {}
    for m, e in bracket_mode_errors(integrator, substeps, damping_ratio, dt).items():
        lim = env[m]
        off = (abs(e["numerical_decay_per_s"]) > lim["numerical_decay_per_s"] * (1 + 1e-9) + 1e-9
               or abs(e["frequency_error"]) > lim["frequency_error"] * (1 + 1e-9) + 1e-12)
        # ζ = 0: no structural decay, below the (positive, tested) injected growth without computing it (24 loop
        # analyses, about a second of the run's start)
        if off and (e["structural_decay_per_s"] == 0.0
                    or e["structural_decay_per_s"] < injected_growth()["growth_per_s"]):
            out[m] = e
    return out


def unchecked(controller: str, reason: str, integrator: str, substeps: int, damping_ratio: float,
              step_s: float) -> dict:
    """The record of a case whose loop is not checked here, with its note: "" when the controller is open-loop
    (:data:`OPEN_LOOP`) or the plant scheme resolves the bracket modes (:func:`unresolved_bracket_modes`), else
    one warning naming the controller, what this plant cannot show and the cure."""
    modes = {} if controller in OPEN_LOOP else unresolved_bracket_modes(integrator, substeps, damping_ratio, step_s)
    note = ""
    if modes:
        es = list(modes.values())
        freqs = "/".join(f"{e['frequency_hz'] / 1e3:.1f}" for e in es)
        damping = "/".join(f"{e['numerical_decay_per_s']:+.2g}" if abs(e["numerical_decay_per_s"]) > 1e-6 else "0"
                           for e in es)  # Gauss: round-off only
        shift = "/".join(f"{100 * e['frequency_error']:+.2g}" for e in es)
        note = (f"loop not checked ({controller}: {reason}); the {integrator} plant at {substeps} substeps/ms would "
                f"hide or misplace a bracket-mode instability (ζ = {damping_ratio:g}; {freqs} kHz modes: damping "
                f"{damping} 1/s, frequency {shift} %); rerun with plant integrator = reference, substeps = 4")
    return {"checked": False, "controller": controller, "reason": reason, "plant_integrator": integrator,
            "plant_substeps": substeps, "damping_ratio": damping_ratio, "unresolved_bracket_modes": modes,
            "note": note}


# -- the LQG loop (Kalman filter, predictor, discrete LQR): linear too --------------------------------------------
def lqg_closed_loop(phi_p, gam_p, phi_c, gam_c, M, C, K, K_xi=None, delay: int = 0, dt: float = 1e-3):
    """The sampled LQG loop of :class:`flexarm.lqg.LqgController` at one schedule point as one matrix: the plant
    (Φp, Γp: exact or the run's scheme) measured `delay` samples late (the controller's ``loop_delay_samples``
    equal to the master's delay), the controller's filter (Φc, Γc, M, C), its predictor across the delay, its gain
    K and, with integral action, K_ξ. State: plant errors e_k .. e_{k−delay}, the filter's posterior of sample
    k − delay − 1, the torque deviations of samples k − 1 − delay .. k − 1, and ξ (with integral action)."""
    nx, d = len(phi_p), int(delay)
    sizes = [nx * (d + 1), nx, 2 * (d + 1), 2 if K_xi is not None else 0]
    n = sum(sizes)
    eye = np.eye(n)
    o = np.cumsum([0] + sizes)
    hist = [eye[o[0] + nx * i: o[0] + nx * (i + 1)] for i in range(d + 1)]  # e_k, e_{k-1}, ...
    xp, du = eye[o[1]:o[2]], [eye[o[2] + 2 * i: o[2] + 2 * (i + 1)] for i in range(d + 1)]
    xi = eye[o[3]:o[4]]
    x = phi_c @ xp + gam_c @ du[0]  # time update with the torque of sample k − delay − 1
    post = x + M @ (C @ hist[d] - C @ x)  # the measurement of e_{k − delay}
    now = post
    for i in range(1, d + 1):
        now = phi_c @ now + gam_c @ du[i]
    u = -K @ now - (K_xi @ xi if K_xi is not None else 0)
    rows = [phi_p @ hist[0] + gam_p @ u, *hist[:d], post, *du[1:], u]
    if K_xi is not None:
        rows.append(xi + dt * (C[0:2] @ now))
    return np.vstack(rows)


@functools.lru_cache(maxsize=64)
def lqg_loop_growth(gain_name: str, schedule: str, damping_ratio: float, payload_mass: float,
                    integrator: str = "exact", substeps: int = 2, delay: int = 0, integral: bool = False) -> dict:
    """As :func:`sampled_loop_growth` for the LQG controller with one Kalman filter per schedule point
    (estimator = kalman) at 1 ms, along the design's operating points."""
    from flexarm.lqg_design import LqgDesign

    design = LqgDesign.load(schedule)
    w = design.weight_index(gain_name)

    def gains(i: int, n: int):
        if integral:
            return design.K_integral[i, w, :, :n], design.K_integral[i, w, :, n:]
        return design.K[i, w], None

    return _filtered_loop_growth(design, gains, damping_ratio, payload_mass, integrator, substeps, delay)


@functools.lru_cache(maxsize=64)
def predicted_loop_growth(gain_name: str, schedule: str, damping_ratio: float, payload_mass: float,
                          integrator: str = "exact", substeps: int = 2, delay: int = 2) -> dict:
    """As :func:`lqg_loop_growth` for the paper's law predicting over `delay` samples (a Jacobi master: the law
    measures the delay; :class:`flexarm.lqg.PredictedTracking`): the LQG design's filter and predictor of the
    schedule, the paper's law on the predicted measurement: its reduced gain on its reconstruction of it
    (:func:`flexarm.lqr.effective_gain`, K E C)."""
    from flexarm.lqg_design import LqgDesign
    from flexarm.lqr import GainSchedule, effective_gain

    on_prediction = effective_gain(GainSchedule.load(gain_name, schedule).gains)
    return _filtered_loop_growth(LqgDesign.load(schedule), lambda i, n: (on_prediction[i], None), damping_ratio,
                                 payload_mass, integrator, substeps, delay)


def _filtered_loop_growth(design, gains, damping_ratio: float, payload_mass: float, integrator: str, substeps: int,
                          delay: int) -> dict:
    """The growth of :func:`lqg_closed_loop` along the design's operating points, `gains(i, n_states)` giving the
    gain (and the integral gain or None) at point i."""
    from flexarm.model import ArmModel, numpy_kernels
    from flexarm.parameters import load_parameters
    from flexarm.trajectory import load_trajectory
    from flexarm.trajectory.io import SAMPLE_TIME

    dt = 1e-3
    traj = load_trajectory()
    kernels = numpy_kernels()
    model = ArmModel(load_parameters(payload_mass=payload_mass), damping_ratio=damping_ratio, kernels=kernels)
    worst = {"growth_per_s": -np.inf}
    for i, t_k in enumerate(design.times):
        k = min(int(round(t_k / SAMPLE_TIME)), traj.n_samples)
        A, B = model.linearize(traj.state(k))
        phi, gam = plant_zoh(A, B, dt, integrator, substeps, expm=kernels.expm)
        K, K_xi = gains(i, len(A))
        loop = lqg_closed_loop(phi, gam, design.Phi[i], design.Gamma[i], design.M[i], design.C, K, K_xi, delay, dt)
        worst = _growth_at(worst, loop, A, dt, t_k)
    return worst


# -- what the growth does to each of the six table metrics ------------------------------------------------------
#: The growing mode's content in the converged plant's errors, as an amplitude a₀ that grows as a₀·e^{g·t}, g the
#: exact sampled loop's growth: rms over the 11 elements' velocity errors and samples (deg/s; its position errors
#: carry a₀ / ω of it, ω the mode's angular frequency), per gain set, and the largest element's peak (deg/s).
#: Measured with the converged plant (reference, RK4 at 1.25 µs) against rodas4 (which damps the mode, at g'):
#: a₀² (F(gT) − F(g'T)) = rms_converged² − rms_rodas4², F(x) = (e^{2x} − 1)/(2x) the mean of e^{2gt} over [0, T].
#: Table 2 noise (γ = 0.1, the 5.7 kHz bracket mode, g = 0.987, g' = −0.054 1/s) over 3 s: 0.986 against 0.799 deg/s,
#: a₀ = 0.0734 (which predicts −4.2 % at 2.058 s, where issue 35 measured −4.4 %); Table 3 noise (γ = 0, g = 0.249,
#: g' = −0.035) over 10 s: 0.990 against 0.874, a₀ = 0.0875. A gain set not measured takes the larger. The peak:
#: docs/model.md's closed loops, γ = 0.1 noise at 5 and 7 s (29.3 and 203 deg/s): 0.211 and 0.203.
MODE_RMS_DEG_S = {"gamma0.1": 0.0734, "gamma0": 0.0875}
MODE_PEAK_DEG_S = 0.211


def _mean_square_growth(x: float) -> float:
    """F(x) = (e^{2x} − 1)/(2x): the mean of e^{2gt} over [0, T] with x = gT (1 at x = 0)."""
    x = min(x, 350.0)
    return math.expm1(2.0 * x) / (2.0 * x) if abs(x) > 1e-12 else 1.0


def metric_deviations(stab: dict, metrics: dict, duration_s: float) -> dict:
    """The predicted relative deviation of this run's table metrics from the converged plant's, run / converged − 1,
    ``{metric: deviation}`` for the error metrics (empty when the loop was not checked or the run has no metrics).

    The growing mode's content (:data:`MODE_RMS_DEG_S`, :data:`MODE_PEAK_DEG_S`) grows at the exact loop's rate in
    the converged plant and at the run's plant's own (``plant_growth_per_s``) in the run: the rms errors add its
    mean square, the peaks are the larger of the run's and its amplitude at the end. Peak torques are left to the
    loop's e-fold check (:func:`judge`: the feedback's torque on the mode grows with it)."""
    if not stab or not stab.get("checked") or not metrics:
        return {}
    T = float(duration_s)
    g, gp = float(stab["growth_per_s"]), float(stab["plant_growth_per_s"])
    omega = 2 * math.pi * float(stab["mode_frequency_hz"])
    # the mode's angle is its rate over |lambda| (|lambda| = the frequency for a lightly damped oscillation; the
    # growth rate for a real mode, whose frequency is 0); a mode with neither leaves the angles' metrics out
    magnitude = math.hypot(g, omega)
    pos = 1.0 / magnitude if magnitude > 0 else None
    out = {}
    for metric, scale in (("rms_velocity_error", 1.0), ("rms_position_error", pos)):
        if scale is None:
            continue
        run = float(metrics[metric])
        a2 = (MODE_RMS_DEG_S.get(stab.get("gain_set"), max(MODE_RMS_DEG_S.values())) * scale) ** 2
        in_run = _mean_square_growth(gp * T)
        a2 = min(a2, run ** 2 / in_run)  # the mode carries at most the run's whole error (a mode of another kind)
        conv = math.sqrt(run ** 2 - a2 * in_run + a2 * _mean_square_growth(g * T))
        out[metric] = run / conv - 1.0 if conv > 0 else 0.0
    for metric, scale in (("peak_velocity_error", 1.0), ("peak_position_error", pos)):
        if scale is None:
            continue
        run = float(metrics[metric])
        amplitude = min(MODE_PEAK_DEG_S * scale, run * math.exp(-max(gp * T, -700.0)))  # at most the run's, as above
        conv = max(run, amplitude * math.exp(min(g * T, 700.0)))
        out[metric] = run / conv - 1.0 if conv > 0 else 0.0
    return out


def metric_note(deviations: dict, stab: dict) -> str:
    """A warning naming every table metric whose predicted deviation exceeds :data:`DEVIATION` ('' if none)."""
    from scenarios.metrics import LABELS

    off = {m: d for m, d in deviations.items() if abs(d) > DEVIATION}
    if not off:
        return ""
    listed = ", ".join(f"{LABELS[m].split(',')[0]} {d:+.1%}" for m, d in off.items())
    return (f"the {stab['plant_integrator']} plant at {stab['plant_substeps']} substeps/ms puts table metrics more "
            f"than {DEVIATION:.0%} off the converged plant's, as predicted from the linearised sampled loop (the "
            f"{stab['mode_frequency_hz']:.0f} Hz mode grows at {stab['growth_per_s']:+.3f} 1/s, in this plant at "
            f"{stab['plant_growth_per_s']:+.3f}): {listed} (this run against the converged plant); rerun with "
            "plant integrator = reference, substeps = 4 for these figures")
