"""The noise cases across stepping, over many noise seeds: what one realisation cannot say (issue 31).

A noise case of the conformance matrix compares one noise realisation in two loops. Both steppings draw the same
noise for the same plant sample (docs/sensors.md), but in a Jacobi master that sample's noise reaches the torque
two samples later, through the predictor over the delay, so the two runs are two realisations of one noisy loop,
and their figures differ by the realisation's own spread. Whether a Jacobi master gives the Gauss-Seidel answer is
then a question about the figures' distributions: this module runs every noise case of the matrix's scenarios on
the native FMUs in our master, both steppings, with noise seeds 1..N (the other Jacobi masters give our Jacobi
master's figures: the matrix), and reports per case each stepping's mean over the seeds and the paired
difference (Jacobi − Gauss-Seidel, seed by seed, the same noise in both) with its 95 % interval (two standard
errors), judged against the matrix's tolerance (5 % of the Gauss-Seidel mean, or 0.005 deg / 0.05 deg/s):
*within* when the whole interval lies inside it, *outside* when the whole interval lies beyond it, *undecided*
when the seeds do not settle it.

``python -m scenarios conformance --write`` stores the per-seed figures in ``docs/conformance.json``
(``noise_seeds``); the results page renders the table of ``docs/masters-and-ssp.md`` from it.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from scenarios.config import load_scenario
from scenarios.conformance.matrix import FIGURES as FLOORS
from scenarios.conformance.matrix import tolerance
from scenarios.run.runner import simulate_case
from scenarios.run.setup import prepare

#: Noise seeds per case and stepping: with the per-seed ratio's spread of about 10-30 % (one realisation against
#: another), 32 pairs put the mean difference's standard error at 2-5 % of the figure.
SEEDS = tuple(range(1, 33))
STEPPINGS = ("gauss-seidel", "jacobi")
FIGURES = ("rms_position_error", "rms_velocity_error")
BLOCK = "conformance-noise-seeds"
#: Half-width of the difference's interval in standard errors (about 95 %).
Z = 2.0


def noise_cases(scenarios) -> list[tuple[str, str]]:
    """(scenario, case key) of every case with the sensors' noise on."""
    return [(name, c.key) for name in scenarios for c in load_scenario(name).cases
            if c.parameters.get("sensors", {}).get("noise_enabled", False)]


def run_seeds(scenarios, seeds=SEEDS, kind: str = "native", progress: bool = True) -> dict:
    """Every noise case of `scenarios` in our master, both steppings, each seed: the per-seed figures.

    Returns ``{"seeds": [...], "kind": kind, "rows": [{"scenario", "case", "gauss-seidel": {figure: [...]},
    "jacobi": {...}}]}``; a run that does not end ok raises RuntimeError naming it (no figure stands for it).
    """
    by_scenario: dict[str, list[str]] = {}
    for name, key in noise_cases(scenarios):
        by_scenario.setdefault(name, []).append(key)
    rows = []
    for name, keys in by_scenario.items():
        sc = load_scenario(name)
        figures = {key: {s: {f: [] for f in FIGURES} for s in STEPPINGS} for key in keys}
        for stepping in STEPPINGS:
            setup = prepare(sc, kind=kind, algorithm=stepping)
            with setup.open_master(stepping) as m:
                for key in keys:
                    case = next(c for c in sc.cases if c.key == key)
                    for seed in seeds:
                        parameters = copy.deepcopy(case.parameters)
                        parameters.setdefault("sensors", {})["noise_seed"] = seed
                        out, metrics = simulate_case(setup, m, parameters)
                        if metrics is None or out["status"] != "ok":
                            raise RuntimeError(f"{name}/{key}, {stepping}, noise_seed {seed}: {out['status']}: "
                                               f"{out['message']}")
                        for f in FIGURES:
                            figures[key][stepping][f].append(float(metrics[f]))
                    if progress:
                        print(f"conformance: noise seeds {name}/{key} {stepping}: {len(seeds)} runs", flush=True)
        rows += [{"scenario": name, "case": key, **figures[key]} for key in keys]
    return {"about": "our master, native FMUs, every noise case with noise_seed 1..N in both steppings: rms position "
                     "error (deg) and rms velocity error (deg/s) per seed",
            "kind": kind, "seeds": list(seeds), "rows": rows}


def paired(gauss_seidel, jacobi, floor: float) -> dict:
    """Means over the seeds and the paired difference Jacobi − Gauss-Seidel: its mean and standard error, the
    matrix's tolerance about the Gauss-Seidel mean (`floor`: its absolute floor) and the verdict: ``within``
    (mean ± Z s.e. inside ± tolerance), ``outside`` (the whole interval beyond it) or ``undecided``."""
    g, j = np.asarray(gauss_seidel, dtype=float), np.asarray(jacobi, dtype=float)
    d = j - g
    mean, se = float(d.mean()), float(d.std(ddof=1) / math.sqrt(len(d)))
    tol = tolerance(float(g.mean()), floor)
    verdict = ("within" if abs(mean) + Z * se <= tol else "outside" if abs(mean) - Z * se > tol else "undecided")
    return {"gauss_seidel": float(g.mean()), "jacobi": float(j.mean()), "difference": mean, "standard_error": se,
            "tolerance": tol, "verdict": verdict}


def verdicts(data: dict) -> dict[str, int]:
    """How many figures of `data` are within, outside and undecided (:func:`paired`)."""
    counts = {"within": 0, "outside": 0, "undecided": 0}
    for r in data["rows"]:
        for f in FIGURES:
            counts[paired(r["gauss-seidel"][f], r["jacobi"][f], FLOORS[f])["verdict"]] += 1
    return counts


def render(data: dict) -> str:
    """The Markdown table: per noise case and figure, each stepping's mean over the seeds, the paired difference
    with its interval, the tolerance and the verdict (:func:`paired`)."""
    n = len(data["seeds"])
    lines = ["| case | figure | Gauss-Seidel, mean | Jacobi, mean | Jacobi − Gauss-Seidel, ± 2 s.e. | tolerance | |",
             "|---|---|---|---|---|---|---|"]
    for r in data["rows"]:
        for f, label in zip(FIGURES, ("position, deg", "velocity, deg/s")):
            p = paired(r["gauss-seidel"][f], r["jacobi"][f], FLOORS[f])
            verdict = p["verdict"] if p["verdict"] == "within" else f"**{p['verdict']}**"
            lines.append(f"| {r['scenario']}/{r['case']} | {label} | {p['gauss_seidel']:.4g} | {p['jacobi']:.4g} | "
                         f"{p['difference']:+.2g} ± {Z * p['standard_error']:.2g} | {p['tolerance']:.2g} | {verdict} |")
    counts = verdicts(data)
    lines += ["", f"{data['kind'].capitalize()} FMUs, our master, noise seeds {data['seeds'][0]}..{data['seeds'][-1]} "
              f"({n} pairs, the same noise on the same plant samples in both steppings): of {sum(counts.values())} "
              f"figures, {counts['within']} within the tolerance, {counts['outside']} outside, "
              f"{counts['undecided']} undecided by {n} seeds."]
    return "\n".join(lines)


__all__ = ["BLOCK", "SEEDS", "noise_cases", "paired", "render", "run_seeds", "verdicts"]
