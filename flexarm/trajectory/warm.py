"""The optimiser's solution recovered from a 1 ms trajectory file, to warm-start a re-plan from it.

The file holds the collocation polynomials of θ and θ̇ evaluated every 1 ms and the exact
1 ms means of the piecewise-linear torque (docs/trajectory.md). Each collocation interval
(≈10.3 ms) holds about 10 samples of a polynomial of degree d = 5, so a least-squares fit
per interval gives back its values at the collocation points to rounding; the torque at the
nodes follows from the 1 ms means by linear least squares. The result is the primal point of
the collocation NLP that made the file (no multipliers: the file does not hold them).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..parameters import ArmParameters
from .io import TrajectoryError, TrajectoryResult
from .problem import (
    DEFAULT_REGULARISATION,
    FLEX_GROUPS,
    TORQUE_RATE_LIMIT,
    CollocationSolution,
    ReducedModel,
    _lagrange_basis,
    _radau,
    collocation_times,
    nlp_expressions,
    nlp_parameters,
)


def solution_from_trajectory(result: TrajectoryResult, params: ArmParameters) -> CollocationSolution:
    """Rebuild the collocation solution (flexible model) from a trajectory's 1 ms samples.

    Parameters
    ----------
    result : TrajectoryResult
        A file written by :func:`flexarm.trajectory.save_trajectory` (its metadata name the
        discretisation: ``intervals``, ``degree``).
    params : ArmParameters
        The parameters it was solved for (torque limits).

    Raises
    ------
    TrajectoryError
        The metadata lack the discretisation, or an interval holds fewer samples than the
        polynomial has coefficients.
    """
    disc = result.metadata.get("discretisation", {})
    try:
        N, d = int(disc["intervals"]), int(disc["degree"])
    except KeyError as exc:
        raise TrajectoryError(f"trajectory metadata lack discretisation {exc}: cannot rebuild its solution") from exc
    t_f, t = result.t_f, result.t
    tau_c, D = _radau(d)
    sn = t / t_f
    k = np.minimum((sn * N).astype(int), N - 1)  # interval of each sample, as CollocationSolution.sample
    loc = sn * N - k
    basis = _lagrange_basis(tau_c, loc)
    M = N * d
    theta = np.empty((M + 1, result.theta.shape[1]))
    omega = np.empty_like(theta)
    theta[0], omega[0] = result.theta[0], result.omega[0]
    for i in range(N):
        rows = np.nonzero(k == i)[0]
        if len(rows) < d + 1:
            raise TrajectoryError(f"interval {i} holds {len(rows)} samples, fewer than the {d + 1} needed")
        coef, *_ = np.linalg.lstsq(basis[rows], np.hstack([result.theta[rows], result.omega[rows]]), rcond=None)
        theta[1 + i * d:1 + (i + 1) * d] = coef[1:, :theta.shape[1]]
        omega[1 + i * d:1 + (i + 1) * d] = coef[1:, theta.shape[1]:]
    # θ̈ at the collocation points: the collocation of θ̇ (h θ̈_j = Σ_r D[r, j] θ̇_r)
    h = t_f / N
    om_int = np.concatenate([omega[0:M:d][:, None], omega[1:].reshape(N, d, -1)], axis=1)  # (N, d+1, 11)
    alpha = np.vstack([np.zeros((1, omega.shape[1])), np.einsum("krn,rj->kjn", om_int, D).reshape(M, -1) / h])
    # torque at the nodes: the file's 1 ms means are linear in them
    n_steps = result.n_samples
    lim = np.asarray(params.torque_limit)
    A = np.empty((n_steps, N + 1))
    for j in range(0, N + 1, 2):
        unit = np.zeros((N + 1, 2))
        unit[j, 0] = 1.0
        if j + 1 <= N:
            unit[j + 1, 1] = 1.0
        probe = CollocationSolution(FLEX_GROUPS, N, d, t_f, np.zeros(0), theta, omega, alpha, unit, None, None, None,
                                    {})
        means = probe.torque_samples(np.ones(2), n_steps)
        A[:, j] = means[:, 0]
        if j + 1 <= N:
            A[:, j + 1] = means[:, 1]
    u, *_ = np.linalg.lstsq(A, result.tau[:-1] / lim, rcond=None)
    red = ReducedModel.build(params, FLEX_GROUPS)
    # node 0 (at rest, undeformed): M a = B̄τ, as solve_collocation records it
    th0 = red.reduce(theta[0])
    a0 = np.linalg.solve(red.mass_coefficients * np.cos(th0[:, None] - th0[None, :]), red.input_matrix @ (u[0] * lim))
    alpha[0] = red.T @ a0
    s = collocation_times(N, d)
    return CollocationSolution(groups=red.groups, n_intervals=N, degree=d, t_f=t_f, s=s, theta=theta, omega=omega,
                               alpha=alpha, u=u, x=None, lam_x=None, lam_g=None,
                               stats={"label": "rebuilt from the 1 ms file", "t_fixed": t_f})


def flexible_guess(sol: CollocationSolution, n_intervals: int, degree: int) -> CollocationSolution:
    """Any collocation solution (the rigid warm-up's) interpolated onto the flexible grid, as a start for FATROP.

    The element angles, rates and accelerations at the new grid's points and the torque at its nodes, linearly
    interpolated in normalised time (:meth:`CollocationSolution.interpolate`); no multipliers. Groups: the flexible
    model's (the rigid solution's links are straight: no deformation to start from).
    """
    N, d = int(n_intervals), int(degree)
    s = collocation_times(N, d)
    at = sol.interpolate(s)
    return CollocationSolution(groups=tuple(FLEX_GROUPS), n_intervals=N, degree=d, t_f=sol.t_f, s=s,
                               theta=at["theta"], omega=at["omega"], alpha=at["alpha"],
                               u=sol.interpolate(np.linspace(0.0, 1.0, N + 1))["u"], x=None, lam_x=None, lam_g=None,
                               stats={"label": f"interpolated from '{sol.stats.get('label', 'a solution')}'"})


def nlp_residuals(params: ArmParameters, sol: CollocationSolution, regularisation: float = DEFAULT_REGULARISATION,
                  torque_rate_limit: float | None = TORQUE_RATE_LIMIT) -> dict:
    """The collocation NLP's constraints evaluated at a solution (no solve: one function evaluation).

    Returns
    -------
    dict
        ``equality``: largest |collocation and dynamics residual| (rad, rad/s·s, N·m);
        ``line_m``: largest distance of the tip from the line at the collocation points, m;
        ``final_acceleration``: largest |joint acceleration| at t_f (scaled as the NLP's row);
        ``rate_excess``: largest excess of a torque step over the slew-rate limit (0 when inside).
    """
    red = ReducedModel.build(params, sol.groups)
    N, d = sol.n_intervals, sol.degree
    nlp, n_eq, n_line, n_rate, _ = nlp_expressions(red, N, d, regularisation, torque_rate_limit)
    th, om, ac = (red.reduce(a[1:]).T for a in (sol.theta, sol.omega, sol.alpha))
    x = np.concatenate([th.ravel("F"), om.ravel("F"), ac.ravel("F"), sol.u.T.ravel("F"), [sol.t_f]])
    p = nlp_parameters(params, red, red.reduce(sol.theta[0]), free_time=False)
    g = np.asarray(ca.Function("g", [nlp["x"], nlp["p"]], [nlp["g"]])(x, p)).ravel()
    i = n_eq + n_line
    return {"equality": float(np.abs(g[:n_eq]).max()), "line_m": float(np.abs(g[n_eq:i]).max()),
            "final_acceleration": float(np.abs(g[i:i + 2]).max()),
            "rate_excess": float(max(0.0, g[i + 2:i + 2 + n_rate].max())) if n_rate else 0.0}
