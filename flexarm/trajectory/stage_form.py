"""The flexible minimum-time NLP in stage form, solved by FATROP: the re-plan for a payload (issue 32 item 1).

The same collocation problem as :mod:`flexarm.trajectory.problem` (Radau, degree d, N intervals, the 8-angle
flexible model, the line band, the torque-rate limit, the regulariser), with θ̇ and θ̈ eliminated by the
collocation's linear maps in normalised time (θ' = t_f θ̇, θ'' = t_f² θ̈; the dynamics multiplied by t_f²)
and ordered by interval, as FATROP's Riccati recursion needs it:

* state of interval k (19): θ and θ' at node k, u = τ/τ_limit at node k, t_f;
* control of interval k (42): θ at its d collocation points, the torque step u_{k+1} − u_k;
* per interval: the gap to the next state, then the d dynamics blocks, the line band at the points and
  the rate limit (the last interval: the band without its end point, and the joints' accelerations zero).

Why this and not IPOPT on the full NLP: the full NLP's KKT factorisation by MUMPS was 94 % of a re-plan
(docs/trajectory.md). FATROP's Riccati recursion on 19 + 42-wide stages is cheap, and FATROP needs no
multipliers to start near a solution: a re-plan starts from the committed file's primal point.

What makes it cheap to make: each interval is one call of a small SX function in an MX graph, with CasADi's
Jacobian penalty set so that its AD takes each interval's own symbolic Jacobian and Hessian
(:func:`_with_interval_derivatives`). Written out as one SX graph, making the derivatives cost 26 CPU-s of
symbolic AD; as a ``Function.map`` the AD took one directional derivative per colour through the map (a
Hessian 0.49 s, against 0.08 s here). ``benchmarks/study_fatrop_mapped.py`` prints the three. Compiled
(:mod:`flexarm.trajectory.compiled`), those interval functions and derivatives are C, and the made solver is cached.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..model import rigid_configuration
from ..parameters import ArmParameters
from .geometry import inverse_kinematics
from .io import TrajectoryError
from .problem import DEFAULT_REGULARISATION, FLEX_GROUPS, LINE_TOLERANCE, TORQUE_RATE_LIMIT, CollocationSolution
from .reduced_model import ReducedModel, _radau, _residual_function, collocation_times

#: FATROP's options for a re-plan. The barrier starts at 1e-4: from FATROP's default (0.1) a start near the
#: solution wanders off into restoration (benchmarks/study_fatrop_condensed.py).
FATROP_OPTIONS = {"mu_init": 1e-4, "tol": 1e-8, "print_level": 0}
#: FATROP return status of a solve that converged.
CONVERGED = 0


@dataclass(frozen=True)
class StageForm:
    """A made FATROP solver of the stage-form NLP and what its vectors mean.

    Attributes
    ----------
    solver : casadi.Function
        ``nlpsol`` (FATROP); parameters from :meth:`parameters`.
    N, d, n : int
        Intervals, Radau degree, reduced angles.
    lbg, ubg : ndarray
        Constraint bounds (fixed for every payload).
    """

    solver: ca.Function
    N: int
    d: int
    n: int
    lbg: np.ndarray
    ubg: np.ndarray

    @property
    def nx(self) -> int:
        return 2 * self.n + 3

    @property
    def nu(self) -> int:
        return self.n * self.d + 2

    def parameters(self, params: ArmParameters) -> np.ndarray:
        """The NLP's parameter vector for `params` (payload, coefficients, torque limits, geometry)."""
        red = ReducedModel.build(params, FLEX_GROUPS)
        direction = (params.line_end - params.line_start) / np.linalg.norm(params.line_end - params.line_start)
        return np.concatenate([[1.0], red.coefficient_vector(), params.torque_limit, red.T.T @ red.length,
                               params.line_start, [-direction[1], direction[0]]])

    def bounds(self, params: ArmParameters, elbow: int = 1, t_fixed: float | None = None):
        """(lbx, ubx): the end points at rest on the line's ends, |u| ≤ 1, t_f free in [0.05, 60] s or fixed."""
        n, N = self.n, self.N
        red = ReducedModel.build(params, FLEX_GROUPS)
        ends = [red.reduce(rigid_configuration(*inverse_kinematics(params, point, elbow)))
                for point in (params.line_start, params.line_end)]
        lb, ub = [], []
        for k in range(N + 1):
            lo, hi = np.full(self.nx, -np.inf), np.full(self.nx, np.inf)
            lo[2 * n:2 * n + 2], hi[2 * n:2 * n + 2] = -1.0, 1.0
            # t_f fixed at the first state only: the gaps carry it, and fixing it at every state too would make
            # N redundant equalities (a singular Riccati recursion: FATROP stalled at its first iteration)
            lo[-1], hi[-1] = (t_fixed, t_fixed) if t_fixed is not None and k == 0 else (0.05, 60.0)
            if k in (0, N):
                lo[:n] = hi[:n] = ends[0 if k == 0 else 1]
                lo[n:2 * n] = hi[n:2 * n] = 0.0
            lb.append(lo)
            ub.append(hi)
            if k < N:
                lb.append(np.full(self.nu, -np.inf))
                ub.append(np.full(self.nu, np.inf))
        return np.concatenate(lb), np.concatenate(ub)

    def point(self, sol: CollocationSolution, params: ArmParameters) -> np.ndarray:
        """The stage-form vector of a flexible collocation solution on the same grid."""
        if sol.groups != tuple(FLEX_GROUPS) or sol.n_intervals != self.N or sol.degree != self.d:
            raise TrajectoryError(f"a stage-form start needs the flexible model on N = {self.N}, d = {self.d}; "
                                  f"got groups {sol.groups}, N = {sol.n_intervals}, d = {sol.degree}")
        red = ReducedModel.build(params, FLEX_GROUPS)
        th, om = red.reduce(sol.theta), red.reduce(sol.omega)
        N, d = self.N, self.d
        w = []
        for k in range(N):
            node, rows = k * d, slice(1 + k * d, 1 + (k + 1) * d)
            w += [th[node], sol.t_f * om[node], sol.u[k], [sol.t_f], th[rows].T.ravel("F"), sol.u[k + 1] - sol.u[k]]
        w += [th[N * d], sol.t_f * om[N * d], sol.u[N], [sol.t_f]]
        return np.concatenate(w)

    def solution(self, x: np.ndarray, params: ArmParameters, stats: dict) -> CollocationSolution:
        """The :class:`CollocationSolution` (11 element angles, rates, accelerations) of a stage-form vector."""
        n, N, d, nx, nu = self.n, self.N, self.d, self.nx, self.nu
        _, D = _radau(d)
        XU = x[:N * (nx + nu)].reshape(N, nx + nu)
        t_f = float(XU[0, 2 * n + 2])
        theta, rate, accel = [XU[0, :n]], [XU[0, n:2 * n]], []
        for k in range(N):
            pts = [XU[k, :n]] + list(XU[k, nx:nx + n * d].reshape(d, n))
            dth = [N * sum(D[r, j] * pts[r] for r in range(d + 1)) for j in range(d)]
            rates = [XU[k, n:2 * n]] + dth
            accel += [N * sum(D[r, j] * rates[r] for r in range(d + 1)) for j in range(d)]
            theta += pts[1:]
            rate += dth
        red = ReducedModel.build(params, FLEX_GROUPS)
        u = np.vstack([XU[:, 2 * n:2 * n + 2], x[N * (nx + nu) + 2 * n:N * (nx + nu) + 2 * n + 2]])
        th0 = theta[0]  # node 0 at rest, undeformed: M a = B̄τ
        a0 = np.linalg.solve(red.mass_coefficients * np.cos(th0[:, None] - th0[None, :]),
                             red.input_matrix @ (u[0] * params.torque_limit))
        T = red.T
        s = collocation_times(N, d)
        return CollocationSolution(
            groups=red.groups, n_intervals=N, degree=d, t_f=t_f, s=s,
            theta=np.asarray(theta) @ T.T, omega=np.asarray(rate) @ T.T / t_f,
            alpha=np.vstack([a0 @ T.T, np.asarray(accel) @ T.T / t_f ** 2]), u=u, x=x,
            lam_x=None, lam_g=None, stats=stats)  # FATROP's multipliers are not the full NLP's (IPOPT)


