"""LQR gain design: Riccati residuals, closed-loop stability, weights, schedules and gain files."""

import json

import numpy as np
import pytest

from flexarm import ArmModel, rigid_configuration
from flexarm.integrator import simulate
from flexarm.lqr import (
    DEFAULT_GAIN_DIR,
    GAIN_SET_NAMES,
    GainError,
    GainSchedule,
    canonical_name,
    design_gain,
    design_schedule,
    effective_gain,
    file_sha256,
    measurement_map,
    operating_times,
    reduce_gain,
    riccati_residual,
    state_weight,
    trajectory_from_states,
)
from flexarm.model import N, joint_angles, joint_velocities, reconstruct_angles, strain_gauge_angles

RES_TOL = 1e-8  # relative Riccati residual, definition in flexarm.lqr's docstring


@pytest.fixture(scope="module")
def model():
    return ArmModel()


@pytest.fixture(scope="module")
def rest_point():
    return np.r_[rigid_configuration(-0.9, 1.0), np.zeros(N)]


def synthetic_trajectory(model, n_steps=600):
    """A stand-in 'desired trajectory': the plant driven by a smooth torque profile (unit tests only)."""
    t = np.arange(n_steps + 1) * 1e-3
    s = t / t[-1]
    window = np.sin(np.pi * s) ** 2
    tau = np.column_stack([4.0 * np.sin(2 * np.pi * s) * window, -0.8 * np.sin(2 * np.pi * s) * window])
    tau[-1] = 0.0
    z0 = np.r_[rigid_configuration(-0.9, 1.6), np.zeros(N)]
    return trajectory_from_states(t, tau, simulate(model, z0, tau[:-1]))


@pytest.mark.parametrize("name", GAIN_SET_NAMES)
def test_gain_solves_riccati_and_stabilises(model, rest_point, name):
    d = design_gain(model, rest_point, state_weight(name), discrete=name.startswith("dlqr-"))
    assert d.residual < RES_TOL
    assert d.residual_scaled < RES_TOL
    if name.startswith("dlqr-"):
        assert d.rho_full < 1.0
    else:
        assert d.max_real_full < 0.0


def test_residual_measure_detects_a_wrong_solution(model, rest_point):
    A, B = model.linearize(rest_point)
    Q, R = state_weight("gamma0.1"), 10 * np.eye(2)
    d = design_gain(model, rest_point, Q)
    assert riccati_residual(A, B, Q, R, d.P) < RES_TOL
    rng = np.random.default_rng(0)
    E = rng.normal(size=d.P.shape)
    wrong = d.P + 1e-8 * np.abs(d.P).max() * (E + E.T)
    assert riccati_residual(A, B, Q, R, wrong) > 1e-6
    assert np.allclose(d.K, np.linalg.solve(R, B.T @ d.P), rtol=1e-9, atol=1e-9 * np.abs(d.K).max())


def test_gain_magnitudes_follow_gamma(model, rest_point):
    """Paper: 10-100 for γ = 1, 1-10 for 0.1, below 1 for 0 (we only check the ordering and γ = 0)."""
    mags = [np.abs(design_gain(model, rest_point, state_weight(n)).K).max() for n in ("gamma1", "gamma0.1", "gamma0")]
    assert mags[0] > mags[1] > mags[2]
    assert mags[2] < 1.0


def test_weights():
    q = np.diag(state_weight("eq32"))
    assert np.all(q[:N] == 10) and q[N] == 80 and q[N + 6] == 4
    assert np.all(q[N + 1:N + 6] == 0.8) and np.all(q[N + 7:] == 0.8)
    assert np.all(np.diag(state_weight("gamma0.1"))[N:] == 0.1)
    assert canonical_name("dlqr") == "dlqr-gamma0.1"
    with pytest.raises(GainError, match="gain set name"):
        state_weight("gamma-1")
    with pytest.raises(GainError, match="gain set name"):
        state_weight("lqr")


