"""Study: how the stage-form NLP is laid out for CasADi's AD decides what FATROP's re-plan costs (issue 32 item 1).

The same NLP (``flexarm.trajectory.stage_form``; the script checks that g agrees between the layouts at the
committed solution), three ways:

* ``written-out``: every interval's equations in one SX graph (``study_fatrop_condensed.py``): symbolic AD
  of the whole graph, cheap to evaluate, dear to make;
* ``map``: one interval's SX function, ``Function.map`` over the intervals: cheap to make, but CasADi's AD
  takes one directional derivative per colour through the map;
* ``calls`` (adopted): one call node per interval with the Jacobian penalty set
  (``stage_form._with_interval_derivatives``): AD uses each interval's own symbolic Jacobian and Hessian.

Prints, per layout, the CPU time of making the Hessian of the Lagrangian and the constraint Jacobian and of
evaluating each (mean of 3).

    python benchmarks/study_fatrop_mapped.py [--skip-written-out]
"""

from __future__ import annotations

import argparse
import os

import casadi as ca
import numpy as np

from flexarm import load_parameters
from flexarm.trajectory import load_trajectory
from flexarm.trajectory import stage_form as sf
from flexarm.trajectory.problem import DEFAULT_REGULARISATION, LINE_TOLERANCE, TORQUE_RATE_LIMIT
from flexarm.trajectory.reduced_model import ReducedModel
from flexarm.trajectory.warm import solution_from_trajectory


def cpu() -> float:
    t = os.times()
    return t.user + t.system


def layout(kind: str, red, N: int, d: int, n_p: int):
    """(w, p, f, g) of the stage-form NLP in the given layout."""
    n = red.n
    nx, nu = 2 * n + 3, n * d + 2
    common = (DEFAULT_REGULARISATION, TORQUE_RATE_LIMIT, LINE_TOLERANCE)
    interval, _, _ = sf._interval_function(red, N, d, n_p, False, *common)
    last, _, _ = sf._interval_function(red, N, d, n_p, True, *common)
    sym = ca.SX.sym if kind == "written-out" else ca.MX.sym
    w, p = sym("w", N * (nx + nu) + nx), sym("p", n_p)
    XU = ca.reshape(w[:N * (nx + nu)], nx + nu, N)
    X, U = XU[:nx, :], XU[nx:, :]
    X_next = ca.horzcat(X[:, 1:], w[N * (nx + nu):])
    if kind == "map":
        plain = [ca.Function(f.name(), *(lambda i: (i, f.call(i)))([ca.SX.sym(f.name_in(j), f.sparsity_in(j))
                                                                       for j in range(4)]))
                 for f in (interval, last)]
        gm, cm = plain[0].map(N - 1, "serial")(X[:, :N - 1], U[:, :N - 1], X_next[:, :N - 1], p)
        gl, cl = plain[1](X[:, N - 1], U[:, N - 1], X_next[:, N - 1], p)
        return w, p, p[0] * w[2 * n + 2] + ca.sum2(cm) + cl, ca.vertcat(ca.vec(gm), gl)
    calls = [(last if k == N - 1 else interval).call([X[:, k], U[:, k], X_next[:, k], p],
                                                     kind == "written-out", False) for k in range(N)]
    return w, p, p[0] * w[2 * n + 2] + sum(c for _, c in calls), ca.vertcat(*(g for g, _ in calls))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--skip-written-out", action="store_true", help="skip the layout that takes ~30 CPU-s to make")
    args = ap.parse_args(argv)
    base = load_parameters()
    traj = load_trajectory()
    guess = solution_from_trajectory(traj, base)
    N, d = guess.n_intervals, guess.degree
    form = sf.StageForm(None, N, d, ReducedModel.build(base, sf.FLEX_GROUPS).n, np.zeros(0), np.zeros(0))
    x0, p0 = form.point(guess, base), form.parameters(base)
    red = ReducedModel.build(base, sf.FLEX_GROUPS)
    g_ref = None
    for kind in ("calls", "map") + (() if args.skip_written_out else ("written-out",)):
        w, p, f, g = layout(kind, red, N, d, p0.size)
        lam = (ca.SX if kind == "written-out" else ca.MX).sym("lam", g.shape[0])
        c = cpu()
        hess = ca.Function("hess_l", [w, p, lam], [ca.triu(ca.hessian(f + ca.dot(lam, g), w)[0])])
        jac = ca.Function("jac_g", [w, p], [ca.jacobian(g, w)])
        made = cpu() - c
        g_now = np.asarray(ca.Function("g", [w, p], [g])(x0, p0)).ravel()
        g_ref = g_now if g_ref is None else g_ref
        lam0 = np.random.default_rng(0).normal(size=g_now.size)
        c = cpu()
        for _ in range(3):
            hess(x0, p0, lam0)
        t_hess = (cpu() - c) / 3
        c = cpu()
        for _ in range(3):
            jac(x0, p0)
        t_jac = (cpu() - c) / 3
        print(f"{kind:12s} Hessian and Jacobian made in {made:5.1f} CPU-s; one Hessian {1e3 * t_hess:6.1f} ms, "
              f"one Jacobian {1e3 * t_jac:6.1f} ms (nonzeros {hess.sparsity_out(0).nnz()} / "
              f"{jac.sparsity_out(0).nnz()}); g against the first layout: {np.abs(g_now - g_ref).max():.1e}",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
