"""Study: IPOPT options of a warm re-plan, per stage (issue 32 item 1; docs/trajectory.md, re-planning speed).

Solves the committed problem cold (:func:`flexarm.trajectory.solve_minimum_time`, or ``--cold-from FILE``
written by an earlier run), then re-plans for ``--payload`` from its primal-dual solution with each option
set below: the free-t_f stage from the cold solution, and the whole-millisecond stage from the free-t_f
re-plan made with the adopted options. Prints per set the iterations, the CPU-s of the solve (the solver is
made beforehand and not counted) and the result (t_f, objective). CasADi's OpenBLAS runs on one thread,
as in a re-plan. ``--verbose`` prints IPOPT's iteration log (every iteration) of each solve.

    python benchmarks/study_replan_options.py [--payload KG] [--cold-from FILE] [--stage free|fixed|both]
"""

from __future__ import annotations

import argparse
import math
import os
import pickle

from flexarm import load_parameters
from flexarm.trajectory import problem as P
from flexarm.trajectory.io import SAMPLE_TIME

#: Option sets tried (the warm-start defaults are warm_start_init_point, bound pushes 1e-9, mu_init 1e-5).
FREE_SETS = {
    "committed warm start (mu_init 1e-5)": {},
    "mu_init 1e-3": {"mu_init": 1e-3},
    "mu_init 3e-4": {"mu_init": 3e-4},
    "mu_init 1e-4 (adopted)": {"mu_init": 1e-4},
    "mu_init 3e-5": {"mu_init": 3e-5},
    "mu_init 1e-6": {"mu_init": 1e-6},
    "bound pushes 1e-6": {"warm_start_bound_push": 1e-6, "warm_start_mult_bound_push": 1e-6},
    "mu_init 1e-4, pushes 1e-4": {"mu_init": 1e-4, "warm_start_bound_push": 1e-4,
                                  "warm_start_mult_bound_push": 1e-4},
    "mu_init 1e-4, mu_linear_decrease_factor 0.1": {"mu_init": 1e-4, "mu_linear_decrease_factor": 0.1},
    "mu_init 1e-4, barrier_tol_factor 100": {"mu_init": 1e-4, "barrier_tol_factor": 100},
    "mu_init 1e-4, nlp_scaling_method none": {"mu_init": 1e-4, "nlp_scaling_method": "none"},
    "bound_relax_factor 0": {"bound_relax_factor": 0.0},
    "mu_strategy adaptive": {"mu_strategy": "adaptive", "adaptive_mu_globalization": "never-monotone-mode"},
    "mu_init 1e-4, tol 1e-7": {"mu_init": 1e-4, "tol": 1e-7},
    "mu_init 1e-4, tol 1e-6": {"mu_init": 1e-4, "tol": 1e-6},
}
FIXED_SETS = {
    "committed warm start (mu_init 1e-5)": {},
    "mu_init 1e-3": {"mu_init": 1e-3},
    "mu_init 1e-4 (adopted)": {"mu_init": 1e-4},
    "mu_init 1e-6": {"mu_init": 1e-6},
    "mu_init 1e-7": {"mu_init": 1e-7},
    "mu_init 1e-8": {"mu_init": 1e-8},
    "mu_init 1e-4, barrier_tol_factor 100": {"mu_init": 1e-4, "barrier_tol_factor": 100},
}


def cpu() -> float:
    t = os.times()
    return t.user + t.system


def run(label, params, guess, t_fixed, options, verbose) -> P.CollocationSolution | None:
    red = P.ReducedModel.build(params, P.FLEX_GROUPS)
    opts = P._ipopt_options(verbose, 1000, 1)
    opts["ipopt"].update(warm_start_init_point="yes", warm_start_bound_push=1e-9, warm_start_mult_bound_push=1e-9,
                         mu_init=1e-5)
    opts["ipopt"].update(options)
    P._cached_solver(red, 200, 5, P.DEFAULT_REGULARISATION, P.TORQUE_RATE_LIMIT, opts)  # made, not counted
    c0 = cpu()
    try:
        sol = P.solve_collocation(params, P.FLEX_GROUPS, 200, 5, guess=guess, t_fixed=t_fixed, verbose=verbose,
                                  print_every=1, warm_options=options)
    except P.TrajectoryError as exc:
        print(f"  {label:45s} failed: {exc}", flush=True)
        return None
    c = cpu() - c0
    print(f"  {label:45s} {sol.stats['iterations']:4d} iterations {c:6.1f} CPU-s   t_f {sol.t_f:.9f} s, "
          f"objective {sol.stats['objective']:.10e}", flush=True)
    return sol


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--payload", type=float, default=0.275)
    ap.add_argument("--cold-from", help="pickle of the cold solve's CollocationSolution (written if absent)")
    ap.add_argument("--stage", choices=("free", "fixed", "both"), default="both")
    ap.add_argument("--verbose", action="store_true")
    args = ap.parse_args(argv)
    base = load_parameters()
    loaded = base.with_payload(args.payload)
    if args.cold_from and os.path.exists(args.cold_from):
        with open(args.cold_from, "rb") as fh:
            cold = pickle.load(fh)
    else:
        from flexarm.trajectory import solve_minimum_time

        cold = solve_minimum_time(base, verbose=False).solution
        if args.cold_from:
            with open(args.cold_from, "wb") as fh:
                pickle.dump(cold, fh)
    with P.blas_threads(1):
        if args.stage in ("free", "both"):
            print(f"free-t_f re-plan for {args.payload} kg from the cold solution:", flush=True)
            for label, options in FREE_SETS.items():
                run(label, loaded, cold, None, options, args.verbose)
        if args.stage in ("fixed", "both"):
            free = run("(adopted free-t_f re-plan, the guess below)", loaded, cold, None, P.REPLAN_FREE_TIME_OPTIONS,
                       args.verbose)
            t_ms = math.ceil(free.t_f / SAMPLE_TIME - 1e-9) * SAMPLE_TIME
            print(f"whole-ms re-plan (t_f {t_ms:.3f} s) from it:", flush=True)
            for label, options in FIXED_SETS.items():
                run(label, loaded, free, t_ms, options, args.verbose)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
