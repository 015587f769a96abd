"""What a run cannot check: how its plant scheme damps or misplaces the bracket modes, against the envelope of the
schemes that resolve them (:func:`resolved_envelope`) and the growth our controllers drive them to.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from scenarios.analysis.sampled_loop import (
    CONTROLLERS,
    GAIN_SET_NAMES,
    SCHEDULE_LABELS,
    sampled_loop_growth,
    stability_matrix,
)

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
    :func:`scenarios.reports.scheme_accuracy_parts.mode_frequencies` names them, from NumPy alone (its modal
    analysis loads Numba and scipy.linalg: about a second of a run's start)."""
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
