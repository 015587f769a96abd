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
    from flexarm import _kernels as kern

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
    from flexarm.integrator import substep_count
    from flexarm.lqr import zoh

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
        ev, vec = np.linalg.eig(closed_loop(phi, gam, effective_gain(gain), delay))
        i = int(np.argmax(np.abs(ev)))
        rate = float(np.log(np.abs(ev[i])) / dt)
        if rate > worst["growth_per_s"]:
            lam, modes = np.linalg.eig(A)
            weight = np.abs(np.linalg.lstsq(modes, vec[:len(A), i], rcond=None)[0])
            worst = {"growth_per_s": rate, "at_time_s": float(t_k),
                     "aliased_frequency_hz": float(abs(np.angle(ev[i])) / (2 * np.pi * dt)),
                     "mode_frequency_hz": float(abs(lam[int(np.argmax(weight))].imag) / (2 * np.pi))}
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
                   duration_s: float, algorithm: str = "gauss-seidel") -> dict | None:
    """The check for one case, or None when it does not apply (another controller, or a step of no whole number of
    milliseconds).

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
    """
    prefix = CONTROLLERS.get(Path(str(paths.get(driver, ""))).stem)
    samples = round(step_s / 1e-3)
    if prefix is None or samples < 1 or abs(step_s - samples * 1e-3) > 1e-9:
        return None  # the FMUs refuse a step of no whole number of milliseconds themselves
    if algorithm not in DELAY_STEPS:
        raise ValueError(f"algorithm: must be one of {', '.join(DELAY_STEPS)}, got {algorithm!r}")
    ctrl, pl = params.get(driver, {}), params.get(plant, {})
    gain_set = _value(ctrl, "gain_set", 2)
    gain = GAIN_SET_NAMES.get(int(gain_set), None) if not isinstance(gain_set, str) else gain_set
    schedule = SCHEDULE_LABELS.get(round(float(_value(ctrl, "schedule_period", 0.2)), 9))
    if gain is None or schedule is None:
        return None
    integ = _value(pl, "integrator", 1)
    integrator = INTEGRATOR_NAMES.get(int(integ), str(integ)) if not isinstance(integ, str) else integ
    substeps = int(_value(pl, "substeps", 2))
    ratio, payload = float(_value(pl, "damping_ratio", 0.0)), float(_value(pl, "payload_mass", 0.0))
    delay = DELAY_STEPS[algorithm]
    args = (prefix + gain, schedule, ratio, payload, samples * 1e-3)
    exact = sampled_loop_growth(*args, delay=delay)
    own = sampled_loop_growth(*args, integrator=integrator, substeps=substeps, delay=delay)
    out = {"gain_set": prefix + gain, "schedule": schedule, "damping_ratio": ratio, "payload_mass": payload,
           "plant_integrator": integrator, "plant_substeps": substeps, "step_ms": samples,
           "algorithm": algorithm, "delay_steps": delay, **exact,
           "e_folds_over_run": exact["growth_per_s"] * float(duration_s),
           "plant_growth_per_s": own["growth_per_s"],
           "plant_e_folds_over_run": own["growth_per_s"] * float(duration_s)}
    out["note"], out["predicted_deviation"] = judge(exact, own, float(duration_s), integrator, substeps, samples,
                                                    delay)
    return out
