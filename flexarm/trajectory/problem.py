"""The collocation NLP of the minimum-time straight-line slew (paper section 2, eq. 3).

Problem
-------
minimise t_f subject to the finite-element model M(θ)θ̈ + C(θ)θ̇² + K(θ)1 = B̄τ,
|τ_i| ≤ 0.8·peak_i, start at rest and undeformed with the tip at the line's
start, the tip on the line throughout, the tip at the line's end at t_f, zero
final kinetic and strain energy and zero final joint accelerations.

Method (continuation in the model, then in the end time)
--------------------------------------------------------
1. Rigid two-link problem (2 angles): gives a bang-bang guess in a second.
2. Flexible problem with rigid brackets (8 angles: θ_2 = θ_1, θ_6 = θ_5,
   θ_8 = θ_7), free t_f, warm-started from step 1. The bracket springs
   (2e6 N·m/rad, modes near 5.6, 13 and 21 kHz) deflect by ~3e-6 rad under
   full torque; keeping them would force a time step of microseconds, while
   the 8-angle model keeps every other mode (8, 20, 26, 65, 66, 190 Hz, the
   same as the 11-element model's to 1e-4). Merging an element into its
   neighbour is the linear map θ = Tθ_r with T a 0/1 grouping matrix, and
   because merged elements share one angle the reduced model has exactly
   the form of eq. 1 with M_r = TᵀM T, K_r = TᵀK T, B̄_r = TᵀB̄.
3. The same problem with t_f fixed to the optimum rounded *up* to a whole
   millisecond (the controller needs a whole number of 1 ms samples),
   minimising only the torque-rate regulariser.

Discretisation: Radau IIA collocation (degree 5, stiffly accurate, order 9)
on N = 200 equal intervals (≈10.5 ms) in normalised time s = t/t_f;
accelerations are decision variables and the dynamics are the implicit
equalities M(θ)a = rhs at every collocation point (never M⁻¹). The torque is
piecewise linear and continuous (linear within each interval), so
τ(t_f) = 0 is what zero final joint accelerations mean for an arm at rest
and undeformed. The end state is imposed by bounds: rest and the undeformed
configuration whose tip is the line's end (equivalent to final tip position,
zero kinetic and zero strain energy on the chosen elbow branch).

Choices that make the discrete problem well posed and the plant agree:

* Tip on the line within ±0.1 mm (LINE_TOLERANCE) at every collocation
  point, not as an equality. The tip of a flexible chain is a
  non-minimum-phase output: holding it exactly on the line makes the
  internal (zero) dynamics unstable with time constants of milliseconds, and
  with an exact equality at every node IPOPT does not converge (tested);
  a 0.1 mm band removes the ill-posedness and is 20 times inside the 2 mm
  acceptance.
* Torque slew rate |dτ/dt| ≤ 50 τ_limit/s (TORQUE_RATE_LIMIT: a full
  reversal takes 40 ms). Sharper switches excite the 65 Hz and 190 Hz modes,
  which 10 ms intervals cannot resolve; the plant would keep their energy
  after t_f. Cost: about 8 ms of t_f (2.101 s without it at rate 100/s).
* A torque-rate regulariser 1e-4·Σ|Δu|² (s) picks one solution on singular
  arcs.
* MUMPS pivot tolerance 1e-3: with the default, the badly scaled KKT
  systems (stiff springs, small segment inertias) give inaccurate steps and
  IPOPT stalls.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import time
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from ..model import rigid_configuration
from ..parameters import N_ELEMENTS, ArmParameters
from .geometry import inverse_kinematics
from .io import SAMPLE_TIME, TrajectoryError
from .reduced_model import (  # noqa: F401 (the group tuples: re-exported, warm.py and the tests use them here)
    FLEX_GROUPS,
    RIGID_GROUPS,
    ReducedModel,
    _lagrange_basis,
    _radau,
    _residual_function,
    collocation_times,
)

#: Weight of the torque-rate regulariser Σ(Δu)², u = τ/τ_limit (s); see solve_minimum_time.
DEFAULT_REGULARISATION = 1e-4
#: Half-width of the band about the line that the tip must stay in at every collocation point, m.
LINE_TOLERANCE = 1e-4
#: Largest torque slew rate, in torque limits per second (a full reversal takes 2/rate s).
TORQUE_RATE_LIMIT = 50.0
ACCEPTED_STATUS = ("Solve_Succeeded",)
#: Warm-start options of a re-plan's free-t_f solve (another payload or parameter set from a previous
#: primal-dual solution; solve_minimum_time with warm_start): the barrier restarts at 1e-4 instead of
#: 1e-5, fewer iterations (benchmarks/study_replan.py). The committed file's own stages keep 1e-5.
REPLAN_FREE_TIME_OPTIONS = {"mu_init": 1e-4}
#: The same for a re-plan's whole-millisecond (fixed t_f) solve. 1e-3 and 1e-7 took a few iterations fewer
#: than 1e-4, but the same options let both stages share one solver (making one costs about 3 CPU-s).
REPLAN_FIXED_TIME_OPTIONS = REPLAN_FREE_TIME_OPTIONS



@dataclass
class CollocationSolution:
    """Raw optimiser result on its grid (full 11-element angles, for warm starts).

    Attributes
    ----------
    groups : tuple of int
        Element grouping of the optimiser model.
    n_intervals, degree : int
    t_f : float
        End time, s.
    s : ndarray, shape (N·(d+1)... )
        Normalised times in [0, 1] of the rows below (node 0, then every
        collocation point in order; the last point of each interval is a node).
    theta, omega, alpha : ndarray, shape (len(s), 11)
        Angles (rad), rates (rad/s), accelerations (rad/s²).
    u : ndarray, shape (N + 1, 2)
        Torque at the nodes divided by the torque limit.
    x, lam_x, lam_g : ndarray
        IPOPT primal and dual vectors (for a warm start of the same problem).
    stats : dict
        Status, iterations, wall time, objective.
    """

    groups: tuple
    n_intervals: int
    degree: int
    t_f: float
    s: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray
    u: np.ndarray
    x: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    stats: dict

    def interpolate(self, s_new: np.ndarray) -> dict:
        """Piecewise-linear interpolation of every variable at normalised times s_new."""
        s_nodes = np.linspace(0.0, 1.0, self.n_intervals + 1)
        return {
            "theta": _interp_rows(s_new, self.s, self.theta),
            "omega": _interp_rows(s_new, self.s, self.omega),
            "alpha": _interp_rows(s_new, self.s, self.alpha),
            "u": _interp_rows(s_new, s_nodes, self.u),
        }

    def sample(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Collocation polynomials of θ, θ̇ (11 elements) at times (s) in [0, t_f]."""
        N, d = self.n_intervals, self.degree
        tau, _ = _radau(d)
        sn = np.clip(np.asarray(times, dtype=float) / self.t_f, 0.0, 1.0)
        k = np.minimum((sn * N).astype(int), N - 1)
        loc = sn * N - k
        basis = _lagrange_basis(tau, loc)  # (m, d+1)
        # rows of self.s: 0 is node 0; interval k has rows 1 + k·d .. (k+1)·d; its start is row k·d.
        rows = np.stack([k * d + r for r in range(d + 1)], axis=1)
        th = np.einsum("mr,mre->me", basis, self.theta[rows])
        om = np.einsum("mr,mre->me", basis, self.omega[rows])
        return th, om

    def torque_samples(self, torque_limit, n_samples: int, dt: float = SAMPLE_TIME) -> np.ndarray:
        """Mean of the piecewise-linear torque over each step [k dt, (k+1) dt), N·m, shape (n, 2)."""
        tau_nodes = self.u * np.asarray(torque_limit)
        h = self.t_f / self.n_intervals
        t_nodes = np.arange(self.n_intervals + 1) * h
        cum = np.concatenate([[np.zeros(2)], np.cumsum(0.5 * h * (tau_nodes[1:] + tau_nodes[:-1]), axis=0)])

        def integral(t):
            t = np.clip(t, 0.0, self.t_f)
            k = np.minimum((t / h).astype(int), self.n_intervals - 1)
            r = (t - t_nodes[k])[:, None]
            slope = (tau_nodes[k + 1] - tau_nodes[k]) / h
            return cum[k] + tau_nodes[k] * r + 0.5 * slope * r**2

        edges = np.arange(n_samples + 1) * dt
        F = integral(edges)
        return (F[1:] - F[:-1]) / dt


