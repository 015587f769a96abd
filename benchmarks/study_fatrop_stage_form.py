"""Study: the flexible collocation NLP in FATROP's stage form (issue 32 item 1; docs/trajectory.md, re-planning).

The same discretisation as :mod:`flexarm.trajectory.problem` (Radau IIA collocation, implicit dynamics, the tip in
a band about the line, the torque's rate limit), with the variables ordered by interval as FATROP's manual
structure needs: per interval k the state x_k = [θ, θ̇, τ/τ_limit at node k, t_f] and the control
u_k = [θ, θ̇, θ̈ at the d collocation points, the torque step to node k + 1]; the gap-closing constraint is
x_{k+1} − F(x_k, u_k) (the last collocation point is the next node), and the collocation equations, the
dynamics, the line band and the rate limit are stage constraints. Started from the committed file's primal
point (:func:`flexarm.trajectory.warm.solution_from_trajectory`), it prints the CPU time of making the solver and
of the solve, FATROP's own time split and the iterations. IPOPT on the same stage-ordered NLP with ``--solver
ipopt``, for comparison.

    python benchmarks/study_fatrop_stage_form.py [--payload KG] [--max-iter N] [--solver fatrop|ipopt]
"""

from __future__ import annotations

import argparse
import os
import time

import casadi as ca
import numpy as np

from flexarm import load_parameters
from flexarm.model import rigid_configuration
from flexarm.trajectory import load_trajectory
from flexarm.trajectory import problem as P
from flexarm.trajectory.geometry import inverse_kinematics
from flexarm.trajectory.reduced_model import _radau, _residual_function
from flexarm.trajectory.warm import solution_from_trajectory


def cpu() -> float:
    t = os.times()
    return t.user + t.system


def build(red, N: int, d: int, reg: float = P.DEFAULT_REGULARISATION, rate: float = P.TORQUE_RATE_LIMIT,
          line_tol: float = P.LINE_TOLERANCE):
    """The stage-ordered NLP: (nlp dict, FATROP's N/nx/nu/ng, lbg, ubg); parameters as :func:`params_vector`."""
    n = red.n
    tau_c, D = _radau(d)
    pattern = red.stiffness_pattern()
    n_c = n * n + int(pattern.sum()) + 2 * n
    p = ca.SX.sym("p", 1 + n_c + 2 + n + 4)  # w_tf, model coefficients, torque limits, lengths, line start, normal
    w_tf, coeff, lim = p[0], p[1:1 + n_c], p[1 + n_c:3 + n_c]
    lg, p0, normal = p[3 + n_c:3 + n_c + n], p[3 + n_c + n:5 + n_c + n], p[5 + n_c + n:7 + n_c + n]
    dyn = _residual_function(n, pattern)
    nx, nu = 2 * n + 3, 3 * n * d + 2
    X = [ca.SX.sym(f"x{k}", nx) for k in range(N + 1)]
    U = [ca.SX.sym(f"u{k}", nu) for k in range(N)]
    w, g, lbg, ubg, ng = [], [], [], [], []
    f = w_tf * X[0][2 * n + 2]
    for k in range(N):
        x, u = X[k], U[k]
        th, om, u_node, t_f = x[:n], x[n:2 * n], x[2 * n:2 * n + 2], x[2 * n + 2]
        TH, OM = ca.reshape(u[:n * d], n, d), ca.reshape(u[n * d:2 * n * d], n, d)
        AC, du = ca.reshape(u[2 * n * d:3 * n * d], n, d), u[3 * n * d:]
        h = t_f / N
        w += [x, u]
        # gap closing, as FATROP needs it: x_{k+1} - F(x_k, u_k)
        g.append(X[k + 1] - ca.vertcat(TH[:, d - 1], OM[:, d - 1], u_node + du, t_f))
        lbg += [0.0] * nx
        ubg += [0.0] * nx
        path, lo, hi = [], [], []
        for j in range(d):
            dth = D[0, j] * th + sum(D[r, j] * TH[:, r - 1] for r in range(1, d + 1))
            dom = D[0, j] * om + sum(D[r, j] * OM[:, r - 1] for r in range(1, d + 1))
            path += [dth - h * OM[:, j], dom - h * AC[:, j]]
            lo += [0.0] * 2 * n
            hi += [0.0] * 2 * n
        for j in range(d):
            torque = lim * (u_node * (1 - tau_c[j + 1]) + (u_node + du) * tau_c[j + 1])
            path.append(dyn(TH[:, j], OM[:, j], AC[:, j], torque, coeff))
            lo += [0.0] * n
            hi += [0.0] * n
        for j in range(d if k < N - 1 else d - 1):  # the end point is imposed by bounds
            tip_x, tip_y = ca.dot(lg, ca.cos(TH[:, j])), ca.dot(lg, ca.sin(TH[:, j]))
            path.append(normal[0] * (tip_x - p0[0]) + normal[1] * (tip_y - p0[1]))
            lo.append(-line_tol)
            hi.append(line_tol)
        path += [du - rate * h, -du - rate * h]
        lo += [-np.inf] * 4
        hi += [0.0] * 4
        if k == N - 1:  # zero final joint accelerations
            path.append(ca.DM(red.joint_rows) @ AC[:, d - 1])
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
    """The NLP's parameters for `params` (free end time)."""
    dvec = (params.line_end - params.line_start) / np.linalg.norm(params.line_end - params.line_start)
    return np.concatenate([[1.0], red.coefficient_vector(), params.torque_limit, red.T.T @ red.length,
                           params.line_start, [-dvec[1], dvec[0]]])


