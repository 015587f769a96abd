"""Is the case's loop stable? The linearised 1 ms sampled loop, checked before believing the plant (issue 24 item 5).

The default plant scheme (RODAS4, L-stable) damps the kHz bracket modes, and Gauss at coarse substeps shifts their
frequencies, so a gain that destabilises a bracket mode through the 1 ms zero-order hold gives a quiet run with
them (γ = 1: 8 deg/s where the converged plant reaches 170 deg/s at 2 s and 3000 at 10 s; docs/model.md). Each case
whose controller is an LQR gain schedule (``controller``, ``controller_fb``, ``controller_dlqr``) run at 1 ms is
therefore checked here: the spectral radius of Φ − Γ K C at the schedule's 11 operating points (the exact ZOH of
the linearised arm with the case's payload and modal damping, gains as implemented: rigid-bracket reconstruction,
tachometers). A loop that grows by more than :data:`E_FOLDS` e-folds over the run gets a note (one of the run's
warnings, printed with the results and in the case's JSON, beside ``loop_stability``) saying whether this run's
plant scheme can show it. The threshold is measured (docs/model.md, closed loops): the bracket mode grows from
round-off and sensor noise, so RODAS4 stays within 1.5 % of the reference on γ = 0.1 over the 2.058 s slew
(2.0 e-folds) but is 70 % off at 5 s (4.9), and 37-95 % off at 2 s on eq. 32 and γ = 1 (6.5-6.7).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

#: The plant scheme settings that resolve the 5.7 kHz bracket mode's dynamics (docs/model.md, closed loops: Gauss
#: at 128 substeps per ms is still 3-5 % off the converged reference, at 256 within 0.3 %).
HONEST = {"reference": 1, "exponential": 1, "gauss": 256}
INTEGRATOR_NAMES = {1: "rodas4", 2: "exponential", 3: "gauss", 4: "reference"}
GAIN_SET_NAMES = {1: "gamma1", 2: "gamma0.1", 3: "gamma0", 4: "eq32"}
SCHEDULE_LABELS = {0.2: "200ms", 0.02: "20ms", 0.0: "single"}
CONTROLLERS = {"controller": "", "controller_fb": "", "controller_dlqr": "dlqr-"}
#: A growth over the run of more than this many e-folds (growth rate × duration) gets a warning.
E_FOLDS = 3.0
#: Modes above this frequency are the stiff brackets' (5.7 kHz and up, docs/model.md), which only the settings in
#: HONEST resolve; the link modes (8 Hz to a few hundred) every scheme resolves at its default substeps.
BRACKET_HZ = 2000.0


@functools.lru_cache(maxsize=64)
def sampled_loop_growth(gain_name: str, schedule: str, damping_ratio: float, payload_mass: float,
                        dt: float = 1e-3) -> dict:
    """Largest ln ρ(Φ − ΓKC)/dt (1/s) over the schedule's gain sets, where, the mode's aliased frequency (Hz) and
    the frequency of the arm's mode that carries it (Hz, ``mode_frequency_hz``: the eigenvalue of A whose
    eigenvector weighs most in the growing one), for a controller sampling and holding every `dt` (s)."""
    from flexarm.lqr import GainSchedule, effective_gain, zoh
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
        phi, gam = zoh(A, B, dt, expm=kernels.expm)
        ev, vec = np.linalg.eig(phi - gam @ effective_gain(gain))
        i = int(np.argmax(np.abs(ev)))
        rate = float(np.log(np.abs(ev[i])) / dt)
        if rate > worst["growth_per_s"]:
            lam, modes = np.linalg.eig(A)
            weight = np.abs(np.linalg.lstsq(modes, vec[:, i], rcond=None)[0])
            worst = {"growth_per_s": rate, "at_time_s": float(t_k),
                     "aliased_frequency_hz": float(abs(np.angle(ev[i])) / (2 * np.pi * dt)),
                     "mode_frequency_hz": float(abs(lam[int(np.argmax(weight))].imag) / (2 * np.pi))}
    return worst


def _value(params: dict, key: str, default):
    value = params.get(key, default)
    return value.item() if hasattr(value, "item") else value


def loop_stability(paths: dict, plant: str, driver: str, params: dict, step_s: float,
                   duration_s: float) -> dict | None:
    """The check for one case, or None when it does not apply (another controller, or a step of no whole number of
    milliseconds). The controller samples and holds at the communication step (Gauss-Seidel).

    Parameters
    ----------
    paths : dict
        FMU instance name -> its file (the controller's file name tells which law it runs).
    plant, driver : str
        The plant's and the torque-driving controller's instance names.
    params : dict
        The case's checked parameters per instance.
    step_s : float
        The communication step (s).
    duration_s : float
        The run's length (s).
    """
    prefix = CONTROLLERS.get(Path(str(paths.get(driver, ""))).stem)
    samples = round(step_s / 1e-3)
    if prefix is None or samples < 1 or abs(step_s - samples * 1e-3) > 1e-9:
        return None  # the FMUs refuse a step of no whole number of milliseconds themselves
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
    out = {"gain_set": prefix + gain, "schedule": schedule, "damping_ratio": ratio, "payload_mass": payload,
           "plant_integrator": integrator, "plant_substeps": substeps,
           "step_ms": samples, **sampled_loop_growth(prefix + gain, schedule, ratio, payload, samples * 1e-3)}
    note = ""
    out["e_folds_over_run"] = out["growth_per_s"] * float(duration_s)
    if out["e_folds_over_run"] > E_FOLDS:
        what = (f"the linearised {samples} ms sampled loop is unstable (growth {out['growth_per_s']:+.2f} 1/s, "
                f"{out['e_folds_over_run']:.1f} e-folds over the run; the {out['mode_frequency_hz']:.0f} Hz mode, "
                f"aliased to {out['aliased_frequency_hz']:.0f} Hz, gain set of t = {out['at_time_s']:g} s)")
        if substeps >= HONEST.get(integrator, 10**9):
            note = f"{what}: the {integrator} plant shows that growth"
        elif out["mode_frequency_hz"] < BRACKET_HZ:  # a link mode, which every scheme resolves at 2 per ms
            note = f"{what}: the {integrator} plant resolves that mode and this run shows the growth"
        else:
            hides = "damps" if integrator == "rodas4" else "misplaces"
            note = (f"{what}, and the {integrator} plant at {substeps} substeps/ms {hides} the bracket mode that "
                    "carries it: this run does not show the growth; rerun with plant integrator = reference")
    out["note"] = note
    return out
