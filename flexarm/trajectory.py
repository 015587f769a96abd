"""Minimum-time straight-line slew of the flexible arm (paper section 2, eq. 3).

Run ``python -m flexarm.trajectory`` to regenerate the committed
``flexarm/data/trajectory.npz`` (1 ms samples) and ``trajectory.json``
(metadata); ``--help`` lists the options.

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

The 1 ms file
-------------
θ and θ̇ are the optimiser's collocation polynomials evaluated every 1 ms
(the desired states come from the optimiser's model). The torque held over
sample k, [kΔ, (k+1)Δ), is the exact mean of the piecewise-linear optimal
torque over that millisecond, so a zero-order-hold replay delivers the same
impulse per step; the torque at t_f (the last sample) is zero.
:func:`verify_against_plant` replays those torques open loop in the full
11-element plant (:func:`flexarm.integrator.simulate`) and measures the
errors against the file.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from .model import ArmModel, joint_angles, rigid_configuration, strain_gauge_angles
from .parameters import DATA_DIR, JOINT2_PAIR, N_ELEMENTS, ArmParameters, load_parameters

DEFAULT_TRAJECTORY_FILE = DATA_DIR / "trajectory.npz"
DEFAULT_PLOT_FILE = DATA_DIR / "trajectory.png"
#: Minimum time reported by the paper for its slew, s.
PAPER_TF = 2.058
#: Sample time of the file (and of the controller), s.
SAMPLE_TIME = 1e-3
#: Element groups (0-based element -> reduced angle) of the two optimiser models.
RIGID_GROUPS = (0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1)
FLEX_GROUPS = (0, 0, 1, 2, 3, 3, 4, 4, 5, 6, 7)  # brackets merged: θ2=θ1, θ6=θ5, θ8=θ7
#: Weight of the torque-rate regulariser Σ(Δu)², u = τ/τ_limit (s); see solve_minimum_time.
DEFAULT_REGULARISATION = 1e-4
#: Half-width of the band about the line that the tip must stay in at every collocation point, m.
LINE_TOLERANCE = 1e-4
#: Largest torque slew rate, in torque limits per second (a full reversal takes 2/rate s).
TORQUE_RATE_LIMIT = 50.0
ACCEPTED_STATUS = ("Solve_Succeeded",)


class TrajectoryError(RuntimeError):
    """The optimiser failed (infeasible, iteration limit, ...) or a file is invalid."""


# -- geometry -----------------------------------------------------------------
def inverse_kinematics(params: ArmParameters, point, elbow: int = 1) -> tuple[float, float]:
    """Joint angles (rad) of the undeformed arm with its tip at `point` (m).

    Parameters
    ----------
    params : ArmParameters
    point : array_like, shape (2,)
        Tip position, m.
    elbow : {1, -1}
        Sign of the elbow angle q2.

    Returns
    -------
    q1, q2 : float
        Shoulder angle and elbow angle (θ_7 − θ_6), rad.
    """
    l1 = params.length[: JOINT2_PAIR[1]].sum()
    l2 = params.length[JOINT2_PAIR[1]:].sum()
    x, y = float(point[0]), float(point[1])
    c2 = (x * x + y * y - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    if not -1.0 < c2 < 1.0:
        raise TrajectoryError(f"point {point} is outside the arm's reach ({abs(l1 - l2):.3f} to {l1 + l2:.3f} m)")
    q2 = elbow * math.acos(c2)
    q1 = math.atan2(y, x) - math.atan2(l2 * math.sin(q2), l1 + l2 * math.cos(q2))
    return q1, q2


def line_distance(params: ArmParameters, tip) -> np.ndarray:
    """Signed distance (m) of tip positions, shape (..., 2), from the straight line."""
    p0, p1 = params.line_start, params.line_end
    d = (p1 - p0) / np.linalg.norm(p1 - p0)
    normal = np.array([-d[1], d[0]])
    return (np.asarray(tip) - p0) @ normal


# -- reduced models -------------------------------------------------------------
@dataclass(frozen=True)
class ReducedModel:
    """Eq. 1 for the elements merged into groups (θ = Tθ_r).

    Attributes
    ----------
    groups : tuple of int, length 11
        Reduced angle of each element.
    T : ndarray, shape (11, n)
        0/1 grouping matrix.
    mass_coefficients : ndarray, shape (n, n)
        TᵀM_jk T, kg·m².
    stiffness : ndarray, shape (n, n)
        TᵀK T, N·m/rad (springs inside a group drop out).
    input_matrix : ndarray, shape (n, 2)
        TᵀB̄.
    """

    groups: tuple
    T: np.ndarray
    mass_coefficients: np.ndarray
    stiffness: np.ndarray
    input_matrix: np.ndarray
    length: np.ndarray
    joint_rows: np.ndarray = field(default_factory=lambda: np.zeros((2, 1)))

    @classmethod
    def build(cls, params: ArmParameters, groups) -> ReducedModel:
        groups = tuple(int(g) for g in groups)
        n = max(groups) + 1
        T = np.zeros((N_ELEMENTS, n))
        T[np.arange(N_ELEMENTS), groups] = 1.0
        full = ArmModel(params)
        sel = np.zeros((2, N_ELEMENTS))  # joint angles q = S θ
        sel[0, 0] = 1.0
        sel[1, JOINT2_PAIR[1]], sel[1, JOINT2_PAIR[0]] = 1.0, -1.0
        return cls(groups, T, T.T @ full.mass_coefficients @ T, T.T @ full.stiffness @ T,
                   T.T @ full.input_matrix(), params.length.copy(), sel @ T)

    @property
    def n(self) -> int:
        return self.T.shape[1]

    def reduce(self, theta_full) -> np.ndarray:
        """Reduced angles (the first element of each group), shape (..., n)."""
        first = [self.groups.index(g) for g in range(self.n)]
        return np.asarray(theta_full)[..., first]

    def coefficient_vector(self) -> np.ndarray:
        """Model constants in the order of :func:`_residual_function`'s `coeff` input."""
        pattern = self.stiffness_pattern()
        return np.concatenate([self.mass_coefficients.ravel(), self.stiffness[pattern], self.input_matrix.ravel()])

    def stiffness_pattern(self) -> np.ndarray:
        """Off-diagonal entries of TᵀKT that are springs (structure of the problem)."""
        pattern = self.stiffness != 0.0
        np.fill_diagonal(pattern, False)
        return pattern


