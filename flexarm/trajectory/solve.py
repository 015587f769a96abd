"""The complete solve: rigid warm-up, flexible free-t_f solve, then t_f rounded up to a whole ms.

See :mod:`flexarm.trajectory.problem` for the NLP and docs/trajectory.md for the method.

The 1 ms file
-------------
θ and θ̇ are the optimiser's collocation polynomials evaluated every 1 ms
(the desired states come from the optimiser's model). The torque held over
sample k, [kΔ, (k+1)Δ), is the exact mean of the piecewise-linear optimal
torque over that millisecond, so a zero-order-hold replay delivers the same
impulse per step; the torque at t_f (the last sample) is zero.
:func:`verify_against_plant` replays those torques open loop in the full
11-element plant (:func:`flexarm.integrator.simulate`) and measures the
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import shlex
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np

from ..model import ArmModel
from ..parameters import ArmParameters, load_parameters
from ..provenance import git_commit
from .io import PAPER_TF, SAMPLE_TIME, TrajectoryError, TrajectoryResult
from .problem import (
    DEFAULT_REGULARISATION,
    FLEX_GROUPS,
    LINE_TOLERANCE,
    REPLAN_FIXED_TIME_OPTIONS,
    REPLAN_FREE_TIME_OPTIONS,
    RIGID_GROUPS,
    TORQUE_RATE_LIMIT,
    CollocationSolution,
    blas_threads,
    solve_collocation,
)


def solve_free_time(params: ArmParameters, n_intervals: int = 200, degree: int = 5,
                    warm_start: TrajectoryResult | CollocationSolution | None = None, rigid_intervals: int = 60,
                    warm_options: dict | None = None, **common) -> tuple[CollocationSolution, list[dict]]:
    """The continuous minimum time: the rigid warm-up (unless warm-started) and the free-t_f flexible solve.

    What the calibration needs (t_f as a function of the parameters); :func:`solve_minimum_time`
    adds the whole-millisecond re-solve and the 1 ms sampling. ``common`` are the keyword
    arguments of :func:`flexarm.trajectory.problem.solve_collocation` (elbow, regularisation, ...);
    ``warm_options`` go to the flexible solve's (see there).

    Returns
    -------
    solution : CollocationSolution
        ``solution.t_f`` is the minimum time, s.
    stages : list of dict
        Solver statistics of each stage.
    """
    stages = []
    guess = warm_start.solution if isinstance(warm_start, TrajectoryResult) else warm_start
    if guess is None:
        rigid = solve_collocation(params, RIGID_GROUPS, rigid_intervals, 3, label="rigid two-link", **common)
        stages.append(rigid.stats)
        guess = rigid
    free = solve_collocation(params, FLEX_GROUPS, n_intervals, degree, guess=guess, label="flexible, t_f free",
                             warm_options=warm_options, **common)
    stages.append(free.stats)
    return free, stages


def solve_minimum_time(params: ArmParameters | None = None, n_intervals: int = 200, degree: int = 5,
                       warm_start: TrajectoryResult | CollocationSolution | None = None, verbose: bool = True,
                       elbow: int = 1, regularisation: float = DEFAULT_REGULARISATION,
                       rigid_intervals: int = 60, max_iter: int = 1000, line_tolerance: float = LINE_TOLERANCE,
                       torque_rate_limit: float | None = TORQUE_RATE_LIMIT) -> TrajectoryResult:
    """Solve the minimum-time slew and sample it every 1 ms.

    Parameters
    ----------
    params : ArmParameters, optional
        Default: the committed parameter file.
    n_intervals : int
        Collocation intervals of the flexible solve (t_f/N ≈ 10 ms at 200).
    degree : int
        Radau points per interval.
    warm_start : TrajectoryResult or CollocationSolution, optional
        A previous solution (e.g. for another payload); skips the rigid stage. A trajectory
        read from a file holds no solution: the solve is cold. Rebuilding one with
        :func:`flexarm.trajectory.warm.solution_from_trajectory` gives a primal point without
        multipliers, measured slower than a cold solve (docs/trajectory.md).
    verbose : bool
        Print progress (IPOPT every 10 iterations).
    elbow : {1, -1}
        Elbow branch (sign of q2).
    regularisation : float
        Weight (s) of the torque-rate term Σ|Δu|², u = τ/τ_limit, added to
        t_f; it picks one solution on singular arcs and costs far less than
        a millisecond of t_f.
    rigid_intervals : int
        Intervals of the rigid warm-up solve.
    max_iter : int
        IPOPT iteration limit per stage.

    Returns
    -------
    TrajectoryResult

    Raises
    ------
    TrajectoryError
        Any stage failed to converge.
    """
    params = params if params is not None else load_parameters()
    t_start = time.perf_counter()
    common = {"elbow": elbow, "regularisation": regularisation, "verbose": verbose, "max_iter": max_iter,
              "line_tolerance": line_tolerance, "torque_rate_limit": torque_rate_limit}
    # A re-plan (warm_start given) uses its own warm-start options and one BLAS thread; the cold
    # solve keeps exactly the settings that made the committed file (problem.blas_threads).
    replan = warm_start is not None
    with blas_threads(1) if replan else contextlib.nullcontext():
        free, stages = solve_free_time(params, n_intervals, degree, warm_start, rigid_intervals=rigid_intervals,
                                       warm_options=REPLAN_FREE_TIME_OPTIONS if replan else None, **common)
        t_ms = int(math.ceil(free.t_f / SAMPLE_TIME - 1e-9))
        fixed = solve_collocation(params, FLEX_GROUPS, n_intervals, degree, t_fixed=t_ms * SAMPLE_TIME, guess=free,
                                  label="flexible, t_f rounded up to whole ms",
                                  warm_options=REPLAN_FIXED_TIME_OPTIONS if replan else None, **common)
    stages.append(fixed.stats)
    return _result(params, free, fixed, stages, time.perf_counter() - t_start,
                   "IPOPT (CasADi nlpsol, exact Hessian, MUMPS)",
                   "Radau IIA direct collocation, implicit dynamics M(θ)a = rhs at every collocation point",
                   regularisation, elbow, line_tolerance, torque_rate_limit)


def replan_minimum_time(params: ArmParameters, warm_start: TrajectoryResult | CollocationSolution,
                        n_intervals: int | None = None, degree: int | None = None, verbose: bool = False,
                        elbow: int = 1, regularisation: float = DEFAULT_REGULARISATION,
                        max_iter: int = 300, line_tolerance: float = LINE_TOLERANCE,
                        torque_rate_limit: float = TORQUE_RATE_LIMIT, form=None) -> TrajectoryResult:
    """Re-plan the slew for changed parameters (a payload) with FATROP, from a solution's primal point alone.

    The same NLP as :func:`solve_minimum_time` in stage form (:mod:`flexarm.trajectory.stage_form`): the
    free-t_f solve, then t_f rounded up to a whole ms and solved again. It needs no multipliers, so a
    trajectory read from a file (the committed one) is a start. Each re-plan gets its own solver
    (:func:`flexarm.trajectory.stage_form.stage_form` says why none is kept: loaded from the compiled-solver cache
    in under a CPU-second, or made interpreted in about 10 without a C compiler), unless `form` gives one made
    for it.

    Parameters
    ----------
    params : ArmParameters
        The parameters to plan for (e.g. ``load_parameters().with_payload(0.275)``).
    warm_start : TrajectoryResult or CollocationSolution
        A flexible solution, or a trajectory file whose metadata name its grid (``discretisation``); the
        re-plan uses its grid (N intervals, Radau degree d).
    n_intervals, degree : int, optional
        The grid asked for; refused unless it is the start's (the re-plan does not regrid).
    verbose : bool
        Print a line per stage.
    form : StageForm, optional
        A solver made for this re-plan (:func:`flexarm.trajectory.stage_form.stage_form`, the same structure and
        options; used for this re-plan only).

    Returns
    -------
    TrajectoryResult

    Raises
    ------
    TrajectoryError
        FATROP did not converge, or the start is not a flexible solution with its grid.
    """
    from .stage_form import solve_stage_form, stage_form
    from .warm import solution_from_trajectory

    t_start = time.perf_counter()
    guess = warm_start
    if isinstance(warm_start, TrajectoryResult):
        guess = warm_start.solution if warm_start.solution is not None else solution_from_trajectory(warm_start,
                                                                                                     params)
    asked = (n_intervals or guess.n_intervals, degree or guess.degree)
    if asked != (guess.n_intervals, guess.degree):
        raise TrajectoryError(f"a re-plan keeps its start's grid (N = {guess.n_intervals}, d = {guess.degree}); "
                              f"asked for N = {asked[0]}, d = {asked[1]}: solve cold for another grid")
    if form is None:
        form = stage_form(params, guess.n_intervals, guess.degree, regularisation, torque_rate_limit, line_tolerance,
                          max_iter)
    with blas_threads(1):
        free = solve_stage_form(form, params, form.point(guess, params), elbow, label="flexible, t_f free")
        if verbose:
            print(f"[trajectory] re-plan, t_f free: {free.stats['iterations']} FATROP iterations, "
                  f"t_f = {free.t_f:.5f} s", flush=True)
        t_ms = int(math.ceil(free.t_f / SAMPLE_TIME - 1e-9))
        fixed = solve_stage_form(form, params, free.x, elbow, t_ms * SAMPLE_TIME,
                                 label="flexible, t_f rounded up to whole ms")
        if verbose:
            print(f"[trajectory] re-plan, t_f = {t_ms} ms: {fixed.stats['iterations']} FATROP iterations",
                  flush=True)
    return _result(params, free, fixed, [free.stats, fixed.stats], time.perf_counter() - t_start,
                   "FATROP (CasADi nlpsol, stage form, exact Hessian)",
                   "Radau IIA direct collocation in stage form: θ' and θ'' eliminated by the collocation's linear "
                   "maps in normalised time, dynamics M(θ)θ'' = t_f² rhs at every collocation point",
                   regularisation, elbow, line_tolerance, torque_rate_limit)


def solve_minimum_time_fatrop(params: ArmParameters | None = None, n_intervals: int = 200, degree: int = 5,
                              verbose: bool = False, elbow: int = 1, regularisation: float = DEFAULT_REGULARISATION,
                              rigid_intervals: int = 60, max_iter: int = 300, line_tolerance: float = LINE_TOLERANCE,
                              torque_rate_limit: float = TORQUE_RATE_LIMIT) -> TrajectoryResult:
    """The cold solve with FATROP: IPOPT's rigid warm-up, interpolated onto the flexible grid, then FATROP's two
    stages as in :func:`replan_minimum_time` (free t_f, then t_f rounded up to a whole ms).

    The same NLP as :func:`solve_minimum_time`, which made the committed file and reproduces it exactly; this one
    lands on it to the solvers' tolerance (``tests/test_trajectory_replan.py``) at a fraction of the CPU time
    (``benchmarks/bench_trajectory.py`` prints both). Parameters as :func:`solve_minimum_time`.

    Raises
    ------
    TrajectoryError
        A stage did not converge.
    """
    from .warm import flexible_guess

    params = params if params is not None else load_parameters()
    t_start = time.perf_counter()
    with blas_threads(1):
        rigid = solve_collocation(params, RIGID_GROUPS, rigid_intervals, 3, label="rigid two-link", elbow=elbow,
                                  regularisation=regularisation, verbose=verbose, max_iter=max_iter,
                                  line_tolerance=line_tolerance, torque_rate_limit=torque_rate_limit)
    result = replan_minimum_time(params, flexible_guess(rigid, n_intervals, degree), verbose=verbose, elbow=elbow,
                                 regularisation=regularisation, max_iter=max_iter, line_tolerance=line_tolerance,
                                 torque_rate_limit=torque_rate_limit)
    solver = result.metadata["solver"]
    solver.update(name=f"{solver['name']}, after IPOPT's rigid warm-up", stages=[rigid.stats, *solver["stages"]],
                  iterations=solver["iterations"] + rigid.stats["iterations"],
                  solve_time_s=time.perf_counter() - t_start)
    return result


def _result(params, free: CollocationSolution, fixed: CollocationSolution, stages: list[dict], total: float,
            solver: str, method: str, regularisation: float, elbow: int, line_tolerance: float,
            torque_rate_limit) -> TrajectoryResult:
    """The 1 ms trajectory of the whole-ms solution, with the solve's metadata."""
    result = sample_solution(params, fixed)
    result.metadata.update({
        "t_f_continuous_s": free.t_f,
        "solver": {"name": solver, "casadi": ca.__version__, "status": fixed.stats["status"],
                   "iterations": sum(s["iterations"] for s in stages),
                   "solve_time_s": total, "stages": stages},
        "discretisation": {
            "method": method,
            "intervals": fixed.n_intervals, "degree": fixed.degree, "interval_s": fixed.t_f / fixed.n_intervals,
            "model": "11 elements with rigid brackets (θ2=θ1, θ6=θ5, θ8=θ7): 8 angles",
            "torque": "piecewise linear, continuous; file holds its mean over each 1 ms step",
            "t_f_rounding": "free-t_f optimum rounded up to a whole ms, then re-solved with t_f fixed",
            "regularisation_s": regularisation, "elbow": elbow,
            "line_tolerance_m": line_tolerance, "torque_rate_limit_per_s": torque_rate_limit,
        },
    })
    return result


