"""The LQG's mathematics: Kalman gains, estimation-error covariance, delay predictor, anti-windup, files."""

import json
import shutil

import numpy as np
import pytest

from flexarm import ArmModel, rigid_configuration
from flexarm.gain_schedule import StaleDataError, trajectory_from_states
from flexarm.lqg import LqgController, LqgError
from flexarm.lqg_design import (
    DEFAULT_LQG_DIR,
    LqgDesign,
    design_point,
    measurement_covariance,
    measurement_matrix,
)
from flexarm.lqr_design import scaling_transform
from flexarm.model import N_STATE, N, joint_angles, joint_velocities, strain_gauge_angles
from flexarm.provenance import write_sealed_json
from flexarm.sensors import SensorSettings

TIP_SIGMA = 0.9  # N, about the committed design's payload force


@pytest.fixture(scope="module")
def model():
    return ArmModel()


@pytest.fixture(scope="module")
def rest():
    return np.r_[rigid_configuration(-0.9, 1.0), np.zeros(N)]


@pytest.fixture(scope="module")
def point(model, rest):
    return design_point(model, rest, np.zeros(2), measurement_covariance(), TIP_SIGMA)


def one_point_design(point, rest) -> LqgDesign:
    return LqgDesign(schedule="single", times=np.array([0.0]), operating_points=rest[None], tau_bar=np.zeros((1, 2)),
                     Phi=point.Phi[None], Gamma=point.Gamma[None], W=point.W[None], M=point.M[None],
                     P_prior=point.P_prior[None], P_post=point.P_post[None], K=point.K[None],
                     K_integral=point.K_integral[None], C=measurement_matrix(), V=measurement_covariance())


def resting_trajectory(rest, n=4000):
    return trajectory_from_states(np.arange(n + 1) * 1e-3, np.zeros((n + 1, 2)), np.tile(rest, (n + 1, 1)))


def doubling_dare(A, G, H, iterations=60):
    """X = AᵀX(I + GX)⁻¹A + H by the structure-preserving doubling algorithm (not scipy's Schur method)."""
    n = len(A)
    for _ in range(iterations):
        S = np.linalg.inv(np.eye(n) + G @ H)
        A, G, H = A @ S @ A, G + A @ S @ G @ A.T, H + A.T @ H @ S @ A
        G, H = 0.5 * (G + G.T), 0.5 * (H + H.T)
    return H


def test_measurement_matrix_is_the_sensor_map(rest):
    rng = np.random.default_rng(3)
    z = rest + rng.normal(scale=0.1, size=N_STATE)
    expect = np.r_[joint_angles(z[:N]), joint_velocities(z[N:]), strain_gauge_angles(z[:N])]
    assert np.allclose(measurement_matrix() @ z, expect, rtol=0, atol=1e-15)


def test_measurement_covariance_is_uniform_variance():
    s = SensorSettings.from_toml()
    V = np.diag(measurement_covariance(s))
    assert V[0] == pytest.approx(np.radians(s.encoder_noise_deg) ** 2 / 3)
    assert V[2] == pytest.approx(np.radians(s.tachometer_noise_deg_per_s) ** 2 / 3)
    assert V[9] == pytest.approx(np.radians(s.strain_gauge_noise_deg) ** 2 / 3)


def test_kalman_gain_matches_an_independent_dare_solution(model, rest, point):
    """Doubling algorithm on the filter DARE (in balanced coordinates, any similarity is exact)."""
    T = scaling_transform(model, rest)
    Ti = np.linalg.inv(T)
    Phi, C, W, V = Ti @ point.Phi @ T, measurement_matrix() @ T, Ti @ point.W @ Ti.T, measurement_covariance()
    P = doubling_dare(Phi.T, C.T @ np.linalg.solve(V, C), W)
    M = P @ C.T @ np.linalg.inv(C @ P @ C.T + V)
    M_lib = Ti @ point.M
    assert np.linalg.norm(M - M_lib) <= 1e-6 * np.linalg.norm(M)
    P_lib = Ti @ point.P_prior @ Ti.T
    assert np.linalg.norm(P - P_lib) <= 1e-6 * np.linalg.norm(P)
    # and the filter is stable: the error dynamics (I − MC)Φ inside the unit circle
    assert np.abs(np.linalg.eigvals((np.eye(N_STATE) - M @ C) @ Phi)).max() < 1.0


