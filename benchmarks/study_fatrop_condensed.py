"""Study: FATROP on the condensed collocation NLP in stage form (issue 32 item 1; docs/trajectory.md).

The stage form of ``study_fatrop_stage_form.py`` had 141-wide stages (θ, θ̇, θ̈ at every collocation
point). Here θ̇ and θ̈ are eliminated as in ``study_condensed_replan.py`` (normalised time, dynamics times
t_f²): per interval k the state is x_k = [θ, θ' = t_f θ̇, u = τ/τ_limit at node k, t_f] (19) and the
control u_k = [θ at the d collocation points, the torque step to node k + 1] (42); the gap-closing
constraint is x_{k+1} = [θ at the last point, θ' there, u + step, t_f]; the d dynamics blocks (40
equalities), the line band and the rate limit are stage constraints. Started from the cold free-t_f
solution (primal point only; ``--cold-from FILE`` as written by ``study_condensed_replan.py``, else a
cold solve), it re-plans for ``--payload`` and prints the CPU time of making the solver, of the solve
and per iteration, the iterations and t_f.

    python benchmarks/study_fatrop_condensed.py [--payload KG] [--max-iter N] [--cold-from FILE] [--solver S]
"""

from __future__ import annotations

import argparse
import os
import pickle

import casadi as ca
import numpy as np

from flexarm import load_parameters
from flexarm.trajectory import problem as P
from flexarm.trajectory import stage_form as sf


def cpu() -> float:
    t = os.times()
    return t.user + t.system


def build(red, N: int, d: int):
    """The condensed stage-ordered NLP written out in one SX graph: (nlp, FATROP's dims, lbg, ubg).

    The intervals' equations are :mod:`flexarm.trajectory.stage_form`'s, inlined (what its module docstring
    calls the written-out layout).
    """
    base = load_parameters()
    nlp_mx, dims, lbg, ubg = sf.stage_nlp(base, N, d)
    n = red.n
    nx, nu = 2 * n + 3, n * d + 2
    n_p = nlp_mx["p"].shape[0]
    common = (P.DEFAULT_REGULARISATION, P.TORQUE_RATE_LIMIT, P.LINE_TOLERANCE)
    interval, _, _ = sf._interval_function(red, N, d, n_p, False, *common)
    last, _, _ = sf._interval_function(red, N, d, n_p, True, *common)
    w, p = ca.SX.sym("w", N * (nx + nu) + nx), ca.SX.sym("p", n_p)
    XU = ca.reshape(w[:N * (nx + nu)], nx + nu, N)
    X_next = ca.horzcat(XU[:nx, 1:], w[N * (nx + nu):])
    calls = [(last if k == N - 1 else interval).call([XU[:nx, k], XU[nx:, k], X_next[:, k], p], True, False)
             for k in range(N)]
    nlp = {"x": w, "p": p, "f": p[0] * w[2 * n + 2] + sum(c for _, c in calls),
           "g": ca.vertcat(*(g for g, _ in calls))}
    return nlp, dims, lbg, ubg


def _form(N: int, d: int) -> sf.StageForm:
    return sf.StageForm(None, N, d, P.ReducedModel.build(load_parameters(), P.FLEX_GROUPS).n, np.zeros(0),
                        np.zeros(0))


def params_vector(params, red) -> np.ndarray:
    return _form(1, 1).parameters(params)


def stage_vector(sol, red, N: int, d: int) -> np.ndarray:
    return _form(N, d).point(sol, load_parameters())


def bounds(params, red, N: int, d: int, elbow: int = 1):
    return _form(N, d).bounds(params, elbow)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--payload", type=float, default=0.275)
    ap.add_argument("--max-iter", type=int, default=300)
    ap.add_argument("--cold-from", help="pickle of the cold free-t_f CollocationSolution")
    ap.add_argument("--solver", choices=("fatrop", "ipopt"), default="fatrop")
    ap.add_argument("--mu-init", type=float, default=1e-4,
                    help="FATROP's / IPOPT's mu_init (FATROP's default 0.1 wanders off from this start)")
    args = ap.parse_args(argv)
    N, d = 200, 5
    base = load_parameters()
    red = P.ReducedModel.build(base, P.FLEX_GROUPS)
    if args.cold_from and os.path.exists(args.cold_from):
        with open(args.cold_from, "rb") as fh:
            cold = pickle.load(fh)
    else:
        from flexarm.trajectory.solve import solve_free_time

        cold, _ = solve_free_time(base, N, d, verbose=False)
    c = cpu()
    nlp, dims, lbg, ubg = build(red, N, d)
    x0 = stage_vector(cold, red, N, d)
    gf = ca.Function("g", [nlp["x"], nlp["p"]], [nlp["g"]])
    g0 = np.asarray(gf(x0, params_vector(base, red))).ravel()
    viol = np.maximum(np.maximum(lbg - g0, g0 - ubg), 0).max()
    print(f"condensed stage form: nx {dims['nx'][0]}, nu {dims['nu'][0]}, stage constraints {dims['ng'][0]}; "
          f"{nlp['x'].shape[0]} variables, {nlp['g'].shape[0]} constraints; the cold solution violates it by "
          f"{viol:.1e}; built in {cpu() - c:.1f} CPU-s", flush=True)
    c = cpu()
    if args.solver == "fatrop":
        fopts = {"max_iter": args.max_iter, "tol": 1e-8}
        if args.mu_init is not None:
            fopts["mu_init"] = args.mu_init
        solver = ca.nlpsol("slew", "fatrop", nlp, {"expand": True, "structure_detection": "manual", **dims,
                                                   "print_time": False, "fatrop": fopts})
    else:
        extra = {"mu_init": args.mu_init} if args.mu_init is not None else {}
        solver = ca.nlpsol("slew", "ipopt", nlp, P._ipopt_options(False, args.max_iter, 10, extra))
    print(f"{args.solver}: solver made in {cpu() - c:.1f} CPU-s", flush=True)
    loaded = base.with_payload(args.payload)
    lbx, ubx = bounds(loaded, red, N, d)
    with P.blas_threads(1):
        c = cpu()
        sol = solver(x0=np.clip(x0, lbx, ubx), lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg,
                     p=params_vector(loaded, P.ReducedModel.build(loaded, P.FLEX_GROUPS)))
        c = cpu() - c
    st = solver.stats()
    it = int(st.get("iter_count", 0))
    t_f = float(np.asarray(sol["x"]).ravel()[2 * red.n + 2])
    print(f"{args.solver}: {st.get('return_status')} after {it} iterations, {c:.1f} CPU-s "
          f"({c / max(it, 1):.3f} per iteration), t_f = {t_f:.7f} s", flush=True)
    if args.solver == "fatrop":
        f = st["fatrop"]
        print("fatrop's own split (wall-clock s): " + ", ".join(f"{k} {f[k]:.2f}" for k in (
            "compute_sd_time", "eval_hess_time", "eval_jac_time", "eval_cv_time", "time_total") if k in f),
            flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
