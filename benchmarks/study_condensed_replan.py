"""Study: the condensed collocation NLP, scaled to normalised time, for a warm re-plan (issue 32 item 1).

The NLP of :mod:`flexarm.trajectory.problem` has θ, θ̇ and θ̈ at every collocation point as variables and
the collocation equations as constraints; MUMPS then factorises a dense block of about 250 rows per
interval. Here θ̇ and θ̈ are eliminated by the collocation's linear maps, in normalised time s = t/t_f
(θ' = dθ/ds = t_f θ̇, θ'' = t_f² θ̈, all O(1) to O(100)):

* variables: θ at the collocation points, θ' at the nodes 1..N (V), the node torques u = τ/τ_limit, t_f;
* inside interval k: θ'_j = N Σ_r D[r, j] θ_r (θ_0 the interval's start) and θ''_j = N Σ_r D[r, j] θ'_r
  (θ'_0 = V_k, the start node's rate; V_0 = 0);
* constraints: V_{k+1} = θ' at the interval's end, the dynamics times t_f²
  (M(θ)θ'' + C(θ)θ'² + t_f²(K(θ)1 − B̄τ) = 0, so every term is O(1) to O(100) N·m·s² instead of
  the h² = 1e-4 scaling the first try used), the line band, the final joint accelerations (times t_f²)
  and the rate limit, as in the full NLP.

The same optimum (the condensed equations are the full ones with θ̇, θ̈ substituted), so the full NLP's
primal-dual solution maps into it: θ, u, t_f as they are, V = t_f θ̇ at the nodes, the dynamics' and final
acceleration's multipliers divided by t_f², the node-rate rows' multipliers from stationarity in V. The
script solves the full NLP cold (the committed file's first two stages, or ``--cold-from FILE`` saved by
an earlier run), maps its free-t_f solution, then re-plans for the payload in both NLPs from the same
point with the same IPOPT options and prints build CPU-s, iterations, CPU-s per iteration and t_f.

    python benchmarks/study_condensed_replan.py [--payload KG] [--mu-init MU] [--cold-from FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
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


def condensed_nlp(red, N: int, d: int, reg: float = P.DEFAULT_REGULARISATION, rate: float = P.TORQUE_RATE_LIMIT):
    """The condensed NLP (MX; parameters as :func:`flexarm.trajectory.problem.nlp_parameters`).

    Returns (nlp, counts) with counts = n_v (node-rate rows), n_dyn, n_line, n_rate, n_g.
    """
    n = red.n
    M = N * d
    tau_c, D = _radau(d)
    pattern = red.stiffness_pattern()
    n_k = int(pattern.sum())
    n_c = n * n + n_k + 2 * n
    P_ = ca.MX.sym("p", 1 + n_c + 2 + n + n + 4)
    w_tf = P_[0]
    coeff = P_[1:1 + n_c]
    lim = P_[1 + n_c:3 + n_c]
    th0 = P_[3 + n_c:3 + n_c + n]
    lg = P_[3 + n_c + n:3 + n_c + 2 * n]
    p0 = P_[3 + n_c + 2 * n:5 + n_c + 2 * n]
    normal = P_[5 + n_c + 2 * n:7 + n_c + 2 * n]
    TH = ca.MX.sym("TH", n, M)
    V = ca.MX.sym("V", n, N)  # θ' at nodes 1..N
    U = ca.MX.sym("U", 2, N + 1)
    tf = ca.MX.sym("tf")
    last = list(range(d - 1, M, d))
    th_start = ca.horzcat(th0, TH[:, last[:-1]])
    v_start = ca.horzcat(ca.DM.zeros(n, 1), V[:, :-1])
    cols = [list(range(r - 1, M, d)) for r in range(1, d + 1)]  # point r of every interval
    # θ' at point j of every interval (n x N each)
    dth = [N * (D[0, j] * th_start + sum(D[r, j] * TH[:, cols[r - 1]] for r in range(1, d + 1))) for j in range(d)]
    ddth = [N * (D[0, j] * v_start + sum(D[r, j] * dth[r - 1] for r in range(1, d + 1))) for j in range(d)]
    # interleave back to column order k*d + j
    OMs = ca.MX.zeros(n, M)
    ACs = ca.MX.zeros(n, M)
    for j in range(d):
        OMs[:, cols[j]] = dth[j]
        ACs[:, cols[j]] = ddth[j]
    w = np.tile(tau_c[1:], N)
    kk = np.repeat(np.arange(N), d)
    Ucol = U[:, list(kk)] * ca.repmat(ca.DM(1 - w).T, 2, 1) + U[:, list(kk + 1)] * ca.repmat(ca.DM(w).T, 2, 1)
    tf2 = tf ** 2
    Tcol = ca.repmat(lim * tf2, 1, M) * Ucol
    coeff2 = ca.vertcat(coeff[:n * n], tf2 * coeff[n * n:n * n + n_k], coeff[n * n + n_k:])
    dyn = _residual_function(n, pattern).map(M)
    cons = [V - dth[d - 1]]
    cons.append(dyn(TH, OMs, ACs, Tcol, ca.repmat(coeff2, 1, M)))
    thl = TH[:, : M - 1]
    tip_x = ca.mtimes(lg.T, ca.cos(thl))
    tip_y = ca.mtimes(lg.T, ca.sin(thl))
    cons.append(normal[0] * (tip_x - p0[0]) + normal[1] * (tip_y - p0[1]))
    cons.append(ca.DM(red.joint_rows) @ ACs[:, M - 1])
    dU = U[:, 1:] - U[:, :-1]
    h = tf / N
    cons += [ca.vec(dU) - rate * h, -ca.vec(dU) - rate * h]
    g = ca.vertcat(*[ca.vec(c) for c in cons])
    x = ca.vertcat(ca.vec(TH), ca.vec(V), ca.vec(U), tf)
    f = w_tf * tf + reg * ca.sumsqr(dU)
    return {"x": x, "f": f, "g": g, "p": P_}, (n * N, n * M, M - 1, 4 * N, int(g.shape[0]))


def expanded_solver(nlp: dict, opts: dict, expand: bool = True):
    """IPOPT on the NLP expanded to SX, as problem._cached_solver makes it (or on the MX NLP)."""
    if not expand:
        return ca.nlpsol("condensed", "ipopt", nlp, {**opts, "expand": False})
    f = ca.Function("nlp", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]]).expand()
    x, p = ca.SX.sym("x", f.size1_in(0)), ca.SX.sym("p", f.size1_in(1))
    fx, gx = f(x, p)
    solver = ca.nlpsol("condensed", "ipopt", {"x": x, "p": p, "f": fx, "g": gx}, {**opts, "expand": False})
    return solver


def map_solution(full: P.CollocationSolution, red, N: int, d: int, counts, grad_lag) -> tuple:
    """Primal-dual point of the condensed NLP from the full NLP's (x, lam_x, lam_g)."""
    n, M = red.n, N * d
    nxs = n * M
    xs, lx, lgf = full.x, full.lam_x, full.lam_g
    tf = xs[-1]
    TH = xs[:nxs]
    OM = xs[nxs:2 * nxs].reshape(n, M, order="F")
    V = (tf * OM[:, d - 1::d]).ravel("F")
    u = xs[3 * nxs:3 * nxs + 2 * (N + 1)]
    x = np.concatenate([TH, V, u, [tf]])
    n_v, n_dyn, n_line, n_rate, n_g = counts
    # full g: 2 d (n x N) collocation blocks, dynamics (n M), line (M - 1), final acceleration (2), rate (4 N)
    i0 = 2 * d * n * N
    lam_dyn = lgf[i0:i0 + n_dyn] / tf ** 2
    lam_line = lgf[i0 + n_dyn:i0 + n_dyn + n_line]
    lam_acc = lgf[i0 + n_dyn + n_line:i0 + n_dyn + n_line + 2] / tf ** 2
    lam_rate = lgf[i0 + n_dyn + n_line + 2:]
    lam_g = np.concatenate([np.zeros(n_v), lam_dyn, lam_line, lam_acc, lam_rate])
    lam_x = np.zeros_like(x)
    lam_x[nxs + n_v:nxs + n_v + 2 * (N + 1)] = lx[3 * nxs:3 * nxs + 2 * (N + 1)]
    # node-rate rows: ∂c/∂V = I, so their multipliers make the Lagrangian stationary in V
    gl = np.asarray(grad_lag(x, lam_g)).ravel()
    lam_g[:n_v] = -gl[nxs:nxs + n_v]
    gl = np.asarray(grad_lag(x, lam_g)).ravel()
    # the last node's rate is fixed (rest at t_f): its row's multiplier is what makes the last interval's
    # free angles stationary (least squares over them; the row is V_N - N Σ_r D[r, d] θ_r)
    _, D = _radau(d)
    w = -N * D[:d, d - 1]  # ∂(row)/∂θ at the interval's start and its first d - 1 points
    R = gl[:nxs].reshape(n, M, order="F")[:, M - d - 1:M - 1]
    lam_g[n_v - n:n_v] += -(R @ w) / (w @ w)
    gl = np.asarray(grad_lag(x, lam_g)).ravel()
    # variables fixed by bounds (final angles, final rate): their bound multipliers absorb the rest
    fixed = np.zeros_like(x, dtype=bool)
    fixed[n * (M - 1):n * M] = True
    fixed[nxs + n_v - n:nxs + n_v] = True
    lam_x[fixed] = -gl[fixed]
    return x, lam_x, lam_g