def test_lqr_gains_stabilise_the_sampled_model(point):
    for K in point.K:
        assert np.abs(np.linalg.eigvals(point.Phi - point.Gamma @ K)).max() < 1.0


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_delay_predictor_is_exact_for_the_linear_noise_free_loop(point, rest, delay):
    """With the filter started on the true state and exact measurements, the prediction equals the state."""
    design = one_point_design(point, rest)
    ctrl = LqgController(resting_trajectory(rest), design, "gamma0.1", delay, saturation=(0.05, 0.02))
    rng = np.random.default_rng(0)
    x = np.zeros(N_STATE)
    x[:N] = rng.normal(scale=2e-3, size=N)
    state = ctrl.initial_state()
    state.x_post = x.copy()
    history, worst, lag_error = [x.copy()], 0.0, 0.0
    saturated = 0
    for k in range(300):
        m = design.C @ (rest + history[max(k - delay, 0)])
        _, x_now = ctrl.estimate(state, k, m)
        worst = max(worst, np.abs(x_now - x).max() / np.abs(x).max())
        if delay:
            lag_error = max(lag_error, np.abs(history[max(k - delay, 0)] - x).max() / np.abs(x).max())
        tau, state = ctrl.step(state, k, m)
        saturated += int(np.any(np.abs(tau) >= np.array([0.05, 0.02])))
        x = design.Phi[0] @ x + design.Gamma[0] @ tau
        history.append(x.copy())
    assert worst < 1e-9
    assert saturated > 0  # the predictor uses the torques actually sent, saturated or not
    if delay:
        assert lag_error > 1e-3  # without the prediction the estimate would lag by this much


def test_estimation_error_covariance_matches_the_design(point, rest):
    """Noisy runs of the linear model with the design's process noise and the sensors' *uniform* noise.

    The error covariance of a linear filter depends on the noise covariances only, not on their
    distribution, so uniform noise of variance a²/3 must give the design's P⁺. Some filter modes
    decay slowly (|λ| up to 0.9999: lightly observed bracket modes), so one long run has few
    independent samples of them; instead 300 independent runs start with an error drawn from the
    stationary N(0, P⁺) and run 60 samples, and we compare the ensemble covariance at the end:
    300 independent samples estimate a variance to ±8 % (1σ), so we allow a factor 1.4 (5σ; the 22
    entries of one seed spread over 0.80-1.22).
    """
    from flexarm.lqg import LqgState

    design = one_point_design(point, rest)
    ctrl = LqgController(resting_trajectory(rest, 100), design, "gamma0.1", 0, saturation=(1e3, 1e3))
    rng = np.random.default_rng(11)
    w_val, w_vec = np.linalg.eigh(point.W)
    w_fac = w_vec * np.sqrt(np.clip(w_val, 0, None))
    p_val, p_vec = np.linalg.eigh(point.P_post)
    p_fac = p_vec * np.sqrt(np.clip(p_val, 0, None))
    a = np.sqrt(3 * np.diag(design.V))
    errors = []
    for _ in range(300):
        x_hat = np.zeros(N_STATE)
        x = x_hat - p_fac @ rng.normal(size=N_STATE)  # the true state: error x̂ − x ~ N(0, P⁺)
        state = LqgState(1, x_hat, np.zeros((1, 2)), np.zeros(2), True)  # posterior at 0, no torque sent at 0
        x = design.Phi[0] @ x + w_fac @ rng.normal(size=N_STATE)
        for k in range(1, 61):
            m = design.C @ (rest + x) + rng.uniform(-a, a)
            tau, state = ctrl.step(state, k, m)
            x_post_err = state.x_post - x
            x = design.Phi[0] @ x + design.Gamma[0] @ tau + w_fac @ rng.normal(size=N_STATE)
        errors.append(x_post_err)
    T = scaling_transform(ArmModel(), rest)  # compare in balanced coordinates: every entry the same scale
    Ti = np.linalg.inv(T)
    e = np.array(errors) @ Ti.T
    sample = e.T @ e / len(e)
    predicted = Ti @ point.P_post @ Ti.T
    ratio = np.diag(sample) / np.diag(predicted)
    assert np.all(ratio > 1 / 1.4) and np.all(ratio < 1.4), ratio
    assert np.trace(sample) / np.trace(predicted) == pytest.approx(1.0, rel=0.2)