def sample_solution(params: ArmParameters, sol: CollocationSolution, dt: float = SAMPLE_TIME) -> TrajectoryResult:
    """1 ms samples of a fixed-t_f collocation solution (t_f a whole number of dt)."""
    n_steps = int(round(sol.t_f / dt))
    if abs(n_steps * dt - sol.t_f) > 1e-9:
        raise TrajectoryError(f"t_f = {sol.t_f} s is not a whole number of {dt} s steps")
    t = np.arange(n_steps + 1) * dt
    theta, omega = sol.sample(t)
    tau = np.vstack([sol.torque_samples(params.torque_limit, n_steps, dt), np.zeros((1, 2))])
    model = ArmModel(params)
    tip = np.array([model.tip_position(th) for th in theta])
    lim = params.torque_limit
    u = sol.u
    meta = {
        "t_f_s": float(t[-1]),
        "paper_t_f_s": PAPER_TF,
        "samples": int(n_steps),
        "sample_time_s": dt,
        "tau1_on_limit_fraction": float(np.mean(np.abs(tau[:-1, 0]) >= 0.99 * lim[0])),
        "tau2_on_limit_fraction": float(np.mean(np.abs(tau[:-1, 1]) >= 0.99 * lim[1])),
        "tau1_on_limit_fraction_nodes": float(np.mean(np.abs(u[:, 0]) >= 0.99)),
        "torque_limit_Nm": lim.tolist(),
        "payload_kg": float(params.payload_mass),
        "parameter_file": Path(params.source).name if params.source else "",
        "parameter_sha256": params.sha256,
        "line": {"start_m": params.line_start.tolist(), "end_m": params.line_end.tolist()},
        "commit": git_commit(),
        "command": _command_line(),
        "sampling": ("theta/omega: optimiser's collocation polynomials at t = k ms; tau[k]: mean optimal torque "
                     "over [t_k, t_k+1), held (zero-order hold); tau at t_f is 0"),
    }
    return TrajectoryResult(t=t, tau=tau, theta=theta, omega=omega, tip=tip, metadata=meta, solution=sol)