def test_reduce_gain_keeps_measured_velocity_columns():
    K = np.ones((2, 2 * N))
    Kr = reduce_gain(K)
    assert np.all(Kr[:, :N] == 1) and np.all(Kr[:, [N, N + 6]] == 1)
    assert np.count_nonzero(Kr[:, N:]) == 4


def test_measurement_map_matches_the_sensors():
    rng = np.random.default_rng(1)
    z = rng.normal(size=2 * N)
    C = measurement_map("tachometer")
    th, om = z[:N], z[N:]
    xh = C @ z
    assert np.allclose(xh[:N], reconstruct_angles(joint_angles(th), strain_gauge_angles(th)))
    assert np.isclose(xh[N], joint_velocities(om)[0]) and np.isclose(xh[N + 6], joint_velocities(om)[1])
    assert np.isclose((measurement_map("rigid") @ z)[N + 6], joint_velocities(om).sum())
    assert effective_gain(np.ones((2, 2 * N))).shape == (2, 2 * N)


def test_operating_times():
    assert np.allclose(operating_times(2.058, "200ms"), np.arange(11) * 0.2)
    assert len(operating_times(2.058, "20ms")) == 103
    assert np.allclose(operating_times(2.058, "single"), [1.029])
    with pytest.raises(GainError, match="schedule"):
        operating_times(2.0, "1s")


def test_schedule_roundtrip_and_lookup(model, tmp_path):
    traj = synthetic_trajectory(model)
    s = design_schedule(model, traj, "gamma0.1", "200ms")
    assert np.allclose(s.times, [0.0, 0.2, 0.4, 0.6])
    assert np.all(s.residuals < RES_TOL)
    assert np.all(s.max_real_full < 0)
    path = s.save(tmp_path)
    assert path.name == "gamma0.1_200ms.npz"
    back = GainSchedule.load("gamma0.1", "200ms", tmp_path)
    assert np.array_equal(back.gains, s.gains)
    assert back.metadata["npz_sha256"] == file_sha256(path)
    assert back.index_at(0.0) == 0 and back.index_at(0.1999) == 0 and back.index_at(0.2) == 1
    assert back.index_at(5.0) == 3
    assert np.count_nonzero(back.gain_at(0.3)[:, N:]) <= 4
    with pytest.raises(GainError, match="does not exist"):
        GainSchedule.load("gamma1", "200ms", tmp_path)


# -- the committed gain files (made from the real trajectory) -------------------------
COMMITTED = sorted(DEFAULT_GAIN_DIR.glob("*.json")) if DEFAULT_GAIN_DIR.exists() else []


@pytest.mark.skipif(not COMMITTED, reason="no committed gain files in flexarm/data/gains "
                                          "(run python -m flexarm.lqr --write once the trajectory exists)")
@pytest.mark.parametrize("json_path", COMMITTED, ids=lambda p: p.stem)
def test_committed_gain_files(json_path):
    meta = json.loads(json_path.read_text())
    s = GainSchedule.load(meta["name"], meta["schedule"])
    assert s.metadata["npz_sha256"] == file_sha256(DEFAULT_GAIN_DIR / meta["npz_file"])
    assert np.all(s.residuals < RES_TOL)
    if not s.discrete:
        assert np.all(s.max_real_full < 0)
    assert len(meta["trajectory_sha256"]) == 64 and len(meta["parameter_sha256"]) == 64


@pytest.mark.skipif(not COMMITTED, reason="no committed gain files")
def test_committed_gains_recompute(model):
    """Re-solving one committed operating point from its stored state gives the stored gain."""
    s = GainSchedule.load("gamma0.1", "200ms")
    k = len(s.times) // 2
    d = design_gain(model, s.operating_points[k], s.Q, s.R)
    assert d.residual < RES_TOL
    assert np.allclose(d.K, s.gains[k], rtol=1e-6, atol=1e-8 * np.abs(d.K).max())