def test_integral_action_freezes_while_saturated(point, rest):
    design = one_point_design(point, rest)
    ctrl = LqgController(resting_trajectory(rest), design, "gamma0.1", 0, integral_action=True,
                         saturation=(1e-3, 1e-3))
    state = ctrl.initial_state()
    m = design.C @ (rest + np.r_[np.full(N, 0.01), np.zeros(N)])  # a large error: a torque saturates
    for k in range(50):
        tau, state = ctrl.step(state, k, m)
        assert np.isclose(np.abs(tau[0]), 1e-3)
    assert np.all(state.xi == 0.0)
    free = LqgController(resting_trajectory(rest), design, "gamma0.1", 0, integral_action=True,
                         saturation=(1e3, 1e3))
    state = free.initial_state()
    small = design.C @ (rest + np.r_[np.full(N, 1e-5), np.zeros(N)])
    for k in range(50):
        _, state = free.step(state, k, small)
    assert np.all(np.abs(state.xi) > 0.0)


def test_bad_settings_are_refused(point, rest):
    design = one_point_design(point, rest)
    traj = resting_trajectory(rest)
    with pytest.raises(LqgError, match="loop_delay_samples"):
        LqgController(traj, design, "gamma0.1", 11)
    with pytest.raises(LqgError, match="loop_delay_samples"):
        LqgController(traj, design, "gamma0.1", 1.5)
    with pytest.raises(ValueError, match="gain_set"):
        LqgController(traj, design, "gamma7")
    ctrl = LqgController(traj, design, "gamma0.1")
    with pytest.raises(LqgError, match="measurements"):
        ctrl.step(ctrl.initial_state(), 0, np.zeros(9))
    with pytest.raises(LqgError, match="sample 0"):
        ctrl.step(ctrl.initial_state(), 3, np.zeros(10))


def test_committed_design_files_load_and_stale_ones_are_refused(tmp_path):
    if not (DEFAULT_LQG_DIR / "lqg_200ms.npz").exists():
        pytest.skip("LQG design files not generated (python -m flexarm.lqr --write)")
    d = LqgDesign.load("200ms")
    assert d.K.shape[1:] == (4, 2, N_STATE) and d.M.shape[1:] == (N_STATE, 10)
    for stem in ("lqg_200ms.npz", "lqg_200ms.json"):
        shutil.copy(DEFAULT_LQG_DIR / stem, tmp_path / stem)
    meta = json.loads((tmp_path / "lqg_200ms.json").read_text())
    write_sealed_json(tmp_path / "lqg_200ms.json", {**meta, "trajectory_sha256": "0" * 64})  # only the input stale
    with pytest.raises(StaleDataError, match="trajectory file"):
        LqgDesign.load("200ms", tmp_path)


def test_required_loop_delay_for_the_target_stepping():
    from flexarm.lqg import required_loop_delay, with_loop_delay

    assert required_loop_delay("gauss-seidel", 2) == 0
    assert required_loop_delay("jacobi", 2) == 2  # plant -> sensors -> controller -> plant
    assert required_loop_delay("jacobi", 1) == 1  # controller reads the plant directly
    assert with_loop_delay({"gain_set": "gamma0.1", "loop_delay_samples": 0}, "jacobi") == \
        {"gain_set": "gamma0.1", "loop_delay_samples": 2}
    with pytest.raises(LqgError, match="stepping"):
        required_loop_delay("parallel")
    with pytest.raises(LqgError, match="feedthrough_fmus"):
        required_loop_delay("jacobi", 0)
    # a Jacobi master stepping n ms delays by n samples per feedthrough FMU; Gauss-Seidel by none
    assert required_loop_delay("jacobi", 2, 4) == 8 and required_loop_delay("gauss-seidel", 2, 4) == 0
    assert with_loop_delay({}, "jacobi", 2, step_size=0.004) == {"loop_delay_samples": 8}
    assert with_loop_delay({}, "jacobi", 2, step_size=0.001) == {"loop_delay_samples": 2}
    with pytest.raises(LqgError, match="step_size"):
        with_loop_delay({}, "jacobi", 2, step_size=0.0015)
    with pytest.raises(LqgError, match="more than the predictor covers"):
        required_loop_delay("jacobi", 2, 6)


def test_process_noise_trades_noise_rejection_against_payload_absorption():
    """The committed filter (W holds the payload's tip force) absorbs the payload but passes noise on; a
    filter that trusts the model keeps noise out (issue 14's ≤ 2×) and lets the payload through."""
    from flexarm.lqg_tradeoff import FILTERS, tradeoff_row

    committed, trusting = tradeoff_row(*FILTERS[0]), tradeoff_row(*FILTERS[-1])
    assert trusting.payload_mass == 0.0
    assert trusting.noisy / trusting.quiet <= 2.0 < 10.0 < committed.noisy / committed.quiet
    assert committed.noisy < 0.05  # still the absolute level with noise
    assert committed.payload < 0.25 * trusting.payload
    assert max(committed.payload_peak_tau) < 7.0  # within the first joint's limit