def _command_line() -> str:
    argv = sys.argv[:]
    if argv and argv[0].endswith("trajectory.py") or (argv and argv[0].endswith("__main__.py")):
        return " ".join(["python -m flexarm.trajectory"] + [shlex.quote(a) for a in argv[1:]])
    return " ".join(shlex.quote(a) for a in argv)


# -- sensitivity -----------------------------------------------------------------------
def sensitivity(base: TrajectoryResult, params: ArmParameters | None = None, change: float = 0.2,
                n_intervals: int | None = None, verbose: bool = False) -> list[dict]:
    """t_f when the elbow-stator mass and the joint-2 rotor inertia change by ±`change`.

    Parameter sets are rebuilt with :func:`flexarm.parameters.build_from_design`
    from the unknowns read back from `params`; each solve is warm-started from `base`.

    Returns
    -------
    list of dict
        One row per case: parameter, factor, t_f (continuous optimum, s), t_f
        of the file (whole ms), iterations, wall time.
    """
    from ..parameters import build_from_design, calibrated_unknowns, load_design

    params = params if params is not None else load_parameters()
    design = load_design()
    unknowns = calibrated_unknowns(params, design)
    rebuilt, _ = build_from_design(design, unknowns)
    for name in ("mass", "com", "inertia", "length"):
        if not np.allclose(getattr(rebuilt, name), getattr(params, name), rtol=1e-9, atol=1e-12):
            raise TrajectoryError(f"parameter file does not match the design rebuilt from its unknowns ({name})")
    n_int = n_intervals or base.metadata.get("discretisation", {}).get("intervals", 200)
    rows = []
    for key in ("stator_mass_kg", "rotor2_inertia_kgm2"):
        for factor in (1 - change, 1 + change):
            unk = dict(unknowns, **{key: unknowns[key] * factor})
            p, _ = build_from_design(design, unk)
            p = dataclasses.replace(p, payload_mass=params.payload_mass)
            t0 = time.perf_counter()
            r = solve_minimum_time(p, n_intervals=n_int, warm_start=base, verbose=verbose)
            rows.append({"parameter": key, "factor": factor, "value": unk[key],
                         "t_f_continuous_s": r.metadata["t_f_continuous_s"], "t_f_file_s": r.t_f,
                         "tau1_on_limit_fraction": r.metadata["tau1_on_limit_fraction"],
                         "iterations": r.metadata["solver"]["iterations"],
                         "wall_time_s": time.perf_counter() - t0})
            if verbose:
                print(f"[sensitivity] {key} x{factor:.2f}: t_f = {rows[-1]['t_f_continuous_s']:.4f} s", flush=True)
    return rows