def bounds(params, red, N, d, counts, t_fixed=None):
    n, M = red.n, N * d
    nxs = n * M
    n_v, n_dyn, n_line, n_rate, n_g = counts
    n_x = nxs + n_v + 2 * (N + 1) + 1
    thf = red.reduce(rigid_configuration(*inverse_kinematics(params, params.line_end, 1)))
    lbx, ubx = np.full(n_x, -np.inf), np.full(n_x, np.inf)
    lbx[n * (M - 1):n * M] = ubx[n * (M - 1):n * M] = thf
    lbx[nxs + n_v - n:nxs + n_v] = ubx[nxs + n_v - n:nxs + n_v] = 0.0
    lbx[nxs + n_v:nxs + n_v + 2 * (N + 1)], ubx[nxs + n_v:nxs + n_v + 2 * (N + 1)] = -1.0, 1.0
    if t_fixed is None:
        lbx[-1], ubx[-1] = 0.05, 60.0
    else:
        lbx[-1] = ubx[-1] = t_fixed
    lbg, ubg = np.zeros(n_g), np.zeros(n_g)
    i = n_v + n_dyn
    lbg[i:i + n_line], ubg[i:i + n_line] = -P.LINE_TOLERANCE, P.LINE_TOLERANCE
    lbg[i + n_line + 2:] = -np.inf
    return lbx, ubx, lbg, ubg


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--payload", type=float, default=0.275)
    ap.add_argument("--mu-init", type=float, default=1e-4)
    ap.add_argument("--cold-from", help="pickle of the cold free-t_f CollocationSolution (written if absent)")
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--mx", action="store_true", help="the condensed NLP in MX, not expanded to SX")
    ap.add_argument("--skip-full", action="store_true", help="re-plan only in the condensed NLP")
    args = ap.parse_args(argv)
    N, d = 200, 5
    base = load_parameters()
    loaded = base.with_payload(args.payload)
    red = P.ReducedModel.build(base, P.FLEX_GROUPS)
    if args.cold_from and os.path.exists(args.cold_from):
        with open(args.cold_from, "rb") as fh:
            cold = pickle.load(fh)
    else:
        from flexarm.trajectory.solve import solve_free_time

        c0 = cpu()
        cold, _ = solve_free_time(base, N, d, verbose=False)
        print(f"cold free-t_f solve (full NLP): {cpu() - c0:.1f} CPU-s, t_f {cold.t_f:.7f} s", flush=True)
        if args.cold_from:
            with open(args.cold_from, "wb") as fh:
                pickle.dump(cold, fh)
    warm = {"warm_start_init_point": "yes", "warm_start_bound_push": 1e-9, "warm_start_mult_bound_push": 1e-9,
            "mu_init": args.mu_init}
    opts = P._ipopt_options(args.verbose, 1000, 1, warm)
    opts["ipopt"]["print_timing_statistics"] = "no"
    th0 = red.reduce(rigid_configuration(*inverse_kinematics(base, base.line_start, 1)))

    c0 = cpu()
    nlp, counts = condensed_nlp(red, N, d)
    solver = expanded_solver(nlp, opts, expand=not args.mx)
    build = cpu() - c0
    x_sym, p_sym = ca.MX.sym("x", nlp["x"].shape[0]), ca.MX.sym("p", nlp["p"].shape[0])
    lam = ca.MX.sym("lam", nlp["g"].shape[0])
    lag = ca.Function("lag", [nlp["x"], nlp["p"], lam], [nlp["f"] + ca.dot(lam, nlp["g"])])
    glag = ca.Function("glag", [x_sym, p_sym, lam], [ca.gradient(lag(x_sym, p_sym, lam), x_sym)]).expand()
    p_base = P.nlp_parameters(base, red, th0, free_time=True)
    p_new = P.nlp_parameters(loaded, P.ReducedModel.build(loaded, P.FLEX_GROUPS), th0, free_time=True)
    x0, lx0, lg0 = map_solution(cold, red, N, d, counts, lambda x, lg: glag(x, p_base, lg))
    lbx, ubx, lbg, ubg = bounds(base, red, N, d, counts)
    gfun = ca.Function("g", [nlp["x"], nlp["p"]], [nlp["g"]])
    g0 = np.asarray(gfun(x0, p_base)).ravel()
    viol = np.maximum(np.maximum(lbg - g0, g0 - ubg), 0.0)
    stat = np.asarray(glag(x0, p_base, lg0)).ravel() + lx0
    kind = "MX" if args.mx else "SX"
    print(f"condensed NLP: {nlp['x'].shape[0]} variables, {counts[-1]} constraints, built ({kind}) "
          f"in {build:.1f} CPU-s; "
          f"the full NLP's cold solution mapped into it: constraint violation {viol.max():.1e}, "
          f"stationarity {np.abs(stat).max():.1e}", flush=True)

    c0 = cpu()
    sol = solver(x0=np.clip(x0, lbx, ubx), lam_x0=lx0, lam_g0=lg0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg, p=p_new)
    c = cpu() - c0
    st = solver.stats()
    it = st["iter_count"]
    fev = sum(v for k, v in st.items() if k.startswith("t_proc_nlp"))
    print(f"condensed re-plan {args.payload} kg (mu_init {args.mu_init:g}): {st['return_status']}, {it} iterations, "
          f"{c:.1f} CPU-s ({c / max(it, 1):.3f} per iteration, of which function evaluations "
          f"{fev / max(it, 1):.3f} s process time), t_f {float(sol['x'][-1]):.7f} s", flush=True)

    if not args.skip_full:
        c0 = cpu()
        fopts = P._ipopt_options(args.verbose, 1000, 1, warm)
        fopts["ipopt"]["print_timing_statistics"] = "no"
        fsolver, *_ = P._cached_solver(red, N, d, P.DEFAULT_REGULARISATION, P.TORQUE_RATE_LIMIT, fopts)
        fbuild = cpu() - c0
        c0 = cpu()
        full = P.solve_collocation(loaded, P.FLEX_GROUPS, N, d, guess=dataclasses.replace(cold), verbose=args.verbose,
                                   print_every=1, warm_options={"mu_init": args.mu_init},
                                   ipopt={"print_timing_statistics": "no"})
        c = cpu() - c0
        it = full.stats["iterations"]
        print(f"full NLP: built (SX) in {fbuild:.1f} CPU-s; re-plan: {it} iterations, {c:.1f} CPU-s "
              f"({c / max(it, 1):.3f} per iteration), t_f {full.t_f:.7f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
