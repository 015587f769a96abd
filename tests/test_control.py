"""The tracking control law: reconstruction, saturation, modes, the hold after the slew, closed loop."""

import numpy as np
import pytest

from flexarm import ArmModel, load_parameters, rigid_configuration
from flexarm.control import PEAK_TORQUE, ControllerError, TrackingController, simulate_closed_loop, tracking_errors
from flexarm.integrator import simulate
from flexarm.lqr import GainSchedule, default_trajectory_path, design_schedule, desired_states, trajectory_from_states
from flexarm.model import N, joint_angles, joint_velocities, reconstruct_angles, strain_gauge_angles
from flexarm.modes import modal_analysis

PAYLOAD = 0.275


@pytest.fixture(scope="module")
def model():
    return ArmModel()


@pytest.fixture(scope="module")
def synthetic(model):
    """Stand-in trajectory (the plant under a smooth torque profile) and a γ = 0.1 schedule on it."""
    n = 600
    t = np.arange(n + 1) * 1e-3
    s = t / t[-1]
    window = np.sin(np.pi * s) ** 2
    tau = np.column_stack([4.0 * np.sin(2 * np.pi * s) * window, -0.8 * np.sin(2 * np.pi * s) * window])
    tau[-1] = 0.0
    z0 = np.r_[rigid_configuration(-0.9, 1.6), np.zeros(N)]
    traj = trajectory_from_states(t, tau, simulate(model, z0, tau[:-1]))
    return traj, design_schedule(model, traj, "gamma0.1", "200ms")


def sensors(z):
    th, om = z[:N], z[N:]
    return joint_angles(th), joint_velocities(om), strain_gauge_angles(th)


def test_reconstruction_returns_true_angles_to_bracket_deflection(model, synthetic):
    """Noiseless sensors of simulated states give the 11 angles up to the (µrad) bracket deflections."""
    traj, _ = synthetic
    # add the link modes so the gauges have something to read
    modes = modal_analysis(model, desired_states(traj)[300, :N])
    worst = 0.0
    for z in desired_states(traj)[::50]:
        th = z[:N] + 0.01 * modes.shapes[:, modes.link_mode(2)] / np.abs(modes.shapes[:, modes.link_mode(2)]).max()
        q, _, eps = sensors(np.r_[th, z[N:]])
        rec = reconstruct_angles(q, eps)
        brackets = np.array([th[1] - th[0], th[5] - th[4], th[7] - th[6]])
        worst = max(worst, np.abs(rec - th).max())
        # error is exactly the accumulated bracket deflections
        assert np.abs(rec - th).max() <= np.abs(brackets).sum() + 1e-12
    assert worst < 2e-5  # rad: bracket springs deflect by a few µrad
    # on the stand-in trajectory (a real plant run, brackets loaded) too
    for z in desired_states(traj):
        q, _, eps = sensors(z)
        assert np.abs(reconstruct_angles(q, eps) - z[:N]).max() < 2e-5


def test_error_is_zero_on_the_trajectory(synthetic):
    traj, sched = synthetic
    for omega7 in ("tachometer", "rigid"):
        c = TrackingController(traj, sched, omega7=omega7)
        for k in (0, 123, 599, 600, 900):
            e = c.error_estimate(k, *sensors(desired_states(traj)[min(k, traj.n_samples)]))
            assert np.abs(e).max() < 1e-12
            assert np.count_nonzero(e[N:]) == 0


def test_velocity_error_interpretation(synthetic):
    traj, sched = synthetic
    q, qd, eps = sensors(desired_states(traj)[100])
    qd_err = np.array([0.01, -0.02])
    e_t = TrackingController(traj, sched).error_estimate(100, q, qd + qd_err, eps)
    e_r = TrackingController(traj, sched, omega7="rigid").error_estimate(100, q, qd + qd_err, eps)
    assert np.isclose(e_t[N], 0.01) and np.isclose(e_t[N + 6], -0.02)
    assert np.isclose(e_r[N + 6], -0.01)
    assert np.count_nonzero(e_t[N:]) == 2


def test_error_estimate_is_the_reconstruction_error(synthetic):
    """The precomputed linear estimator equals eqs. 21-31 applied to measured and desired sensor values."""
    traj, sched = synthetic
    rng = np.random.default_rng(3)
    c = TrackingController(traj, sched)
    for k in (0, 250, 599):
        q_d, qd_d, eps_d = sensors(desired_states(traj)[k])
        q, qd, eps = q_d + rng.normal(size=2), qd_d + rng.normal(size=2), eps_d + rng.normal(scale=1e-2, size=6)
        e = c.error_estimate(k, q, qd, eps)
        assert np.allclose(e[:N], reconstruct_angles(q, eps) - reconstruct_angles(q_d, eps_d), atol=1e-14)
        tau = c.torque_at(k, q, qd, eps)
        unsat = c.feedforward(k) - c.gain(k) @ e
        assert np.allclose(tau, np.clip(unsat, -np.array(PEAK_TORQUE), PEAK_TORQUE), rtol=1e-12, atol=1e-12)
        assert np.array_equal(c.torque_from_measurements(k, np.concatenate([q, qd, eps])), tau)
    with pytest.raises(ControllerError, match="measurements: expected 10 finite"):
        c.torque_from_measurements(0, [0.0] * 9 + [np.nan])