def stage_vector(sol, red, N: int, d: int) -> np.ndarray:
    """A :class:`flexarm.trajectory.problem.CollocationSolution` as the stage-ordered primal vector."""
    th, om, ac = red.reduce(sol.theta), red.reduce(sol.omega), red.reduce(sol.alpha)
    w = []
    for k in range(N):
        node, rows = k * d, slice(1 + k * d, 1 + (k + 1) * d)
        w += [th[node], om[node], sol.u[k], [sol.t_f]]
        w += [th[rows].T.ravel("F"), om[rows].T.ravel("F"), ac[rows].T.ravel("F"), sol.u[k + 1] - sol.u[k]]
    w += [th[N * d], om[N * d], sol.u[N], [sol.t_f]]
    return np.concatenate(w)


def bounds(params, red, N: int, d: int, elbow: int = 1):
    """Bounds of the stage-ordered vector: start and end at rest on the line's ends, torque limits, t_f."""
    n = red.n
    nx, nu = 2 * n + 3, 3 * n * d + 2
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
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--payload", type=float, default=0.275, help="tip payload of the re-plan, kg")
    ap.add_argument("--max-iter", type=int, default=200)
    ap.add_argument("--solver", choices=("fatrop", "ipopt"), default="fatrop")
    args = ap.parse_args(argv)
    N, d = 200, 5
    params = load_parameters()
    red = P.ReducedModel.build(params, P.FLEX_GROUPS)
    guess = solution_from_trajectory(load_trajectory(), params)
    c = cpu()
    nlp, dims, lbg, ubg = build(red, N, d)
    print(f"stage form: N {N}, nx {dims['nx'][0]}, nu {dims['nu'][0]}, stage constraints {dims['ng'][0]}; "
          f"{nlp['x'].shape[0]} variables, {nlp['g'].shape[0]} constraints; built in {cpu() - c:.1f} CPU-s",
          flush=True)
    c = cpu()
    if args.solver == "fatrop":
        solver = ca.nlpsol("slew", "fatrop", nlp, {"expand": True, "structure_detection": "manual", **dims,
                                                   "print_time": False,
                                                   "fatrop": {"max_iter": args.max_iter, "tol": 1e-8}})
    else:
        solver = ca.nlpsol("slew", "ipopt", nlp, P._ipopt_options(True, args.max_iter, 10))
    print(f"{args.solver}: solver made in {cpu() - c:.1f} CPU-s", flush=True)
    loaded = params.with_payload(args.payload)
    red_loaded = P.ReducedModel.build(loaded, P.FLEX_GROUPS)  # the same structure, the payload's coefficients
    lbx, ubx = bounds(loaded, red, N, d)
    c, w = cpu(), time.perf_counter()
    sol = solver(x0=np.clip(stage_vector(guess, red, N, d), lbx, ubx), lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg,
                 p=params_vector(loaded, red_loaded))
    st = solver.stats()
    t_f = float(np.asarray(sol["x"]).ravel()[2 * red.n + 2])
    print(f"{args.solver}: {st.get('return_status')} after {st.get('iter_count')} iterations, {cpu() - c:.1f} CPU-s "
          f"(wall {time.perf_counter() - w:.1f} s), t_f = {t_f:.5f} s", flush=True)
    if args.solver == "fatrop":
        f = st["fatrop"]
        print("fatrop's own split (wall-clock s): " + ", ".join(f"{k} {f[k]:.2f}" for k in (
            "compute_sd_time", "eval_hess_time", "eval_jac_time", "initialization_time", "time_total")))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