def _residual_function(n: int, pattern: np.ndarray) -> ca.Function:
    """CasADi f(θ, ω, a, τ, coeff) = M(θ)a + C(θ)ω² + K(θ)1 − B̄τ, N·m (SX).

    The constants (M_jk, spring stiffnesses, B̄) are an input so one NLP serves
    every parameter set with the same structure (payload changes, sensitivity).
    """
    th, om, a = ca.SX.sym("th", n), ca.SX.sym("om", n), ca.SX.sym("a", n)
    tau = ca.SX.sym("tau", 2)
    n_k = int(pattern.sum())
    coeff = ca.SX.sym("coeff", n * n + n_k + 2 * n)
    Mc = ca.reshape(coeff[: n * n], n, n).T  # row-major as numpy's ravel
    kvals = {}
    for idx, (i, j) in enumerate(zip(*np.nonzero(pattern))):
        kvals[(int(i), int(j))] = coeff[n * n + idx]
    B = ca.reshape(coeff[n * n + n_k:], 2, n).T
    terms = []
    for i in range(n):
        t = -(B[i, 0] * tau[0] + B[i, 1] * tau[1]) + Mc[i, i] * a[i]
        for j in range(n):
            if i == j:
                continue
            dth = th[i] - th[j]
            c, sn = ca.cos(dth), ca.sin(dth)
            t += Mc[i, j] * (c * a[j] + sn * om[j] ** 2)
            if (i, j) in kvals:
                t += -kvals[(i, j)] * sn
        terms.append(t)
    return ca.Function("dyn", [th, om, a, tau, coeff], [ca.vertcat(*terms)])