def test_feedforward_only_replays_trajectory_torques(synthetic):
    traj, _ = synthetic
    c = TrackingController(traj, None, mode="ff", saturation=None)
    rng = np.random.default_rng(0)
    for k in range(traj.n_samples):
        q, qd, eps = rng.normal(size=2), rng.normal(size=2), rng.normal(size=6)  # ignored
        assert np.array_equal(c.torque_at(k, q, qd, eps), traj.tau[k])
    assert np.array_equal(c.torque(0.2, q, qd, eps), traj.tau[200])


def test_hold_after_slew(synthetic):
    traj, sched = synthetic
    c = TrackingController(traj, sched)
    zf = desired_states(traj)[-1]
    for k in (traj.n_samples, traj.n_samples + 1, traj.n_samples + 5000):
        assert np.array_equal(c.feedforward(k), np.zeros(2))
        assert np.array_equal(c.desired_state(k), zf)
        assert np.allclose(c.torque_at(k, *sensors(zf)), 0.0, atol=1e-12)
        assert np.array_equal(c.gain(k), c.gain(traj.n_samples))
    # an error after the slew is fed back against the final state with the last gain set
    q, qd, eps = sensors(zf)
    tau = c.torque_at(traj.n_samples + 10, q + np.array([0.01, 0.0]), qd, eps)
    assert np.allclose(tau, -c.gain(traj.n_samples) @ c.error_estimate(traj.n_samples, q + [0.01, 0.0], qd, eps))
    assert np.abs(tau).max() > 0


def test_saturation_never_exceeded(synthetic):
    traj, sched = synthetic
    limits = np.array([7.0, 2.25])
    c = TrackingController(traj, sched, saturation=limits)
    rng = np.random.default_rng(2)
    hit = np.zeros(2, dtype=bool)
    for k in rng.integers(0, 800, size=400):
        q, qd, eps = sensors(desired_states(traj)[min(k, traj.n_samples)])
        tau = c.torque_at(int(k), q + rng.normal(scale=2.0, size=2), qd + rng.normal(scale=20, size=2),
                          eps + rng.normal(scale=0.5, size=6))
        assert np.all(np.abs(tau) <= limits)
        hit |= np.isclose(np.abs(tau), limits)
    assert hit.all()  # the limits were actually active
    small = TrackingController(traj, sched, saturation=(0.5, 0.1))
    assert np.all(np.abs(small.torque_at(100, *sensors(desired_states(traj)[0]))) <= [0.5, 0.1])


def test_feedback_only_has_no_feedforward(synthetic):
    traj, sched = synthetic
    c = TrackingController(traj, sched, mode="fb")
    assert np.allclose(c.torque_at(100, *sensors(desired_states(traj)[100])), 0.0)
    assert np.array_equal(c.feedforward(100), np.zeros(2))


def test_bad_settings_are_rejected(synthetic):
    traj, sched = synthetic
    with pytest.raises(ControllerError, match="mode"):
        TrackingController(traj, sched, mode="pid")
    with pytest.raises(ControllerError, match="schedule"):
        TrackingController(traj, None, mode="ff+fb")
    with pytest.raises(ControllerError, match="saturation"):
        TrackingController(traj, sched, saturation=(7.0, -1.0))
    with pytest.raises(ControllerError, match="omega7"):
        TrackingController(traj, sched, omega7="estimate")
    c = TrackingController(traj, sched)
    with pytest.raises(ControllerError, match="strain"):
        c.torque_at(0, [0, 0], [0, 0], [0, 0, 0])
    with pytest.raises(ControllerError, match="t: must be"):
        c.torque(-1.0, [0, 0], [0, 0], np.zeros(6))


def test_closed_loop_beats_feedforward_with_payload_synthetic(synthetic):
    """Unit-level version on the stand-in trajectory: γ = 0.1 feedback reduces the payload error."""
    traj, sched = synthetic
    plant = ArmModel(load_parameters().with_payload(PAYLOAD))
    ff = tracking_errors(simulate_closed_loop(plant, TrackingController(traj, None, mode="ff"))[0], traj)
    fb = tracking_errors(simulate_closed_loop(plant, TrackingController(traj, sched))[0], traj)
    assert fb["pos_rms"] < ff["pos_rms"]


REAL = default_trajectory_path()


@pytest.mark.skipif(not REAL.exists(), reason=f"the minimum-time trajectory {REAL} is missing "
                                              "(produced by python -m flexarm.trajectory)")
def test_closed_loop_beats_feedforward_with_payload():
    """Acceptance: library plant, 1 ms, no noise, 0.275 kg payload, γ = 0.1, 200 ms schedule."""
    plant = ArmModel(load_parameters().with_payload(PAYLOAD))
    try:
        sched = GainSchedule.load("gamma0.1", "200ms")
    except ValueError:
        sched = design_schedule(ArmModel(), REAL, "gamma0.1", "200ms")
    ff_ctrl = TrackingController(REAL, None, mode="ff")
    states_ff, _ = simulate_closed_loop(plant, ff_ctrl)
    states_fb, tau_fb = simulate_closed_loop(plant, TrackingController(REAL, sched))
    assert len(states_fb) == ff_ctrl.n_steps + 1  # no divergence
    ff = tracking_errors(states_ff, REAL)
    fb = tracking_errors(states_fb, REAL)
    assert fb["pos_rms"] < ff["pos_rms"]
    assert np.all(np.abs(tau_fb) <= [7.0, 2.25])