@pytest.fixture(scope="module")
def payload_bank():
    from flexarm.lqg_bank import PayloadBank

    return PayloadBank.load()  # the committed bank (what controller_lqg's estimator = payload_bank runs)


def test_committed_payload_bank_is_what_its_command_designs(payload_bank):
    """The committed bank file regenerates from the committed parameters and trajectory
    (``python -m flexarm.lqr --write``): a fresh design equals it to rounding. The bound is 1e-7 of each
    array's peak (1e-6 for the prior covariance, the solution of an ill-conditioned Riccati equation): with
    the same NumPy/SciPy versions and single-threaded BLAS, another CPU reproduces the committed file to
    2.2e-8 (measured on M of the 0.025 kg filter), above the 1e-8 this test first had."""
    from flexarm.lqg_bank import DEFAULT_MASSES, design_bank
    from flexarm.parameters import load_parameters

    fresh = design_bank(load_parameters())
    assert tuple(payload_bank.masses) == DEFAULT_MASSES and payload_bank.quiet.mass == 0.0
    for new, old in zip(fresh.filters, payload_bank.filters):
        assert new.mass == old.mass
        # The quiet filter (last) trusts the model (process noise QUIET_SCALE times smaller): its Riccati
        # equation is worse conditioned even with the prescribed pole radius (M moves 1.5e-8 for a 1e-15
        # relative change of Phi, a condition number of about 1.5e7; across OpenBLAS kernels its M agrees to
        # 4e-8), so its bound is 1e-6 (the plain Kalman gain's M agreed only to 6e-6 and would fail it).
        quiet = old is payload_bank.quiet
        for name in ("Phi", "Gamma", "M", "K", "K_integral", "P_prior"):
            a, b = getattr(new.design, name), getattr(old.design, name)
            bound = 1e-6 if quiet or name == "P_prior" else 1e-7
            assert np.abs(a - b).max() <= bound * np.abs(b).max(), (old.mass, name)
        for a, b in ((new.drift, old.drift), (new.S_inv, old.S_inv), (new.log_det_S, old.log_det_S)):
            assert np.abs(a - b).max() <= (1e-6 if quiet else 1e-7) * max(np.abs(b).max(), 1e-300)


_QUIET_ON_ANOTHER_KERNEL = (
    "import pickle, sys\n"
    "from flexarm.lqg_bank import QUIET_POLE_RADIUS, QUIET_SCALE, design_bank_model\n"
    "from flexarm.parameters import load_parameters\n"
    "q = design_bank_model(load_parameters(), 0.0, None, '200ms', QUIET_SCALE, QUIET_POLE_RADIUS)\n"
    "sys.stdout.buffer.write(pickle.dumps(q))\n")


def test_quiet_filter_is_well_posed_and_its_closed_loop_reproduces_on_another_kernel(payload_bank):
    """Issue 35 item 9: the quiet filter's slowest estimator pole is inside the committed radius at every
    point (the plain Kalman gain left the 190-290 Hz modes at |λ| = 0.999999, a 1000 s time constant), and
    its closed loop is what matters, not its matrix entries: designed afresh on another OpenBLAS kernel
    (Prescott: SSE3 only, other summation orders), the γ = 1 loop with integral action, noise and a 2-sample
    delay gives the committed bank's torques to 1e-8 of their peak. Measured 5e-11 (the plain gain: 4e-10);
    the bound leaves 200× for other CPUs and BLAS builds, far below the noise's own effect (about 1e-2)."""
    import dataclasses
    import os
    import pickle
    import subprocess
    import sys

    from flexarm.gain_schedule import default_trajectory_path
    from flexarm.lqg import simulate_lqg
    from flexarm.lqg_bank import QUIET_POLE_RADIUS, BankController
    from flexarm.parameters import load_parameters
    from flexarm.sensors import SensorBank

    d = payload_bank.quiet.design
    slowest = [np.abs(np.linalg.eigvals((np.eye(22) - d.M[j] @ d.C) @ d.Phi[j])).max() for j in range(len(d.times))]
    assert max(slowest) < QUIET_POLE_RADIUS, slowest
    assert payload_bank.metadata["quiet_pole_radius"] == QUIET_POLE_RADIUS
    out = subprocess.run([sys.executable, "-c", _QUIET_ON_ANOTHER_KERNEL], capture_output=True, check=True,
                         env={**os.environ, "OPENBLAS_CORETYPE": "Prescott"}, timeout=600).stdout
    other = dataclasses.replace(payload_bank, quiet=pickle.loads(out))
    params = load_parameters()
    runs = []
    for bank in (payload_bank, other):
        law = BankController(default_trajectory_path(), bank, "gamma1", 2, True, params.peak_torque)
        sensors = SensorBank(SensorSettings(noise_enabled=True, noise_seed=1))
        runs.append(simulate_lqg(ArmModel(params), law, sensors=sensors)[1])
    assert np.abs(runs[1] - runs[0]).max() <= 1e-8 * np.abs(runs[0]).max()
    assert payload_bank.metadata["npz_sha256"] and payload_bank.metadata["trajectory_sha256"]


