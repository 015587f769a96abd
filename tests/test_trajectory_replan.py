"""FATROP's re-plan on the stage form (flexarm.trajectory.stage_form): the same NLP as IPOPT's, the same answer.

The stage form is the full NLP with θ̇ and θ̈ eliminated: the committed solution must satisfy it, its vectors
must map to and from a collocation solution without loss, and FATROP's re-plan for a payload must land on
the file IPOPT solved (the same parameters, from the file's primal point alone).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from flexarm import load_parameters
from flexarm.trajectory import TrajectoryError, load_trajectory, replan_minimum_time
from flexarm.trajectory.stage_form import StageForm, stage_nlp
from flexarm.trajectory.warm import solution_from_trajectory


@pytest.fixture(scope="module")
def committed():
    params = load_parameters()
    return params, solution_from_trajectory(load_trajectory(), params)


def test_the_committed_solution_satisfies_the_stage_form_and_maps_back(committed):
    params, sol = committed
    N, d = sol.n_intervals, sol.degree
    nlp, dims, lbg, ubg = stage_nlp(params, N, d)
    form = StageForm(None, N, d, 8, lbg, ubg)
    x = form.point(sol, params)
    assert x.size == sum(dims["nx"]) + sum(dims["nu"]) and nlp["g"].shape[0] == sum(dims["nx"][1:]) + sum(dims["ng"])
    g = np.asarray(ca.Function("g", [nlp["x"], nlp["p"]], [nlp["g"]])(x, form.parameters(params))).ravel()
    # The file's 1 ms samples rebuild the optimiser's point to about 3e-11 rad (tests/test_trajectory_warm.py);
    # the stage form's dynamics rows multiply angles by (N·D)² ≈ 1e6 per interval (θ'' by the collocation's
    # linear maps) and by t_f²: 2e-7 measured, against residuals of order 1 away from the solution.
    assert np.maximum(np.maximum(lbg - g, g - ubg), 0.0).max() < 1e-6
    lbx, ubx = form.bounds(params)
    assert np.all(x >= lbx - 1e-9) and np.all(x <= ubx + 1e-9)
    back = form.solution(x, params, {})
    assert back.t_f == sol.t_f and np.array_equal(back.u, sol.u)
    np.testing.assert_allclose(back.theta, sol.theta, rtol=0, atol=1e-14)  # the same numbers, regrouped
    # θ̇ at the points: the derivative of the interval's polynomial through θ (the file's rebuild fits θ and θ̇
    # as separate polynomials: they agree to the rebuild's accuracy, scaled by N·D ≈ 1e3)
    np.testing.assert_allclose(back.omega, sol.omega, rtol=0, atol=1e-6 * np.abs(sol.omega).max())


def test_fatrop_replans_the_committed_parameters_back_to_the_committed_file(committed):
    """The committed file was solved by IPOPT on the full NLP. FATROP on the stage form, started from the file's
    primal point (no multipliers) for the same parameters, must land on it: the same NLP solved to tol 1e-8 by
    two methods. The continuous t_f agrees to 1e-6 s (it moves by about 3e-8 s between FATROP's starts) and the
    whole-ms t_f exactly. The torques: τ1 sits on its limit 93 % of the slew (bang-bang), so the optimum pins
    it: within 1e-3 of the limit (measured 2.8e-5). τ2 is never on its limit and reaches the objective only
    through the regulariser reg·Σ(Δu)², reg = 1e-4 s: at the solvers' KKT tolerance 1e-8 it is determined to
    about sqrt(1e-8 / 1e-4) = 1e-2 of its limit (measured 2.4e-3)."""
    params, _ = committed
    file = load_trajectory()
    fatrop = replan_minimum_time(params, file)
    assert fatrop.metadata["solver"]["name"].startswith("FATROP")
    _lands_on_the_committed_file(fatrop, params, file, 1e-6)


def _lands_on_the_committed_file(result, params, file, t_f_tolerance: float) -> None:
    """The bounds of the test above (their reasons are there)."""
    assert result.t_f == file.t_f
    assert abs(result.metadata["t_f_continuous_s"] - file.metadata["t_f_continuous_s"]) < t_f_tolerance
    assert np.all(np.abs(result.tau - file.tau).max(axis=0) < np.array([1e-3, 1e-2]) * params.torque_limit)
    # the angles follow τ2: measured 1.5e-4 rad for its 2.4e-3; bounded in proportion to its bound
    assert np.abs(result.theta - file.theta).max() < 1e-3  # rad
    assert np.all(np.abs(result.tau) <= params.torque_limit * (1 + 1e-6))


def test_fatrop_solves_cold_from_the_rigid_warm_up_to_the_committed_file(committed):
    """The cold solve with FATROP (issue 32 item 1: a cold solve within 60 CPU-s; IPOPT's takes about three times
    that): IPOPT's rigid warm-up, interpolated onto the flexible grid, then FATROP's two stages. It starts far from
    the file (rigid links, t_f of the rigid arm) and must land on it as the re-plan does. The continuous t_f: the
    solvers stop at different points of the same flat optimum (τ2 is fixed only by the regulariser, above): from
    the file's own point FATROP stays within 3e-8 s of it (bound 1e-6 s above), from the rigid start it ends
    9.6e-7 s away (measured), so 2e-6 s here; the whole-ms t_f, which is what the file holds, is identical."""
    from flexarm.trajectory.solve import solve_minimum_time_fatrop

    params, _ = committed
    file = load_trajectory()
    cold = solve_minimum_time_fatrop(params)
    stages = cold.metadata["solver"]["stages"]
    assert [s["label"] for s in stages] == ["rigid two-link", "flexible, t_f free",
                                            "flexible, t_f rounded up to whole ms"]
    assert "FATROP" in cold.metadata["solver"]["name"] and "IPOPT's rigid warm-up" in cold.metadata["solver"]["name"]
    _lands_on_the_committed_file(cold, params, file, 2e-6)


def test_a_start_on_another_grid_is_refused(committed):
    params, sol = committed
    form = StageForm(None, 100, 5, 8, np.zeros(0), np.zeros(0))
    with pytest.raises(TrajectoryError, match="N = 100, d = 5"):
        form.point(sol, params)


def test_the_command_line_replan_never_writes_over_the_committed_file(capsys):
    from flexarm.trajectory.report import main

    with pytest.raises(SystemExit) as exc:
        main(["--replan", "--payload", "0.275"])
    assert exc.value.code == 2 and "--replan: give --out FILE" in capsys.readouterr().err


def test_the_command_line_replan_refuses_another_grid_instead_of_ignoring_it(capsys, tmp_path):
    """--intervals / --degree with --replan: the re-plan keeps the committed file's grid, so another one is an
    error (exit 1, nothing written), before any solver is made."""
    from flexarm.trajectory.report import main

    out = tmp_path / "slew.npz"
    assert main(["--replan", "--intervals", "100", "--out", str(out)]) == 1
    assert "keeps its start's grid (N = 200, d = 5); asked for N = 100, d = 5" in capsys.readouterr().err
    assert not out.exists()