def _interp_rows(x_new, x, y) -> np.ndarray:
    x, idx = np.unique(np.asarray(x), return_index=True)
    y = np.asarray(y)[idx]
    return np.stack([np.interp(x_new, x, y[:, c]) for c in range(y.shape[1])], axis=1)


def _ipopt_options(verbose: bool, max_iter: int, print_every: int, extra: dict | None = None) -> dict:
    opts = {
        "expand": True,
        "print_time": False,
        "ipopt": {
            "linear_solver": "mumps",
            "max_iter": int(max_iter),
            "tol": 1e-8,
            "acceptable_iter": 0,  # never stop at "acceptable": converge or fail
            "print_level": 5 if verbose else 0,
            "print_frequency_iter": int(print_every),
            "sb": "yes",
            # The KKT matrices are badly scaled (stiff springs, tiny segment inertias): with
            # MUMPS's default pivot tolerance (1e-6) the steps are inaccurate and IPOPT stalls.
            "mumps_pivtol": 1e-3,
            "mumps_pivtolmax": 0.5,
            "mumps_mem_percent": 5000,
        },
    }
    opts["ipopt"].update(extra or {})
    return opts


def solve_collocation(params: ArmParameters, groups, n_intervals: int, degree: int = 3,
                      t_fixed: float | None = None, guess: CollocationSolution | None = None,
                      elbow: int = 1, regularisation: float = DEFAULT_REGULARISATION,
                      verbose: bool = True, max_iter: int = 1000, print_every: int = 10,
                      line_tolerance: float = LINE_TOLERANCE,
                      torque_rate_limit: float | None = TORQUE_RATE_LIMIT, label: str = "",
                      ipopt: dict | None = None, warm_options: dict | None = None) -> CollocationSolution:
    """One direct-collocation solve of the straight-line minimum-time problem.

    Parameters
    ----------
    params : ArmParameters
    groups : sequence of int, length 11
        Element grouping of the optimiser model (:data:`RIGID_GROUPS`,
        :data:`FLEX_GROUPS`, or ``range(11)`` for the full model).
    n_intervals : int
        Collocation intervals N (equal length t_f/N).
    degree : int
        Radau collocation points per interval.
    t_fixed : float, optional
        Fix the end time (s) and minimise only the regulariser.
    guess : CollocationSolution, optional
        Initial guess (any grouping and grid: it is interpolated). When it
        has the same grouping, grid and mode, IPOPT is warm-started with its
        multipliers too.
    elbow : {1, -1}
        Sign of the elbow angle at the start and end.
    regularisation : float
        Weight (s) of Σ_k |u_{k+1} − u_k|² added to t_f; u = τ/τ_limit.
    verbose : bool
        Print IPOPT's iterations (every `print_every`).
    max_iter : int
        IPOPT iteration limit; reaching it raises :class:`TrajectoryError`.
    ipopt : dict, optional
        Extra IPOPT options (they win over every default, the warm-start ones included).
    warm_options : dict, optional
        IPOPT options that replace the warm-start defaults (``mu_init`` 1e-5, bound pushes 1e-9)
        when the guess's multipliers are used; ignored otherwise. A re-plan passes
        :data:`REPLAN_FREE_TIME_OPTIONS` / :data:`REPLAN_FIXED_TIME_OPTIONS`.

    Returns
    -------
    CollocationSolution

    Raises
    ------
    TrajectoryError
        IPOPT did not report ``Solve_Succeeded``.
    """
    red = ReducedModel.build(params, groups)
    n, N, d = red.n, int(n_intervals), int(degree)
    if N < 2 or d < 1:
        raise ValueError("n_intervals must be >= 2 and degree >= 1")
    M = N * d
    nx_state = n * M
    n_x = 3 * nx_state + 2 * (N + 1) + 1
    lim = params.torque_limit
    th0 = red.reduce(rigid_configuration(*inverse_kinematics(params, params.line_start, elbow)))
    thf = red.reduce(rigid_configuration(*inverse_kinematics(params, params.line_end, elbow)))
    same = (guess is not None and guess.groups == red.groups and guess.n_intervals == N and guess.degree == d
            and guess.lam_g is not None and guess.lam_x is not None and len(guess.x) == n_x)
    opts = _ipopt_options(verbose, max_iter, print_every)
    if same:
        # Same structure: start from the previous primal-dual point (valid for a fixed t_f too:
        # t_f's own multiplier absorbs the objective's dt_f term).
        opts["ipopt"].update(warm_start_init_point="yes", warm_start_bound_push=1e-9,
                             warm_start_mult_bound_push=1e-9, mu_init=1e-5)
        opts["ipopt"].update(warm_options or {})
    opts["ipopt"].update(ipopt or {})  # the caller's options win over the warm-start defaults
    solver, n_eq, n_line, n_rate, n_g = _cached_solver(red, N, d, regularisation, torque_rate_limit, opts)
    p = nlp_parameters(params, red, th0, free_time=t_fixed is None)

    # bounds: final state fixed (rest, undeformed, tip at the end: the rigid
    # configuration of the end point), torque limits, t_f
    lbx = np.full(n_x, -np.inf)
    ubx = np.full(n_x, np.inf)
    i_th_f = slice(n * (M - 1), n * M)
    lbx[i_th_f] = ubx[i_th_f] = thf
    i_om_f = slice(nx_state + n * (M - 1), nx_state + n * M)
    lbx[i_om_f] = ubx[i_om_f] = 0.0
    i_u = slice(3 * nx_state, 3 * nx_state + 2 * (N + 1))
    lbx[i_u], ubx[i_u] = -1.0, 1.0
    if t_fixed is not None:
        lbx[-1] = ubx[-1] = float(t_fixed)
    else:
        lbx[-1], ubx[-1] = 0.05, 60.0
    lbg = np.zeros(n_g)
    ubg = np.zeros(n_g)
    lbg[n_eq:n_eq + n_line], ubg[n_eq:n_eq + n_line] = -line_tolerance, line_tolerance
    i_rate = n_eq + n_line + 2
    lbg[i_rate:i_rate + n_rate] = -np.inf

    # initial guess
    s_cols = collocation_times(N, d)[1:]
    if guess is None:
        x0 = _straight_guess(params, red, elbow, s_cols, N)
    else:
        gi = guess.interpolate(np.concatenate([s_cols, np.linspace(0, 1, N + 1)]))
        t_new = t_fixed if t_fixed is not None else guess.t_f
        rate = guess.t_f / t_new  # the guess is stretched in time to t_new
        th_g = red.reduce(gi["theta"][:M]).T
        om_g = red.reduce(gi["omega"][:M]).T * rate
        ac_g = red.reduce(gi["alpha"][:M]).T * rate**2
        u_g = guess.interpolate(np.linspace(0, 1, N + 1))["u"].T
        x0 = np.concatenate([th_g.ravel("F"), om_g.ravel("F"), ac_g.ravel("F"), u_g.ravel("F"), [t_new]])
    x0 = np.clip(x0, lbx, ubx)
    args = {"x0": x0, "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg, "p": p}
    if same:
        args.update(x0=np.clip(guess.x, lbx, ubx), lam_x0=guess.lam_x, lam_g0=guess.lam_g)
    if verbose:
        mode = f"t_f fixed at {t_fixed:.4f} s" if t_fixed is not None else "t_f free"
        print(f"[trajectory] {label or 'solve'}: {n} angles, N={N}, Radau degree {d}, "
              f"{n_x} variables, {n_g} constraints, {mode}", flush=True)
    t0 = time.perf_counter()
    sol = solver(**args)
    wall = time.perf_counter() - t0
    st = solver.stats()
    status = st.get("return_status", "unknown")
    iters = int(st.get("iter_count", -1))
    if status not in ACCEPTED_STATUS:
        raise TrajectoryError(f"IPOPT failed in '{label or 'solve'}': {status} after {iters} iterations "
                              f"({wall:.1f} s); nothing was written")
    xs = np.asarray(sol["x"]).ravel()
    THs = xs[:nx_state].reshape(n, M, order="F")
    OMs = xs[nx_state:2 * nx_state].reshape(n, M, order="F")
    ACs = xs[2 * nx_state:3 * nx_state].reshape(n, M, order="F")
    Us = xs[3 * nx_state:3 * nx_state + 2 * (N + 1)].reshape(2, N + 1, order="F")
    tfs = float(xs[-1])
    # node 0 acceleration: solve the dynamics there (at rest, undeformed: M a = B̄τ)
    a0 = np.linalg.solve(red.mass_coefficients * np.cos(th0[:, None] - th0[None, :]),
                         red.input_matrix @ (Us[:, 0] * lim))
    T = red.T
    stats = {"status": status, "iterations": iters, "wall_time_s": wall, "objective": float(sol["f"]),
             "t_fixed": t_fixed, "label": label, "angles": n, "variables": n_x,
             "constraints": n_g}
    if verbose:
        print(f"[trajectory] {label or 'solve'}: {status}, {iters} iterations, {wall:.1f} s, t_f = {tfs:.5f} s",
              flush=True)
    return CollocationSolution(
        groups=red.groups, n_intervals=N, degree=d, t_f=tfs,
        s=np.concatenate([[0.0], s_cols]),
        theta=np.vstack([T @ th0, (T @ THs).T]),
        omega=np.vstack([np.zeros(N_ELEMENTS), (T @ OMs).T]),
        alpha=np.vstack([T @ a0, (T @ ACs).T]),
        u=Us.T.copy(), x=xs, lam_x=np.asarray(sol["lam_x"]).ravel(), lam_g=np.asarray(sol["lam_g"]).ravel(),
        stats=stats)


_NLP_CACHE: dict = {}


@contextlib.contextmanager
def blas_threads(n: int):
    """Run the OpenBLAS bundled with CasADi (MUMPS factorises the KKT systems with it) on n threads.

    The previous count is restored on exit. A no-op when that library is not there (another
    CasADi build). One thread does the same factorisations in about the same wall time on a
    shared 2-core machine, but without the second thread's spinning, which OpenBLAS's default
    (one thread per core) adds to the CPU time (benchmarks/study_replan.py). The cold solve
    keeps the default: the committed file was computed with it, and one thread changes its last
    digits (the torques by about 1e-10 N·m), so only re-plans use this.
    """
    lib = None
    with contextlib.suppress(OSError, AttributeError):
        path = Path(ca.__file__).parent / "libcasadi-tp-openblas.so.0"
        if path.exists():
            lib = ctypes.CDLL(str(path))
            get, put = lib.openblas_get_num_threads, lib.openblas_set_num_threads
    if lib is None:
        yield
        return
    before = int(get())
    put(int(n))
    try:
        yield
    finally:
        put(before)


def nlp_parameters(params: ArmParameters, red: ReducedModel, th0: np.ndarray, free_time: bool) -> np.ndarray:
    """The parameter vector p of :func:`nlp_expressions` (its docstring gives the layout)."""
    dvec = (params.line_end - params.line_start) / np.linalg.norm(params.line_end - params.line_start)
    return np.concatenate([[1.0 if free_time else 0.0], red.coefficient_vector(), params.torque_limit, th0,
                           red.T.T @ red.length, params.line_start, [-dvec[1], dvec[0]]])


def _cached_solver(red: ReducedModel, N: int, d: int, regularisation: float, torque_rate_limit, opts: dict):
    """IPOPT on :func:`nlp_expressions`; returns (solver, n_eq, n_line, n_rate, n_g).

    The NLP is built once per structure (the model constants, payload included, are parameters).
    IPOPT's options are fixed when a CasADi solver is made and a warm start needs other ones
    (warm_start_init_point, mu_init), so each option set gets its own solver; the second one
    reuses the first one's derivative functions (the exact Hessian and Jacobian: for the flexible
    problem the second solver then takes about 5 CPU-s to make instead of about 22).
    """
    key = (red.groups, N, d, float(regularisation), torque_rate_limit, tuple(map(tuple, red.stiffness_pattern())))
    if key not in _NLP_CACHE:
        if len(_NLP_CACHE) >= 2:  # they are large: keep the latest (rigid and flexible)
            _NLP_CACHE.pop(next(iter(_NLP_CACHE)))
        nlp, *counts = nlp_expressions(red, N, d, regularisation, torque_rate_limit)
        f = ca.Function("nlp", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]]).expand()
        x, p = ca.SX.sym("x", f.size1_in(0)), ca.SX.sym("p", f.size1_in(1))
        fx, gx = f(x, p)
        _NLP_CACHE[key] = {"nlp": {"x": x, "p": p, "f": fx, "g": gx}, "counts": counts, "derivatives": {},
                           "solvers": {}}
    entry = _NLP_CACHE[key]
    okey = json.dumps(opts, sort_keys=True)
    if okey not in entry["solvers"]:
        full = {**opts, "expand": False, **entry["derivatives"]}
        solver = ca.nlpsol("slew", "ipopt", entry["nlp"], full)
        if not entry["derivatives"]:
            entry["derivatives"] = {"hess_lag": solver.get_function("nlp_hess_l"),
                                    "jac_g": solver.get_function("nlp_jac_g"),
                                    "grad_f": solver.get_function("nlp_grad_f")}
        entry["solvers"][okey] = solver
    return (entry["solvers"][okey], *entry["counts"])