def _interval_function(red: ReducedModel, N: int, d: int, n_p: int, last: bool, regularisation: float,
                       rate: float, line_tolerance: float):
    """One interval: (x, u, x_next, p) -> (g: the gap, then the interval's constraints; its cost); g's bounds."""
    n = red.n
    tau_c, D = _radau(d)
    pattern = red.stiffness_pattern()
    n_k = int(pattern.sum())
    n_c = n * n + n_k + 2 * n
    dyn = _residual_function(n, pattern)
    nx, nu = 2 * n + 3, n * d + 2
    x, u, xn, p = ca.SX.sym("x", nx), ca.SX.sym("u", nu), ca.SX.sym("xn", nx), ca.SX.sym("p", n_p)
    coeff, lim = p[1:1 + n_c], p[1 + n_c:3 + n_c]
    lg, p0, normal = p[3 + n_c:3 + n_c + n], p[3 + n_c + n:5 + n_c + n], p[5 + n_c + n:7 + n_c + n]
    th, v, u_node, t_f = x[:n], x[n:2 * n], x[2 * n:2 * n + 2], x[2 * n + 2]
    TH, du = ca.reshape(u[:n * d], n, d), u[n * d:]
    t2 = t_f ** 2
    coeff2 = ca.vertcat(coeff[:n * n], t2 * coeff[n * n:n * n + n_k], coeff[n * n + n_k:])
    pts = [th] + [TH[:, r] for r in range(d)]
    dth = [N * sum(D[r, j] * pts[r] for r in range(d + 1)) for j in range(d)]
    rates = [v] + dth
    ddth = [N * sum(D[r, j] * rates[r] for r in range(d + 1)) for j in range(d)]
    g = [xn - ca.vertcat(TH[:, d - 1], dth[d - 1], u_node + du, t_f)]
    lo, hi = [0.0] * nx, [0.0] * nx
    for j in range(d):
        torque = t2 * lim * (u_node * (1 - tau_c[j + 1]) + (u_node + du) * tau_c[j + 1])
        g.append(dyn(TH[:, j], dth[j], ddth[j], torque, coeff2))
        lo += [0.0] * n
        hi += [0.0] * n
    for j in range(d - 1 if last else d):  # the end point is fixed on the line by its bounds
        tip_x, tip_y = ca.dot(lg, ca.cos(TH[:, j])), ca.dot(lg, ca.sin(TH[:, j]))
        g.append(normal[0] * (tip_x - p0[0]) + normal[1] * (tip_y - p0[1]))
        lo.append(-line_tolerance)
        hi.append(line_tolerance)
    h = t_f / N
    g += [du - rate * h, -du - rate * h]
    lo += [-np.inf] * 4
    hi += [0.0] * 4
    if last:
        g.append(ca.DM(red.joint_rows) @ ddth[d - 1])
        lo += [0.0] * 2
        hi += [0.0] * 2
    f = ca.Function("last" if last else "interval", [x, u, xn, p], [ca.vertcat(*g), regularisation * ca.sumsqr(du)],
                    ["x", "u", "x_next", "p"], ["g", "cost"])
    return _with_interval_derivatives(f), np.array(lo), np.array(hi)