# -- collocation ----------------------------------------------------------------
def _radau(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Radau IIA points (with 0 first) and derivative matrix D[r, j] = L_r'(τ_j), j ≥ 1."""
    tau = np.array([0.0] + ca.collocation_points(degree, "radau"))
    D = np.zeros((degree + 1, degree))
    for r in range(degree + 1):
        coeff = np.poly1d([1.0])
        for m in range(degree + 1):
            if m != r:
                coeff *= np.poly1d([1.0, -tau[m]]) / (tau[r] - tau[m])
        der = np.polyder(coeff)
        D[r] = der(tau[1:])
    return tau, D


def _lagrange_basis(tau: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Lagrange basis on points tau evaluated at x: shape (len(x), len(tau))."""
    out = np.ones((len(x), len(tau)))
    for r in range(len(tau)):
        for m in range(len(tau)):
            if m != r:
                out[:, r] *= (x - tau[m]) / (tau[r] - tau[m])
    return out


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
                      ipopt: dict | None = None) -> CollocationSolution:
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
    tau_c, _ = _radau(d)
    M = N * d
    nx_state = n * M
    n_x = 3 * nx_state + 2 * (N + 1) + 1
    lim = params.torque_limit
    th0 = red.reduce(rigid_configuration(*inverse_kinematics(params, params.line_start, elbow)))
    thf = red.reduce(rigid_configuration(*inverse_kinematics(params, params.line_end, elbow)))
    same = (guess is not None and guess.groups == red.groups and guess.n_intervals == N and guess.degree == d
            and guess.lam_g is not None and guess.lam_x is not None and len(guess.x) == n_x)
    opts = _ipopt_options(verbose, max_iter, print_every, ipopt)
    if same:
        # Same structure: start from the previous primal-dual point (valid for a fixed t_f too:
        # t_f's own multiplier absorbs the objective's dt_f term).
        opts["ipopt"].update(warm_start_init_point="yes", warm_start_bound_push=1e-9,
                             warm_start_mult_bound_push=1e-9, mu_init=1e-5)
    key = (red.groups, N, d, float(regularisation), torque_rate_limit,
           tuple(map(tuple, red.stiffness_pattern())), json.dumps(opts, sort_keys=True))
    if key not in _NLP_CACHE:
        if len(_NLP_CACHE) >= 3:  # they are large: keep the latest few (cold and warm variants)
            _NLP_CACHE.pop(next(iter(_NLP_CACHE)))
        _NLP_CACHE[key] = _build_nlp(red, N, d, regularisation, torque_rate_limit, opts)
    solver, n_eq, n_line, n_rate, n_g = _NLP_CACHE[key]
    dvec = (params.line_end - params.line_start) / np.linalg.norm(params.line_end - params.line_start)
    lengths = red.T.T @ red.length
    p = np.concatenate([[0.0 if t_fixed is not None else 1.0], red.coefficient_vector(), lim, th0, lengths,
                        params.line_start, [-dvec[1], dvec[0]]])

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
    s_cols = (np.repeat(np.arange(N), d) + np.tile(tau_c[1:], N)) / N
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


def _build_nlp(red: ReducedModel, N: int, d: int, regularisation: float, torque_rate_limit, opts: dict):
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
    solver = ca.nlpsol("slew", "ipopt", {"x": x, "f": f, "g": g, "p": P}, opts)
    return solver, n_eq, n_line, n_rate, int(g.shape[0])


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


# -- the complete solve ------------------------------------------------------------
@dataclass
class TrajectoryResult:
    """The optimal slew sampled every 1 ms.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Sample times 0, 1 ms, ..., t_f, s (n = t_f / 1 ms + 1).
    tau : ndarray, shape (n, 2)
        Torque held from t[k] to t[k+1], N·m (zero at t_f: the arm is left at rest).
    theta, omega : ndarray, shape (n, 11)
        Desired element angles (rad) and rates (rad/s).
    tip : ndarray, shape (n, 2)
        Tip position of the desired angles, m.
    metadata : dict
        t_f, solver statistics, discretisation, parameter file hash, line, commit, command.
    solution : CollocationSolution or None
        The optimiser's raw result (None when loaded from a file).
    """

    t: np.ndarray
    tau: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    tip: np.ndarray
    metadata: dict
    solution: CollocationSolution | None = None

    @property
    def t_f(self) -> float:
        """Slew time of the file, s (a whole number of milliseconds)."""
        return float(self.t[-1])

    @property
    def n_samples(self) -> int:
        """Number of 1 ms torque steps, t_f / 1 ms."""
        return len(self.t) - 1

    def state(self, k: int) -> np.ndarray:
        """Desired state z = (θ, θ̇) at sample k, shape (22,)."""
        return np.concatenate([self.theta[k], self.omega[k]])


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
        A previous solution (e.g. for another payload); skips the rigid stage.
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
    stages = []
    common = {"elbow": elbow, "regularisation": regularisation, "verbose": verbose, "max_iter": max_iter,
              "line_tolerance": line_tolerance, "torque_rate_limit": torque_rate_limit}
    guess = warm_start.solution if isinstance(warm_start, TrajectoryResult) else warm_start
    if guess is None:
        rigid = solve_collocation(params, RIGID_GROUPS, rigid_intervals, 3, label="rigid two-link", **common)
        stages.append(rigid.stats)
        guess = rigid
    free = solve_collocation(params, FLEX_GROUPS, n_intervals, degree, guess=guess, label="flexible, t_f free",
                             **common)
    stages.append(free.stats)
    t_ms = int(math.ceil(free.t_f / SAMPLE_TIME - 1e-9))
    fixed = solve_collocation(params, FLEX_GROUPS, n_intervals, degree, t_fixed=t_ms * SAMPLE_TIME, guess=free,
                              label="flexible, t_f rounded up to whole ms", **common)
    stages.append(fixed.stats)
    total = time.perf_counter() - t_start
    result = sample_solution(params, fixed)
    result.metadata.update({
        "t_f_continuous_s": free.t_f,
        "solver": {"name": "IPOPT (CasADi nlpsol, exact Hessian, MUMPS)", "casadi": ca.__version__,
                   "status": fixed.stats["status"],
                   "iterations": sum(s["iterations"] for s in stages),
                   "solve_time_s": total, "stages": stages},
        "discretisation": {
            "method": "Radau IIA direct collocation, implicit dynamics M(θ)a = rhs at every collocation point",
            "intervals": n_intervals, "degree": degree, "interval_s": fixed.t_f / n_intervals,
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
        "commit": _git_commit(),
        "command": _command_line(),
        "sampling": ("theta/omega: optimiser's collocation polynomials at t = k ms; tau[k]: mean optimal torque "
                     "over [t_k, t_k+1), held (zero-order hold); tau at t_f is 0"),
    }
    return TrajectoryResult(t=t, tau=tau, theta=theta, omega=omega, tip=tip, metadata=meta, solution=sol)


# -- verification against the full plant -------------------------------------------
def verify_against_plant(result: TrajectoryResult, params: ArmParameters | None = None,
                         settle_s: float = 1.0) -> dict:
    """Replay the file's torques open loop in the full 11-element plant.

    Parameters
    ----------
    result : TrajectoryResult
    params : ArmParameters, optional
        Plant parameters (default: the committed file).
    settle_s : float
        Zero-torque run after t_f, s.

    Returns
    -------
    dict
        ``max_angle_error_deg`` (any element, over the slew),
        ``max_line_distance_mm`` (plant tip from the line, over the slew),
        ``final_tip_error_mm``, ``residual_energy_J`` (T + V at t_f) and
        ``max_energy_after_J`` (over the settling run).
    """
    from .integrator import simulate

    params = params if params is not None else load_parameters()
    model = ArmModel(params)
    z0 = result.state(0)
    n = result.n_samples
    n_settle = int(round(settle_s / SAMPLE_TIME))
    torques = np.vstack([result.tau[:n], np.zeros((n_settle, 2))])
    z = simulate(model, z0, torques)
    th = z[: n + 1, :N_ELEMENTS]
    tip = np.array([model.tip_position(x) for x in th])
    energy_after = np.array([model.total_energy(x) for x in z[n:]])
    return {
        "max_angle_error_deg": float(np.degrees(np.max(np.abs(th - result.theta)))),
        "max_velocity_error_deg_s": float(np.degrees(np.max(np.abs(z[: n + 1, N_ELEMENTS:] - result.omega)))),
        "max_line_distance_mm": float(1e3 * np.max(np.abs(line_distance(params, tip)))),
        "final_tip_error_mm": float(1e3 * np.linalg.norm(tip[-1] - params.line_end)),
        "residual_energy_J": float(energy_after[0]),
        "max_energy_after_J": float(energy_after.max()),
        "states": z,
    }


def check_constraints(result: TrajectoryResult, params: ArmParameters | None = None) -> dict:
    """Constraint residuals of the file's desired trajectory (its own samples).

    Returns
    -------
    dict
        ``max_line_distance_mm``, ``final_tip_error_mm``, ``final_kinetic_J``,
        ``final_strain_J``, ``max_torque_ratio`` (|τ|/τ_limit),
        ``initial_strain_J``, ``initial_speed`` (rad/s).
    """
    params = params if params is not None else load_parameters()
    model = ArmModel(params)
    lim = params.torque_limit
    return {
        "max_line_distance_mm": float(1e3 * np.max(np.abs(line_distance(params, result.tip)))),
        "final_tip_error_mm": float(1e3 * np.linalg.norm(result.tip[-1] - params.line_end)),
        "final_kinetic_J": model.kinetic_energy(result.state(-1)),
        "final_strain_J": model.strain_energy(result.theta[-1]),
        "max_torque_ratio": float(np.max(np.abs(result.tau) / lim)),
        "initial_strain_J": model.strain_energy(result.theta[0]),
        "initial_speed": float(np.max(np.abs(result.omega[0]))),
        "final_tau": result.tau[-1].tolist(),
    }


# -- files ---------------------------------------------------------------------------
def _npz_arrays(result: TrajectoryResult) -> dict:
    out = {"t": result.t, "tau1": result.tau[:, 0], "tau2": result.tau[:, 1]}
    for i in range(N_ELEMENTS):
        out[f"theta{i + 1}"] = result.theta[:, i]
    for i in range(N_ELEMENTS):
        out[f"omega{i + 1}"] = result.omega[:, i]
    out["tip_x"], out["tip_y"] = result.tip[:, 0], result.tip[:, 1]
    return out


def _atomic_write(path: Path, write) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.chmod(tmp, 0o644)  # mkstemp creates 0600
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def save_trajectory(result: TrajectoryResult, path: str | os.PathLike = DEFAULT_TRAJECTORY_FILE) -> Path:
    """Write ``path`` (.npz, 1 ms samples + metadata) and its ``.json`` sidecar atomically.

    Returns
    -------
    Path
        The JSON metadata file.
    """
    path = Path(path)
    meta = _jsonable(result.metadata)
    text = json.dumps(meta, indent=2, sort_keys=False) + "\n"
    arrays = _npz_arrays(result)
    arrays["metadata"] = np.array(text)
    _atomic_write(path, lambda fh: np.savez_compressed(fh, **arrays))
    json_path = path.with_suffix(".json")
    _atomic_write(json_path, lambda fh: fh.write(text.encode()))
    return json_path


def load_trajectory(path: str | os.PathLike = DEFAULT_TRAJECTORY_FILE) -> TrajectoryResult:
    """Read a file written by :func:`save_trajectory`.

    Raises
    ------
    TrajectoryError
        A key is missing or the arrays are inconsistent.
    """
    path = Path(path)
    with np.load(path, allow_pickle=False) as data:
        try:
            t = data["t"]
            tau = np.stack([data["tau1"], data["tau2"]], axis=1)
            theta = np.stack([data[f"theta{i + 1}"] for i in range(N_ELEMENTS)], axis=1)
            omega = np.stack([data[f"omega{i + 1}"] for i in range(N_ELEMENTS)], axis=1)
            tip = np.stack([data["tip_x"], data["tip_y"]], axis=1)
            meta = json.loads(str(data["metadata"])) if "metadata" in data else {}
        except KeyError as exc:
            raise TrajectoryError(f"{path}: missing array {exc}") from exc
    n = len(t)
    if any(len(a) != n for a in (tau, theta, omega, tip)) or n < 2:
        raise TrajectoryError(f"{path}: arrays of different lengths")
    if not np.allclose(np.diff(t), SAMPLE_TIME, atol=1e-12, rtol=0):
        raise TrajectoryError(f"{path}: samples are not {SAMPLE_TIME} s apart")
    return TrajectoryResult(t=t, tau=tau, theta=theta, omega=omega, tip=tip, metadata=meta)


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items() if not isinstance(v, np.ndarray) or v.size < 50}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return obj


def _git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent, capture_output=True,
                             text=True, timeout=10)
        return out.stdout.strip() if out.returncode == 0 else ""
    except (OSError, subprocess.SubprocessError):
        return ""


def _command_line() -> str:
    argv = sys.argv[:]
    if argv and argv[0].endswith("trajectory.py") or (argv and argv[0].endswith("__main__.py")):
        return " ".join(["python -m flexarm.trajectory"] + [shlex.quote(a) for a in argv[1:]])
    return " ".join(shlex.quote(a) for a in argv)


# -- sensitivity -----------------------------------------------------------------------
def calibrated_unknowns(params: ArmParameters, design: dict) -> dict[str, float]:
    """The calibrated unknowns read back from a parameter set (see flexarm.calibration)."""
    mb = design["chosen"]["bracket_mass_kg"]
    return {
        "hub_inertia_kgm2": float(params.inertia[0]),
        "stator_mass_kg": float(params.mass[5] - mb),
        "rotor2_inertia_kgm2": float(params.inertia[6]),
        "accelerometer2_mass_kg": float(params.point_mass[-1]),
    }


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
    from .parameters import build_from_design, load_design

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


# -- plot ---------------------------------------------------------------------------------
def plot_trajectory(result: TrajectoryResult, path: str | os.PathLike = DEFAULT_PLOT_FILE,
                    params: ArmParameters | None = None) -> Path:
    """Tip path against the line, torques against their limits, joint and strain-gauge angles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    params = params if params is not None else load_parameters()
    lim = params.torque_limit
    t = result.t
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    a = ax[0, 0]
    a.plot([params.line_start[0], params.line_end[0]], [params.line_start[1], params.line_end[1]], "k--",
           lw=1, label="line")
    a.plot(result.tip[:, 0], result.tip[:, 1], "C0", label="tip")
    model = ArmModel(params)
    for k in np.linspace(0, len(t) - 1, 6).astype(int):
        pts = model.hinge_positions(result.theta[k])
        a.plot(pts[:, 0], pts[:, 1], "-", color="0.6", lw=0.8)
    a.set_aspect("equal")
    a.set_xlabel("x (m)")
    a.set_ylabel("y (m)")
    a.set_title("tip path (arm drawn at 6 instants)")
    a.legend(loc="best")
    a = ax[0, 1]
    for i, c in ((0, "C0"), (1, "C1")):
        a.step(t, result.tau[:, i], where="post", color=c, label=f"τ{i + 1}")
        a.axhline(lim[i], color=c, ls=":", lw=0.8)
        a.axhline(-lim[i], color=c, ls=":", lw=0.8)
    a.set_xlabel("t (s)")
    a.set_ylabel("torque (N·m)")
    a.set_title("torques and their limits (80 % of peak)")
    a.legend(loc="best")
    a = ax[1, 0]
    q = np.array([joint_angles(th) for th in result.theta])
    a.plot(t, np.degrees(q[:, 0]), label="q1 = θ1")
    a.plot(t, np.degrees(q[:, 1]), label="q2 = θ7 − θ6")
    a.set_xlabel("t (s)")
    a.set_ylabel("joint angle (deg)")
    a.set_title("joint angles")
    a.legend(loc="best")
    a = ax[1, 1]
    e = np.array([strain_gauge_angles(th) for th in result.theta])
    names = ("ε11", "ε12", "ε13", "ε21", "ε22", "ε23")
    for i in range(6):
        a.plot(t, np.degrees(e[:, i]), label=names[i])
    a.set_xlabel("t (s)")
    a.set_ylabel("segment angle (deg)")
    a.set_title("strain-gauge angles")
    a.legend(loc="best", ncol=2, fontsize=8)
    fig.suptitle(f"Minimum-time slew: t_f = {result.t_f:.3f} s (paper {PAPER_TF} s)")
    fig.tight_layout()
    path = Path(path)
    _atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=110))
    plt.close(fig)
    return path


