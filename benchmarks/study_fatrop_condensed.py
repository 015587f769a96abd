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
from flexarm.model import rigid_configuration
from flexarm.trajectory import problem as P
from flexarm.trajectory.geometry import inverse_kinematics
from flexarm.trajectory.reduced_model import _radau, _residual_function


def cpu() -> float:
    t = os.times()
    return t.user + t.system


def build(red, N: int, d: int, reg: float = P.DEFAULT_REGULARISATION, rate: float = P.TORQUE_RATE_LIMIT,
          line_tol: float = P.LINE_TOLERANCE):
    """The condensed stage-ordered NLP: (nlp, FATROP's dims, lbg, ubg); parameters as params_vector."""
    n = red.n
    tau_c, D = _radau(d)
    pattern = red.stiffness_pattern()
    n_k = int(pattern.sum())
    n_c = n * n + n_k + 2 * n
    p = ca.SX.sym("p", 1 + n_c + 2 + n + 4)
    w_tf, coeff, lim = p[0], p[1:1 + n_c], p[1 + n_c:3 + n_c]
    lg, p0, normal = p[3 + n_c:3 + n_c + n], p[3 + n_c + n:5 + n_c + n], p[5 + n_c + n:7 + n_c + n]
    dyn = _residual_function(n, pattern)
    nx, nu = 2 * n + 3, n * d + 2
    X = [ca.SX.sym(f"x{k}", nx) for k in range(N + 1)]
    U = [ca.SX.sym(f"u{k}", nu) for k in range(N)]
    w, g, lbg, ubg, ng = [], [], [], [], []
    f = w_tf * X[0][2 * n + 2]
    for k in range(N):
        x, u = X[k], U[k]
        th, v, u_node, t_f = x[:n], x[n:2 * n], x[2 * n:2 * n + 2], x[2 * n + 2]
        TH, du = ca.reshape(u[:n * d], n, d), u[n * d:]
        t2 = t_f ** 2
        coeff2 = ca.vertcat(coeff[:n * n], t2 * coeff[n * n:n * n + n_k], coeff[n * n + n_k:])
        pts = [th] + [TH[:, r] for r in range(d)]
        dth = [N * sum(D[r, j] * pts[r] for r in range(d + 1)) for j in range(d)]
        rates = [v] + dth
        ddth = [N * sum(D[r, j] * rates[r] for r in range(d + 1)) for j in range(d)]
        w += [x, u]
        g.append(X[k + 1] - ca.vertcat(TH[:, d - 1], dth[d - 1], u_node + du, t_f))
        lbg += [0.0] * nx
        ubg += [0.0] * nx
        path, lo, hi = [], [], []
        for j in range(d):
            torque = t2 * lim * (u_node * (1 - tau_c[j + 1]) + (u_node + du) * tau_c[j + 1])
            path.append(dyn(TH[:, j], dth[j], ddth[j], torque, coeff2))
            lo += [0.0] * n
            hi += [0.0] * n
        for j in range(d if k < N - 1 else d - 1):
            tip_x, tip_y = ca.dot(lg, ca.cos(TH[:, j])), ca.dot(lg, ca.sin(TH[:, j]))
            path.append(normal[0] * (tip_x - p0[0]) + normal[1] * (tip_y - p0[1]))
            lo.append(-line_tol)
            hi.append(line_tol)
        h = t_f / N
        path += [du - rate * h, -du - rate * h]
        lo += [-np.inf] * 4
        hi += [0.0] * 4
        if k == N - 1:
            path.append(ca.DM(red.joint_rows) @ ddth[d - 1])
            lo += [0.0] * 2
            hi += [0.0] * 2
        g += path
        lbg += lo
        ubg += hi
        ng.append(len(lo))
        f += reg * ca.sumsqr(du)
    w.append(X[N])
    nlp = {"x": ca.vertcat(*w), "f": f, "g": ca.vertcat(*g), "p": p}
    dims = {"N": N, "nx": [nx] * (N + 1), "nu": [nu] * N + [0], "ng": ng + [0]}
    return nlp, dims, np.array(lbg), np.array(ubg)


def params_vector(params, red) -> np.ndarray:
    dvec = (params.line_end - params.line_start) / np.linalg.norm(params.line_end - params.line_start)
    return np.concatenate([[1.0], red.coefficient_vector(), params.torque_limit, red.T.T @ red.length,
                           params.line_start, [-dvec[1], dvec[0]]])


def stage_vector(sol, red, N: int, d: int) -> np.ndarray:
    th, om = red.reduce(sol.theta), red.reduce(sol.omega)
    w = []
    for k in range(N):
        node, rows = k * d, slice(1 + k * d, 1 + (k + 1) * d)
        w += [th[node], sol.t_f * om[node], sol.u[k], [sol.t_f], th[rows].T.ravel("F"), sol.u[k + 1] - sol.u[k]]
    w += [th[N * d], sol.t_f * om[N * d], sol.u[N], [sol.t_f]]
    return np.concatenate(w)


def bounds(params, red, N: int, d: int, elbow: int = 1):
    n = red.n
    nx, nu = 2 * n + 3, n * d + 2
    th0 = red.reduce(rigid_configuration(*inverse_kinematics(params, params.line_start, elbow)))
    thf = red.reduce(rigid_configuration(*inverse_kinematics(params, params.line_end, elbow)))
    lb, ub = [], []
    for k in range(N + 1):
        lo, hi = np.full(nx, -np.inf), np.full(nx, np.inf)
        lo[2 * n:2 * n + 2], hi[2 * n:2 * n + 2] = -1.0, 1.0
        lo[-1], hi[-1] = 0.05, 60.0
        for node, angles in ((0, th0), (N, thf)):
            if k == node:
                lo[:n] = hi[:n] = angles
                lo[n:2 * n] = hi[n:2 * n] = 0.0
        lb.append(lo)
        ub.append(hi)
        if k < N:
            lb.append(np.full(nu, -np.inf))
            ub.append(np.full(nu, np.inf))
    return np.concatenate(lb), np.concatenate(ub)


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