def _with_interval_derivatives(f: ca.Function) -> ca.Function:
    """`f` with CasADi's Jacobian penalty set so that AD through a call of it uses its whole symbolic Jacobian.

    A forward sweep with the Hessian's or the Jacobian's many colours then costs one evaluation of the
    interval's Jacobian, and (``reverse_options``) a forward sweep over the gradient one of the interval's
    Hessian, instead of one directional derivative per colour. 0.05: every multi-direction sweep uses the
    Jacobian, and the gradient's single reverse sweep stays a reverse sweep.
    """
    ins = [ca.SX.sym(f.name_in(i), f.sparsity_in(i)) for i in range(f.n_in())]
    return ca.Function(f.name(), ins, f.call(ins), f.name_in(), f.name_out(), INTERVAL_AD_OPTIONS)


#: How CasADi's AD treats a call of an interval function (:func:`_with_interval_derivatives`), interpreted or
#: compiled (:mod:`flexarm.trajectory.compiled`).
INTERVAL_AD_OPTIONS = {"jac_penalty": 0.05, "reverse_options": {"jac_penalty": 0.0},
                       "jacobian_options": {"jac_penalty": 0.0}}


def stage_form(params: ArmParameters, n_intervals: int = 200, degree: int = 5,
               regularisation: float = DEFAULT_REGULARISATION, torque_rate_limit: float = TORQUE_RATE_LIMIT,
               line_tolerance: float = LINE_TOLERANCE, max_iter: int = 300, compiled: bool = True) -> StageForm:
    """A FATROP solver of the stage-form NLP, for one re-plan (its two solves).

    The payload, the mass and stiffness coefficients, the torque limits and the line are parameters (``params`` only
    fixes the structure: the stiffness pattern). With `compiled` (and a C compiler) the interval functions are
    compiled to C and the made solver is cached (:mod:`flexarm.trajectory.compiled`): the first call on a machine
    compiles and makes it (about 40 CPU-s), later calls load it (under 1 CPU-s), and each solve evaluates the
    compiled derivatives. Otherwise CasADi's virtual machine evaluates them and each call makes the solver anew
    (about 10 CPU-s, N = 200, d = 5). The two give the same iterates to rounding. A solver serves one re-plan:
    FATROP keeps state between solves on one solver, and a re-plan for another payload on the solver of an earlier
    one stalled (0.275 kg, then 0.2 kg: not converged after 8 CPU-minutes, where a fresh solver takes 28 CPU-s).
    """
    from . import compiled as compiled_solvers

    N, d = int(n_intervals), int(degree)
    functions, dims, lbg, ubg, n = _stage_parts(params, N, d, regularisation, torque_rate_limit, line_tolerance)
    options = {"expand": False, "structure_detection": "manual", **dims, "print_time": False,
               "fatrop": {**FATROP_OPTIONS, "max_iter": int(max_iter)}}

    def make(interval_functions) -> ca.Function:
        return ca.nlpsol("replan", "fatrop", _stage_nlp(interval_functions, N, n), options)

    solver = None
    if compiled:
        solver = compiled_solvers.load_or_make("replan", functions, make, repr(sorted(options.items())),
                                               fixed_inputs=("p",), external_options=INTERVAL_AD_OPTIONS)
    return StageForm(make(functions) if solver is None else solver, N, d, n, lbg, ubg)