def nlp_expressions(red: ReducedModel, N: int, d: int, regularisation: float, torque_rate_limit):
    """The collocation NLP for one structure; model constants, start and line are parameters.

    Parameters p = [w_tf, model coefficients, τ_limit (2), θ_r(0) (n), group lengths (n),
    line start (2), line normal (2)]; the objective is w_tf·t_f + regulariser.
    """
    n = red.n
    M = N * d
    tau_c, D = _radau(d)
    pattern = red.stiffness_pattern()
    n_c = n * n + int(pattern.sum()) + 2 * n
    P = ca.MX.sym("p", 1 + n_c + 2 + n + n + 4)
    w_tf = P[0]
    coeff = P[1:1 + n_c]
    lim = P[1 + n_c:3 + n_c]
    th0 = P[3 + n_c:3 + n_c + n]
    lg = P[3 + n_c + n:3 + n_c + 2 * n]
    p0 = P[3 + n_c + 2 * n:5 + n_c + 2 * n]
    normal = P[5 + n_c + 2 * n:7 + n_c + 2 * n]

    TH, OM, AC = ca.MX.sym("TH", n, M), ca.MX.sym("OM", n, M), ca.MX.sym("AC", n, M)
    U = ca.MX.sym("U", 2, N + 1)
    tf = ca.MX.sym("tf")
    h = tf / N
    last = list(range(d - 1, M, d))  # columns that are nodes 1..N
    th_start = ca.horzcat(th0, TH[:, last[:-1]])
    om_start = ca.horzcat(ca.DM.zeros(n, 1), OM[:, last[:-1]])
    cons = []
    for j in range(d):
        cols = list(range(j, M, d))
        dth = D[0, j] * th_start + sum(D[r, j] * TH[:, list(range(r - 1, M, d))] for r in range(1, d + 1))
        dom = D[0, j] * om_start + sum(D[r, j] * OM[:, list(range(r - 1, M, d))] for r in range(1, d + 1))
        cons += [dth - h * OM[:, cols], dom - h * AC[:, cols]]
    # torque (N·m) at every collocation point: linear within the interval
    w = np.tile(tau_c[1:], N)
    kk = np.repeat(np.arange(N), d)
    Ucol = U[:, list(kk)] * ca.repmat(ca.DM(1 - w).T, 2, 1) + U[:, list(kk + 1)] * ca.repmat(ca.DM(w).T, 2, 1)
    Tcol = ca.repmat(lim, 1, M) * Ucol
    dyn = _residual_function(n, pattern).map(M)
    cons.append(dyn(TH, OM, AC, Tcol, ca.repmat(coeff, 1, M)))
    n_eq = sum(c.numel() for c in cons)
    # tip on the line at every collocation point before t_f (at t_f the end point is imposed),
    # within ±line_tolerance: see the module notes for why not an exact equality.
    thl = TH[:, : M - 1]
    tip_x = ca.mtimes(lg.T, ca.cos(thl))
    tip_y = ca.mtimes(lg.T, ca.sin(thl))
    cons.append(normal[0] * (tip_x - p0[0]) + normal[1] * (tip_y - p0[1]))
    n_line = M - 1
    # zero final joint accelerations
    cons.append(ca.DM(red.joint_rows) @ AC[:, M - 1])
    # torque slew-rate limit: |Δu| ≤ rate·h (linear in t_f), both signs
    n_rate = 0
    dU = U[:, 1:] - U[:, :-1]
    if torque_rate_limit is not None:
        cons += [ca.vec(dU) - torque_rate_limit * h, -ca.vec(dU) - torque_rate_limit * h]
        n_rate = 4 * N
    g = ca.vertcat(*[ca.vec(c) for c in cons])
    x = ca.vertcat(ca.vec(TH), ca.vec(OM), ca.vec(AC), ca.vec(U), tf)
    f = w_tf * tf + regularisation * ca.sumsqr(dU)
    return {"x": x, "f": f, "g": g, "p": P}, n_eq, n_line, n_rate, int(g.shape[0])


def _straight_guess(params, red: ReducedModel, elbow: int, s_cols, N) -> np.ndarray:
    """Rigid arm moving along the line with a symmetric bang-bang path speed."""
    t_guess = 2.0
    sigma = np.where(s_cols < 0.5, 2 * s_cols**2, 1 - 2 * (1 - s_cols) ** 2)
    pts = params.line_start + sigma[:, None] * (params.line_end - params.line_start)
    th = np.array([red.reduce(rigid_configuration(*inverse_kinematics(params, p, elbow))) for p in pts]).T
    th = np.unwrap(th, axis=1)
    om = np.gradient(th, s_cols * t_guess, axis=1)
    ac = np.gradient(om, s_cols * t_guess, axis=1)
    u = np.zeros((2, N + 1))
    return np.concatenate([th.ravel("F"), om.ravel("F"), ac.ravel("F"), u.ravel("F"), [t_guess]])