# -- command line -----------------------------------------------------------------------------
def _report(result: TrajectoryResult, replay: dict, sens: list[dict] | None) -> str:
    m = result.metadata
    lines = [
        f"t_f = {m['t_f_continuous_s']:.4f} s (continuous optimum); file: {result.t_f:.3f} s = "
        f"{result.n_samples} samples of 1 ms; paper: {PAPER_TF} s "
        f"({100 * (m['t_f_continuous_s'] / PAPER_TF - 1):+.1f} %)",
        f"solver: {m['solver']['status']}, {m['solver']['iterations']} iterations in all stages, "
        f"{m['solver']['solve_time_s']:.1f} s",
        f"tau1 within 1 % of its limit: {100 * m['tau1_on_limit_fraction']:.1f} % of the 1 ms steps "
        f"(tau2: {100 * m['tau2_on_limit_fraction']:.1f} %)",
        f"plant replay: max angle error {replay['max_angle_error_deg']:.4f} deg, max tip-line distance "
        f"{replay['max_line_distance_mm']:.3f} mm, final tip error {replay['final_tip_error_mm']:.3f} mm, "
        f"residual energy {replay['residual_energy_J']:.2e} J",
    ]
    if sens:
        lines.append("sensitivity (t_f, s):")
        lines.append(f"  {'parameter':24s} {'factor':>6s} {'value':>10s} {'t_f':>8s} {'change':>8s}")
        for r in sens:
            lines.append(f"  {r['parameter']:24s} {r['factor']:6.2f} {r['value']:10.5f} "
                         f"{r['t_f_continuous_s']:8.4f} {r['t_f_continuous_s'] - m['t_f_continuous_s']:+8.4f}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m flexarm.trajectory",
                                 description="Solve the minimum-time straight-line slew and write the 1 ms file.")
    ap.add_argument("--params", default=None, help="parameter file (default: the committed Sandia arm)")
    ap.add_argument("--payload", type=float, default=None, help="tip payload, kg (default: the file's)")
    ap.add_argument("--intervals", type=int, default=200, help="collocation intervals (default 200)")
    ap.add_argument("--degree", type=int, default=5, help="Radau points per interval (default 5)")
    ap.add_argument("--out", default=str(DEFAULT_TRAJECTORY_FILE), help="output .npz (a .json sidecar is written)")
    ap.add_argument("--plot", default=None, help="also write this PNG")
    ap.add_argument("--sensitivity", action="store_true",
                    help="also solve with stator mass and rotor-2 inertia at ±20 %% (stored in the metadata)")
    ap.add_argument("--quiet", action="store_true", help="no IPOPT output")
    args = ap.parse_args(argv)
    try:
        params = load_parameters(args.params, payload_mass=args.payload)
        result = solve_minimum_time(params, n_intervals=args.intervals, degree=args.degree, verbose=not args.quiet)
        replay = verify_against_plant(result, params)
        result.metadata["plant_replay"] = {k: v for k, v in replay.items() if k != "states"}
        result.metadata["constraints"] = check_constraints(result, params)
        sens = None
        if args.sensitivity:
            sens = sensitivity(result, params, verbose=not args.quiet)
            result.metadata["sensitivity"] = sens
    except TrajectoryError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    json_path = save_trajectory(result, args.out)
    print(f"wrote {args.out} and {json_path}")
    if args.plot:
        print(f"wrote {plot_trajectory(result, args.plot, params)}")
    print(_report(result, replay, sens))
    return 0


if __name__ == "__main__":
    sys.exit(main())