def test_payload_bank_file_refuses_a_schedule_without_a_bank_and_a_stale_file(tmp_path, payload_bank):
    from flexarm.gain_schedule import GainError, StaleDataError
    from flexarm.lqg_bank import PayloadBank

    with pytest.raises(GainError, match="schedule"):
        PayloadBank.load("20ms")
    path = payload_bank.save(tmp_path)
    assert PayloadBank.load(directory=tmp_path).masses.tolist() == payload_bank.masses.tolist()
    path.write_bytes(path.read_bytes()[:-10] + b"0123456789")  # the arrays no longer match their record
    with pytest.raises(StaleDataError, match="bank_200ms.npz"):
        PayloadBank.load(directory=tmp_path)


def run_bank(bank, payload_mass, gain_set, integral_action, noise):
    from flexarm.gain_schedule import default_trajectory_path
    from flexarm.lqg import simulate_lqg
    from flexarm.lqg_bank import BankController
    from flexarm.parameters import load_parameters
    from flexarm.sensors import SensorBank

    params = load_parameters()
    c = BankController(default_trajectory_path(), bank, gain_set, 2, integral_action, params.peak_torque)
    sensors = SensorBank(SensorSettings(noise_enabled=True, noise_seed=1)) if noise else None
    states, torques = simulate_lqg(ArmModel(params.with_payload(payload_mass)), c, sensors=sensors)
    n = len(states) - 1
    rms = float(np.degrees(np.sqrt(np.mean((states[:n, :N] - c.z[:n, :N]) ** 2))))
    return rms, np.max(np.abs(torques), axis=0), np.array(c.history)


def test_payload_bank_drift_is_what_the_payload_adds(payload_bank):
    """The unloaded models carry no drift; a loaded one's drift grows with the mass."""
    unloaded, light, heavy = payload_bank.models[0], payload_bank.models[1], payload_bank.models[-1]
    assert np.all(unloaded.drift == 0.0) and np.all(payload_bank.quiet.drift == 0.0)
    assert 0.0 < np.abs(light.drift).max() < np.abs(heavy.drift).max()


def test_payload_bank_keeps_noise_out_and_identifies_the_payload(payload_bank):
    """Issue 14's two goals at once (delay 2, noise seed 1): noise raises the γ = 1 error at most 2×, with
    and without integral action, while the posterior stays on the unloaded arm; with the 0.275 kg payload
    the light models are ruled out within 50 ms and the error is at most half our LQR's 3.56°, within the
    torque limits."""
    for integral in (False, True):
        quiet, _, _ = run_bank(payload_bank, 0.0, "gamma1", integral, False)
        noisy, _, history = run_bank(payload_bank, 0.0, "gamma1", integral, True)
        assert noisy <= 2.0 * quiet, (integral, quiet, noisy)
        assert np.all(history[100:, 0] > 0.5)
    rms, peak, history = run_bank(payload_bank, 0.275, "gamma0.1", True, True)
    light = history[:, payload_bank.masses <= 0.05].sum(axis=1)
    assert np.all(light[50:60] < 0.01)
    assert 0.1 <= np.median(history[100:] @ payload_bank.masses) <= 0.4
    assert rms <= 0.5 * 3.56
    assert peak[0] < 7.0 and peak[1] < 2.25


