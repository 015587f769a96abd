"""The committed slew, rebuilt from its 1 ms file, is the collocation NLP's solution (no solve: cheap).

This is what a re-plan warm-starts from, and the check that a faster formulation or solver
setting still describes the committed optimum: the NLP's constraints hold at it to IPOPT's
tolerance, and sampling it again gives the file back.
"""

import numpy as np
import pytest

pytest.importorskip("casadi")

from flexarm import load_parameters  # noqa: E402
from flexarm.trajectory import LINE_TOLERANCE, load_trajectory, sample_solution  # noqa: E402
from flexarm.trajectory.warm import nlp_residuals, solution_from_trajectory  # noqa: E402


@pytest.fixture(scope="module")
def rebuilt():
    params = load_parameters()
    traj = load_trajectory()
    return params, traj, solution_from_trajectory(traj, params)


def test_rebuilt_solution_satisfies_the_nlp(rebuilt):
    params, traj, sol = rebuilt
    res = nlp_residuals(params, sol)
    # IPOPT stopped at a constraint violation of 5.4e-9 (tol 1e-8 on its scaled problem); the
    # rebuild adds rounding of a least-squares fit (~1e-11 rad). 1e-7 is well above both and far
    # below what a wrong model or payload gives (the dynamics rows are of order 1 N·m).
    assert res["equality"] < 1e-7
    # IPOPT relaxes every bound by its bound_relax_factor, 1e-8 (absolute for bounds below 1)
    assert res["line_m"] <= LINE_TOLERANCE + 1e-8
    assert res["final_acceleration"] < 1e-7
    assert res["rate_excess"] < 1e-9
    assert sol.t_f == traj.t_f


def test_rebuilt_solution_resamples_to_the_file(rebuilt):
    params, traj, sol = rebuilt
    again = sample_solution(params, sol)
    # the fit recovers the polynomials to rounding: 1e-9 rad, 1e-7 N·m are far below any
    # figure the project reports (0.001 deg, 0.001 N·m)
    assert np.abs(again.theta - traj.theta).max() < 1e-9
    assert np.abs(again.omega - traj.omega).max() < 1e-7
    assert np.abs(again.tau - traj.tau).max() < 1e-7


def test_rebuilt_solution_is_not_the_loaded_arms(rebuilt):
    """The residual check can fail: the same motion violates the dynamics with a 0.275 kg payload."""
    params, _, sol = rebuilt
    assert nlp_residuals(params.with_payload(0.275), sol)["equality"] > 1e-3


def test_one_nlp_serves_cold_and_warm_solves_and_payloads():
    """The NLP is built once per structure: a warm re-solve and another payload reuse it."""
    from flexarm.trajectory import problem

    params = load_parameters()
    problem._NLP_CACHE.clear()
    cold = problem.solve_collocation(params, problem.RIGID_GROUPS, 20, 3, verbose=False)
    warm = problem.solve_collocation(params.with_payload(0.275), problem.RIGID_GROUPS, 20, 3, guess=cold,
                                     verbose=False)
    (entry,) = problem._NLP_CACHE.values()
    assert len(entry["solvers"]) == 2  # cold options and warm-start options, one NLP
    # the payload is a parameter, not a constant of the NLP: it moves the optimum (more inertia, slower)
    assert warm.t_f > cold.t_f * 1.001
    assert warm.stats["iterations"] < cold.stats["iterations"]