def _stage_parts(params: ArmParameters, N: int, d: int, regularisation: float, torque_rate_limit: float,
                 line_tolerance: float):
    """The interval functions (interval, last), FATROP's dimensions, the constraint bounds and the angle count."""
    red = ReducedModel.build(params, FLEX_GROUPS)
    n = red.n
    nx = 2 * n + 3
    n_p = 1 + len(red.coefficient_vector()) + 2 + n + 4
    common = (regularisation, torque_rate_limit, line_tolerance)
    interval, lo, hi = _interval_function(red, N, d, n_p, False, *common)
    last, lo_last, hi_last = _interval_function(red, N, d, n_p, True, *common)
    dims = {"N": N, "nx": [nx] * (N + 1), "nu": [n * d + 2] * N + [0],
            "ng": [len(lo) - nx] * (N - 1) + [len(lo_last) - nx, 0]}
    return ((interval, last), dims, np.concatenate([np.tile(lo, N - 1), lo_last]),
            np.concatenate([np.tile(hi, N - 1), hi_last]), n)


def _stage_nlp(functions, N: int, n: int) -> dict:
    """The stage-form NLP, an MX graph with one call of ``functions`` = (interval, last) per interval."""
    interval, last = functions
    nx, nu, n_p = interval.size1_in(0), interval.size1_in(1), interval.size1_in(3)
    w, p = ca.MX.sym("w", N * (nx + nu) + nx), ca.MX.sym("p", n_p)
    XU = ca.reshape(w[:N * (nx + nu)], nx + nu, N)
    X, U = XU[:nx, :], XU[nx:, :]
    X_next = ca.horzcat(X[:, 1:], w[N * (nx + nu):])
    calls = [(last if k == N - 1 else interval)(X[:, k], U[:, k], X_next[:, k], p) for k in range(N)]
    return {"x": w, "p": p, "f": p[0] * w[2 * n + 2] + sum(c for _, c in calls),
            "g": ca.vertcat(*(g for g, _ in calls))}


def stage_nlp(params: ArmParameters, n_intervals: int, degree: int, regularisation: float = DEFAULT_REGULARISATION,
              torque_rate_limit: float = TORQUE_RATE_LIMIT, line_tolerance: float = LINE_TOLERANCE):
    """The stage-form NLP (an MX graph: one call per interval) with FATROP's dimensions: (nlp, dims, lbg, ubg)."""
    N, d = int(n_intervals), int(degree)
    functions, dims, lbg, ubg, n = _stage_parts(params, N, d, regularisation, torque_rate_limit, line_tolerance)
    return _stage_nlp(functions, N, n), dims, lbg, ubg


def solve_stage_form(form: StageForm, params: ArmParameters, start: np.ndarray, elbow: int = 1,
                     t_fixed: float | None = None, label: str = "") -> CollocationSolution:
    """One FATROP solve from the stage-form point `start` (clipped to the bounds).

    Raises
    ------
    TrajectoryError
        FATROP did not converge.
    """
    lbx, ubx = form.bounds(params, elbow, t_fixed)
    t0 = time.perf_counter()
    sol = form.solver(x0=np.clip(start, lbx, ubx), lbx=lbx, ubx=ubx, lbg=form.lbg, ubg=form.ubg,
                      p=form.parameters(params))
    wall = time.perf_counter() - t0
    st = form.solver.stats()
    status, iterations = st.get("return_status"), int(st.get("iter_count", -1))
    if status != CONVERGED or not st.get("success", True):
        raise TrajectoryError(f"FATROP failed in '{label or 'solve'}': return status {status} after "
                              f"{iterations} iterations ({wall:.1f} s); nothing was written")
    stats = {"status": "Solve_Succeeded (FATROP)", "iterations": iterations, "wall_time_s": wall,
             "objective": float(sol["f"]), "t_fixed": t_fixed, "label": label, "angles": form.n,
             "variables": int(start.size), "constraints": int(form.lbg.size)}
    return form.solution(np.asarray(sol["x"]).ravel(), params, stats)