def test_payload_bank_refuses_bad_settings(payload_bank):
    from flexarm.gain_schedule import default_trajectory_path
    from flexarm.lqg_bank import BankController, design_bank
    from flexarm.parameters import load_parameters

    traj = default_trajectory_path()
    with pytest.raises(LqgError, match="select"):
        BankController(traj, payload_bank, select="median")
    with pytest.raises(LqgError, match="floor"):
        BankController(traj, payload_bank, floor=0.5)
    with pytest.raises(LqgError, match="loop_delay_samples"):
        BankController(traj, payload_bank, loop_delay_samples=11)
    with pytest.raises(LqgError, match="masses"):
        design_bank(load_parameters(), (0.1, 0.2))


def _hold_poles(design, K) -> np.ndarray:
    """Continuous-equivalent poles (1/s) of the sampled hold loop Φ − ΓK at the design's last point, below 200
    rad/s (the arm's servo and first flexible modes; the kHz bracket modes are the plant's, not the hold's)."""
    s = np.log(np.linalg.eigvals(design.Phi[-1] - design.Gamma[-1] @ K).astype(complex)) / 1e-3
    return s[np.abs(s) < 200.0]


@pytest.mark.parametrize("schedule", ["200ms", "20ms", "single", "bank"])
def test_the_end_point_is_held_by_a_regulator_that_settles(schedule):
    """Issue 32 item 4: every committed LQG design (and every filter of the payload bank) ends with a point at
    t_f, the end state at rest with zero torque, whose gains are the hold's (HOLD_STATE_WEIGHT, the same for
    every gain set). Its slowest servo/flexible pole decays at 3.9 1/s (e^-4 within about 1 s); the paper's
    γ = 0.1 weights at the same point give 0.6 1/s with the filter's full state (and about 0.1 1/s as the
    paper's law runs them, docs/findings.md). Bounds: 3 and 1 1/s, far from both figures."""
    from flexarm.gain_schedule import default_trajectory_path
    from flexarm.gain_sets import WEIGHT_NAMES, state_weight
    from flexarm.lqg_bank import PayloadBank
    from flexarm.lqg_design import HOLD_STATE_WEIGHT, R_PAPER, dlqr
    from flexarm.parameters import load_parameters
    from flexarm.trajectory import load_trajectory

    traj = load_trajectory(default_trajectory_path())
    designs = ([b.design for b in PayloadBank.load().filters] if schedule == "bank"
               else [LqgDesign.load(schedule)])
    for design in designs:
        assert design.times[-1] == pytest.approx(traj.n_samples * 1e-3, abs=1e-12)
        np.testing.assert_array_equal(design.tau_bar[-1], 0.0)
        np.testing.assert_allclose(design.operating_points[-1], np.r_[traj.theta[-1], np.zeros(N)], atol=1e-9)
        for w in range(len(WEIGHT_NAMES)):
            np.testing.assert_array_equal(design.K[-1, w], design.K[-1, 0])
            assert -_hold_poles(design, design.K[-1, w]).real.max() >= 3.0, (design.schedule, w)
    # the same point designed with the paper's γ = 0.1 weights (scaled coordinates, as lqg_design does)
    model = ArmModel(load_parameters())
    z_end = designs[0].operating_points[-1]
    T = scaling_transform(model, z_end)
    Ti = np.linalg.inv(T)
    assert np.allclose(HOLD_STATE_WEIGHT, np.diag(np.diag(HOLD_STATE_WEIGHT)))
    Q = T.T @ state_weight("gamma0.1") @ T
    K_paper = dlqr(Ti @ designs[0].Phi[-1] @ T, Ti @ designs[0].Gamma[-1], 0.5 * (Q + Q.T), R_PAPER) @ Ti
    assert -_hold_poles(designs[0], K_paper).real.max() < 1.0


def test_the_tip_settles_within_about_a_second_after_the_slew_with_the_payload_and_noise():
    """Issue 32 item 4, measured: controller_lqg's law (γ = 0.1, 200 ms) with an unknown 0.275 kg payload and the
    paper's sensor noise (seed 1) leaves the tip 13 mm from its end point at t_f. With the hold it is within
    1 mm from t_f + 1.06 s to t_f + 5 s (bound 1.3 s); holding with the last slew point's gains instead (as the
    controller did before) it is not within 1 mm by t_f + 4.9 s (4.98 s). Hold torques within the limits. The
    same measurement writes docs/findings.md's table (scenarios.reports.findings_doc.lqg_tip_settling)."""
    from flexarm.parameters import load_parameters
    from scenarios.reports.findings_doc import lqg_tip_settling

    held, peak = lqg_tip_settling(0.275)
    assert 0.0 < held <= 1.3 and (peak < load_parameters().peak_torque).all(), (held, peak)
    assert lqg_tip_settling(0.275, hold=False)[0] > 4.9
