"""Study: what making the flexible NLP's IPOPT solver costs, and what an iteration costs (issue 32 item 1).

Prints CPU time (os.times, this process: the machine is shared) of

* making the solver as :func:`flexarm.trajectory.problem._cached_solver` does (the NLP expanded to SX,
  exact Hessian and Jacobian made symbolically) and of a second solver with other (warm-start) options
  made from the first one's derivative functions;
* making it from the MX NLP without expanding (CasADi then differentiates the MX graph);
* saving the SX-built solver with CasADi's serialisation (``Function.save``), its file size, and loading
  it back (``Function.load``), as a re-plan in a fresh process would from a cache under build/;
* the first ``--iterations`` IPOPT iterations of the flexible free-t_f stage from the rigid stage's
  guess, per iteration, with each solver, and with CasADi's bundled OpenBLAS on its default thread count
  and on one thread (:func:`flexarm.trajectory.problem.blas_threads`); CasADi's own function-evaluation
  times are printed beside them, the rest is IPOPT and MUMPS.

    python benchmarks/study_replan_build.py [--iterations N] [--no-serialise]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import tempfile
from pathlib import Path

import casadi as ca

from flexarm import load_parameters
from flexarm.trajectory import problem as P

ROOT = Path(__file__).resolve().parents[1]


def cpu() -> float:
    t = os.times()
    return t.user + t.system


def iterate(label: str, params, rigid, iterations: int, solver_maker, threads=None) -> None:
    """Run the flexible free-t_f stage for `iterations` iterations with the solver solver_maker() returns."""
    orig = P._cached_solver
    made = {}

    def patched(red, N, d, reg, rate, opts):
        if "solver" not in made:
            made["solver"], made["counts"] = solver_maker(red, N, d, reg, rate, opts)
        return (made["solver"], *made["counts"])

    P._cached_solver = patched
    try:
        with P.blas_threads(threads) if threads else contextlib.nullcontext():
            c0 = cpu()
            try:
                P.solve_collocation(params, P.FLEX_GROUPS, 200, 5, guess=rigid, verbose=False, max_iter=iterations)
            except P.TrajectoryError:
                pass  # the iteration limit: expected
            total = cpu() - c0
    finally:
        P._cached_solver = orig
    st = made["solver"].stats()
    it = int(st["iter_count"])
    fev = sum(v for k, v in st.items() if k.startswith("t_proc_nlp"))
    print(f"  {label}: {it} iterations, {total / it:.3f} CPU-s per iteration "
          f"(of which CasADi function evaluations {fev / it:.3f} s of process time)", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=10)
    ap.add_argument("--no-serialise", action="store_true", help="skip the save/load figures (a ~600 MB file)")
    args = ap.parse_args(argv)
    params = load_parameters()
    red = P.ReducedModel.build(params, P.FLEX_GROUPS)
    N, d = 200, 5
    reg, rate = P.DEFAULT_REGULARISATION, P.TORQUE_RATE_LIMIT
    opts = P._ipopt_options(False, args.iterations, 10)
    warm_opts = P._ipopt_options(False, args.iterations, 10, {"warm_start_init_point": "yes", "mu_init": 1e-5})

    P._NLP_CACHE.clear()
    c0 = cpu()
    sx_solver, *counts = P._cached_solver(red, N, d, reg, rate, opts)
    print(f"SX (expand=True, as committed): NLP and first solver {cpu() - c0:.1f} CPU-s", flush=True)
    c0 = cpu()
    P._cached_solver(red, N, d, reg, rate, warm_opts)
    print(f"  second solver (warm-start options) from the first one's derivatives: {cpu() - c0:.1f} CPU-s", flush=True)

    c0 = cpu()
    nlp, *mx_counts = P.nlp_expressions(red, N, d, reg, rate)
    mx_solver = ca.nlpsol("slew", "ipopt", nlp, {**opts, "expand": False})
    print(f"MX (expand=False): solver {cpu() - c0:.1f} CPU-s", flush=True)

    if not args.no_serialise:
        cache = ROOT / "build" / "solver-cache"
        cache.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=cache) as tmp:
            path = Path(tmp) / "slew.casadi"
            c0 = cpu()
            sx_solver.save(str(path))
            saved = cpu() - c0
            size = path.stat().st_size / 1e6
            c0 = cpu()
            ca.Function.load(str(path))
            print(f"CasADi serialisation of the SX solver: save {saved:.1f} CPU-s, {size:.0f} MB, "
                  f"load {cpu() - c0:.1f} CPU-s", flush=True)

    rigid = P.solve_collocation(params, P.RIGID_GROUPS, 60, 3, verbose=False)
    print(f"per iteration, the first {args.iterations} iterations of the flexible free-t_f stage:", flush=True)
    iterate("SX, default BLAS threads", params, rigid, args.iterations, lambda *a: (sx_solver, counts))
    iterate("SX, one BLAS thread", params, rigid, args.iterations, lambda *a: (sx_solver, counts), threads=1)
    iterate("MX, one BLAS thread", params, rigid, args.iterations, lambda *a: (mx_solver, mx_counts), threads=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
