"""Iterative learning control (flexarm.ilc): the mathematics (the norm-optimal update, its settling weights, the
Q-filter, the lifted model) and the learned-feedforward files. Through the FMUs: tests/test_ilc_fmus.py."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from flexarm import ilc
from flexarm.control import TrackingController
from flexarm.gain_schedule import StaleDataError, as_trajectory
from flexarm.model import N_STATE
from flexarm.trajectory.io import DEFAULT_TRAJECTORY_FILE

SCENARIO = Path(__file__).resolve().parent.parent / "scenarios" / "ilc_payload.toml"


@pytest.fixture(scope="module")
def small_model():
    """The lifted closed-loop model over 80 samples in the middle of the first 200 ms (dense forms stay small)."""
    m = ilc.closed_loop_model(120)
    return ilc.LtvModel(m.A[40:], m.B[40:], m.C, m.dt)


def _scalar_model(n: int, a: float, b: float, c: float) -> ilc.LtvModel:
    """x_(k+1) = a x_k + b u1_k, y = c x in state 0 / output 0; everything else zero (u2 reaches nothing)."""
    A = np.zeros((n, N_STATE, N_STATE))
    A[:, 0, 0] = a
    B = np.zeros((n, N_STATE, 2))
    B[:, 0, 0] = b
    C = np.zeros((11, N_STATE))
    C[0, 0] = c
    return ilc.LtvModel(A, B, C, 1e-3)


def test_update_equals_a_hand_computed_small_case():
    # N = 2, a = 0.5, b = 1, c = 2: y1 = 2 u0, y2 = 2 (0.5 u0 + u1) -> G = [[2, 0], [1, 2]] for input 1.
    # Qe = 1, Ru = 1, e = (1, 1): Δu = (GᵀG + I)⁻¹ Gᵀ e = [[6, 2], [2, 5]]⁻¹ [3, 2] = [11, 6] / 26.
    law = ilc.NormOptimalIlc(_scalar_model(2, 0.5, 1.0, 2.0), error_weight=1.0, input_weight=1.0, q_cutoff_hz=None)
    e = np.zeros((2, 11))
    e[:, 0] = 1.0
    du = law.step(e)
    assert du[:, 0] == pytest.approx([11 / 26, 6 / 26], rel=1e-12)
    assert np.all(du[:, 1] == 0.0)  # the input that reaches no output is not moved
    # With a leak s = 1 on the correction u = (1, 0): Δu = (GᵀG + 2I)⁻¹ (Gᵀe − u) = [[7, 2], [2, 6]]⁻¹ [2, 2]
    #   = [6·2 − 2·2, −2·2 + 7·2] / 38 = [8, 10] / 38.
    leaky = ilc.NormOptimalIlc(_scalar_model(2, 0.5, 1.0, 2.0), 1.0, 1.0, None, leak_weight=1.0)
    u = np.array([[1.0, 0.0], [0.0, 0.0]])
    assert leaky.step(e, u)[:, 0] == pytest.approx([8 / 38, 10 / 38], rel=1e-12)
    # The update adds Δu and clips τ_ff + u to the limits: with τ_ff = 0.3, 0.1 and limit 0.5 on joint 1, the
    # first sample (0.3 + 11/26 > 0.5) is clipped to 0.2, the second (0.1 + 6/26 < 0.5) is not.
    nxt = law.update(np.zeros((2, 2)), e, feedforward=np.array([[0.3, 0.0], [0.1, 0.0]]), limits=(0.5, 1.0))
    assert nxt[:, 0] == pytest.approx([0.2, 6 / 26], rel=1e-12)


def test_weighted_update_equals_a_hand_computed_small_case():
    # The same G = [[2, 0], [1, 2]], Ru = 1, e = (1, 1), the second sample's error weighted 4 (W = diag(1, 4)):
    # Δu = (GᵀWG + I)⁻¹ GᵀWe = [[9, 8], [8, 17]]⁻¹ [6, 8] = [17·6 − 8·8, −8·6 + 9·8] / 89 = [38, 24] / 89.
    e = np.zeros((2, 11))
    e[:, 0] = 1.0
    timed = ilc.NormOptimalIlc(_scalar_model(2, 0.5, 1.0, 2.0), 1.0, 1.0, None, time_weight=[1.0, 4.0])
    assert timed.step(e)[:, 0] == pytest.approx([38 / 89, 24 / 89], rel=1e-12)
    # the same weight as an output weight added on sample 2 (1 + 3 on the first output), and on an output the
    # model does not reach (changes nothing)
    x = np.zeros((2, 11, 11))
    x[1, 0, 0] = 3.0
    x[:, 5, 5] = 7.0
    added = ilc.NormOptimalIlc(_scalar_model(2, 0.5, 1.0, 2.0), 1.0, 1.0, None, output_weight=x)
    assert added.step(e)[:, 0] == pytest.approx([38 / 89, 24 / 89], rel=1e-12)
    for bad, match in ((-x, "positive semidefinite"), (x[:1], "matrices"), (x + np.triu(np.ones((11, 11)), 1),
                                                                            "symmetric")):
        with pytest.raises(ilc.IlcError, match=match):
            ilc.NormOptimalIlc(_scalar_model(2, 0.5, 1.0, 2.0), 1.0, 1.0, None, output_weight=bad)


def test_settling_weights_and_the_tip_jacobian():
    """The factor and the tip term act at and after t_f only; J is the derivative of the plant's tip position."""
    from flexarm.gain_schedule import desired_states
    from flexarm.model import ArmModel
    from flexarm.parameters import load_parameters

    traj = as_trajectory(DEFAULT_TRAJECTORY_FILE)
    n = traj.n_samples + 10
    w, x = ilc.settling_weights(traj, n, 5.0, 100.0)
    assert np.all(w[:traj.n_samples - 1] == 1.0) and np.all(w[traj.n_samples - 1:] == 5.0)
    assert not x[:traj.n_samples - 1].any() and np.all(x[-1] == x[traj.n_samples - 1])
    theta = desired_states(traj)[-1][:11]
    arm, h = ArmModel(load_parameters()), 1e-7
    numeric = np.array([(arm.tip_position(theta + h * d) - arm.tip_position(theta - h * d)) / (2 * h)
                        for d in np.eye(11)]).T
    J = arm.tip_jacobian(theta)
    assert np.abs(J - numeric).max() < 1e-8
    assert np.allclose(x[-1], 100.0 * J.T @ J, rtol=1e-14, atol=0)
    assert ilc.settling_weights(traj, n)[1] is None and np.all(ilc.settling_weights(traj, n)[0] == 1.0)
    with pytest.raises(ilc.IlcError, match="settling_tip_weight"):
        ilc.settling_weights(traj, n, 1.0, -1.0)


@pytest.fixture(scope="module")
def settling_model():
    """The lifted model over 80 samples across t_f (t_f at its sample 58), with the settling weights there."""
    traj = as_trajectory(DEFAULT_TRAJECTORY_FILE)
    end = traj.n_samples + 22
    m = ilc.closed_loop_model(end)
    w, x = ilc.settling_weights(traj, end, 30.0, 1e4)
    return ilc.LtvModel(m.A[-80:], m.B[-80:], m.C, m.dt), w[-80:], x[-80:]


def test_settling_weighted_sweep_equals_dense_and_contracts(settling_model):
    """With the settling factor and the tip term, the sweep equals the dense update and ρ(Q(I − LG − sH⁻¹)) < 1."""
    model, w, x = settling_model
    assert w[0] == 1.0 and w[-1] == 30.0 and x[-1].any() and not x[0].any()
    law = ilc.NormOptimalIlc(model, 1.0, 1e-4, 10.0, 2, 1e-3, time_weight=w, output_weight=x)
    rng = np.random.default_rng(4)
    e = rng.normal(scale=1e-3, size=(model.n_samples, 11))
    u = rng.normal(scale=0.1, size=(model.n_samples, 2))
    G = law.lifted_matrix()
    import scipy.linalg

    W = np.diag(np.repeat(w, 11)) + scipy.linalg.block_diag(*x)
    H = G.T @ W @ G + (1e-4 + 1e-3) * np.eye(G.shape[1])
    dense = np.linalg.solve(H, G.T @ W @ e.ravel() - 1e-3 * u.ravel()).reshape(-1, 2)
    assert np.abs(law.step(e, u) - dense).max() <= 1e-9 * np.abs(dense).max()
    _, T = law.dense_operator()
    assert np.abs(np.linalg.eigvals(T)).max() < 1.0
    # and with the Q-filter passing to 3 Hz from t_f on (sample 58 of this horizon)
    switched = ilc.NormOptimalIlc(model, 1.0, 1e-4, 20.0, 2, 1e-3, time_weight=w, output_weight=x,
                                  settling_q_cutoff_hz=3.0, settling_start=58)
    assert np.abs(np.linalg.eigvals(switched.dense_operator()[1])).max() < 1.0
    # without leak and Q-filter: eigenvalues in (0, 1), and the weighted error falls monotonically on the model
    plain = ilc.NormOptimalIlc(model, 1.0, 1e-4, None, time_weight=w, output_weight=x)
    eig = np.linalg.eigvals(plain.dense_operator()[1])
    assert np.abs(eig.imag).max() < 1e-8 and 0 < eig.real.min() and eig.real.max() < 1.0
    r = model.simulate(rng.normal(scale=0.2, size=(model.n_samples, 2)))
    uu, norms = np.zeros((model.n_samples, 2)), []
    for _ in range(6):
        err = r - model.simulate(uu)
        norms.append(float(err.ravel() @ W @ err.ravel()))
        uu = uu + plain.step(err)
    assert all(b < a for a, b in zip(norms, norms[1:])) and norms[-1] < 0.05 * norms[0]


def test_settling_q_filter_filters_each_phase_on_its_own():
    """Before t_f the slew's Q-filter on the slew's samples alone, from t_f on the settling's on the rest; linear."""
    model = _scalar_model(600, 0.5, 1.0, 2.0)
    law = ilc.NormOptimalIlc(model, 1.0, 1.0, 20.0, 2, settling_q_cutoff_hz=3.0, settling_start=300)
    u = np.random.default_rng(6).normal(size=(600, 2))
    out = law.q(u)
    assert np.array_equal(out[:300], ilc.q_filter(u[:300], 1e-3, 20.0, 2))
    assert np.array_equal(out[300:], ilc.q_filter(u[300:], 1e-3, 3.0, 2))
    v = u.copy()
    v[300:] += 5.0  # the settling's samples do not reach the slew's, and the other way round
    assert np.array_equal(law.q(v)[:300], out[:300])
    assert np.allclose(law.q(2 * u + 1), 2 * out + law.q(np.ones_like(u)), rtol=1e-12, atol=1e-12)
    plain = ilc.NormOptimalIlc(model, 1.0, 1.0, 20.0, 2, settling_q_cutoff_hz=3.0)  # no start: one filter
    assert np.array_equal(plain.q(u), ilc.q_filter(u, 1e-3, 20.0, 2))
    with pytest.raises(ilc.IlcError, match="settling_start"):
        ilc.NormOptimalIlc(model, 1.0, 1.0, 20.0, 2, settling_q_cutoff_hz=3.0, settling_start=601)


@pytest.mark.parametrize("leak", [0.0, 1e-3])
def test_riccati_sweep_equals_the_dense_norm_optimal_update(small_model, leak):
    rng = np.random.default_rng(3)
    w = rng.uniform(0.5, 3.0, small_model.n_samples)  # per-sample error weights
    law = ilc.NormOptimalIlc(small_model, error_weight=1.0, input_weight=1e-4, q_cutoff_hz=10.0, leak_weight=leak,
                             time_weight=w)
    e = rng.normal(scale=1e-3, size=(small_model.n_samples, 11))
    u = rng.normal(scale=0.1, size=(small_model.n_samples, 2))
    G = law.lifted_matrix()
    W = np.repeat(w, 11)
    H = (G.T * W) @ G + (1e-4 + leak) * np.eye(G.shape[1])
    dense = np.linalg.solve(H, (G.T * W) @ e.ravel() - leak * u.ravel()).reshape(-1, 2)
    sweep = law.step(e, u)
    assert np.abs(sweep - dense).max() <= 1e-9 * np.abs(dense).max()
    # and G itself is the model: its product equals simulating the LTV model
    assert np.allclose((G @ u.ravel()).reshape(-1, 11), small_model.simulate(u), rtol=1e-10, atol=1e-15)


def test_learning_operator_is_a_contraction_on_the_lifted_model(small_model):
    """ρ(Q(I − LG − sH⁻¹)) < 1 with the scenario's weights; without leak and Q-filter the plain norm-optimal
    operator (GᵀG + rI)⁻¹r has every eigenvalue in (0, 1), and the error falls monotonically on the model."""
    import tomllib

    cfg = tomllib.loads(SCENARIO.read_text())["ilc"]
    law = ilc.NormOptimalIlc(small_model, cfg["error_weight"], cfg["input_weight"], cfg["q_filter_cutoff_hz"],
                             cfg["q_filter_order"], cfg["leak_weight"])
    _, T = law.dense_operator()
    assert np.abs(np.linalg.eigvals(T)).max() < 1.0
    plain = ilc.NormOptimalIlc(small_model, 1.0, 1e-4, None)
    _, T0 = plain.dense_operator()
    eig = np.linalg.eigvals(T0)
    assert np.abs(eig.imag).max() < 1e-8 and 0 < eig.real.min() and eig.real.max() < 1.0
    rng = np.random.default_rng(5)
    r = small_model.simulate(rng.normal(scale=0.2, size=(small_model.n_samples, 2)))  # a reachable error
    u, norms = np.zeros((small_model.n_samples, 2)), []
    for _ in range(6):
        e = r - small_model.simulate(u)
        norms.append(np.linalg.norm(e))
        u = u + plain.step(e)
    assert all(b < a for a, b in zip(norms, norms[1:])) and norms[-1] < 0.05 * norms[0]


def test_q_filter_is_zero_phase_and_low_pass():
    t = np.arange(2000) * 1e-3
    slow, fast = np.sin(2 * np.pi * 1.0 * t), np.sin(2 * np.pi * 80.0 * t)
    out = ilc.q_filter(np.column_stack([slow, fast]), 1e-3, 10.0, 2)
    assert np.abs(out[200:-200, 0] - slow[200:-200]).max() < 2e-3  # passes 1 Hz without lag
    assert np.abs(out[200:-200, 1]).max() < 0.01  # stops 80 Hz
    with pytest.raises(ilc.IlcError, match="Nyquist"):
        ilc.q_filter(np.zeros((100, 2)), 1e-3, 600.0)


def test_measured_errors_are_zero_on_the_trajectory_and_refuse_nan():
    from flexarm.model import joint_angles, strain_gauge_angles

    traj = as_trajectory(DEFAULT_TRAJECTORY_FILE)
    q = np.array([joint_angles(th) for th in traj.theta[:301]])
    eps = np.array([strain_gauge_angles(th) for th in traj.theta[:301]])
    assert np.abs(ilc.measured_errors(q, eps, traj)).max() < 1e-12
    q[5, 0] = np.nan
    with pytest.raises(ilc.IlcError, match="non-finite"):
        ilc.measured_errors(q, eps, traj)


def test_learned_feedforward_file_round_trip_and_data_chain(tmp_path):
    from flexarm.parameters import DEFAULT_PARAMETER_FILE
    from flexarm.provenance import sha256_file

    u = np.linspace(-0.1, 0.1, 600).reshape(300, 2)
    meta = {"trajectory_file": str(DEFAULT_TRAJECTORY_FILE), "trajectory_sha256": sha256_file(DEFAULT_TRAJECTORY_FILE),
            "parameter_file": str(DEFAULT_PARAMETER_FILE), "parameter_sha256": sha256_file(DEFAULT_PARAMETER_FILE),
            "trials": [0, 1]}
    path = ilc.write_learned_feedforward(tmp_path / "learned", u, 1e-3, meta)
    got = ilc.read_learned_feedforward(path)
    assert np.array_equal(got.correction, u) and got.dt == 1e-3 and got.metadata["trials"] == [0, 1]
    # a controller adds it to the feedforward (and after the slew, where the trajectory's is zero)
    ctrl = TrackingController(DEFAULT_TRAJECTORY_FILE, "gamma0.1", feedforward_correction=got.correction)
    plain = TrackingController(DEFAULT_TRAJECTORY_FILE, "gamma0.1")
    assert np.array_equal(ctrl.feedforward(7), plain.feedforward(7) + u[7])
    assert np.array_equal(ctrl.feedforward(300), plain.feedforward(300))
    # learnt on another trajectory: refused as stale, naming it
    stale = ilc.write_learned_feedforward(tmp_path / "stale", u, 1e-3, dict(meta, trajectory_sha256="0" * 64))
    with pytest.raises(StaleDataError, match="trajectory") as err:
        ilc.read_learned_feedforward(stale)
    assert "python -m scenarios run ilc_payload" in str(err.value) and "flexarm.lqr" not in str(err.value)
    # an edited side file is refused too
    doc = json.loads((tmp_path / "learned.json").read_text())
    doc["trials"] = [0, 1, 2]
    (tmp_path / "learned.json").write_text(json.dumps(doc))
    with pytest.raises(StaleDataError):
        ilc.read_learned_feedforward(path)


def test_lifted_blocks_equal_the_models_response(small_model):
    """The floor's lifted matrix (inputs held over blocks) maps a block input as the model's own recursion does,
    including a last, shorter block."""
    block = 7  # 80 samples: 11 full blocks and one of 3
    from flexarm.ilc_floor import lifted_blocks

    G = lifted_blocks(small_model, block)
    nb = -(-small_model.n_samples // block)
    assert G.shape == (small_model.n_samples * 11, 2 * nb)
    v = np.random.default_rng(3).normal(size=(nb, 2))
    held = np.repeat(v, block, axis=0)[:small_model.n_samples]
    y = small_model.simulate(held)
    assert np.abs(G @ v.ravel() - y.ravel()).max() <= 1e-12 * np.abs(y).max()




def test_the_safeguard_keeps_only_what_lowers_the_measured_error():
    """flexarm.ilc_trial.Safeguard on a learning whose model has a third of the plant's gain (a model error the
    update cannot see): unguarded, each step overshoots and the error grows by 1.5x per trial; guarded, each update
    starts from the best correction, a trial that is no new lowest halves the step and a new lowest doubles it, so
    the error converges. The correction is a convex combination of two within the limits, so within them too."""
    from flexarm.ilc_trial import Safeguard

    target, g_plant, g_model = np.array([1.0, -0.5]), 2.5, 1.0
    error = lambda u: target - g_plant * u  # noqa: E731 - the "plant"
    update = lambda u, e: u + e / g_model  # noqa: E731 - the model's exact inverse: overshoots on the plant

    u = np.zeros(2)
    unguarded = []
    for _ in range(6):
        unguarded.append(np.linalg.norm(error(u)))
        u = update(u, error(u))
    assert all(b > a for a, b in zip(unguarded, unguarded[1:]))  # diverges
    u, guard, norms, steps = np.zeros(2), None, [], []
    corrections = {}
    for j in range(12):
        e = error(u)
        n = float(np.linalg.norm(e))
        norms.append(n)
        corrections[j] = (u, e)
        guard, _ = (Safeguard(j, n), True) if guard is None else guard.after(j, n)
        steps.append(guard.step)
        ub, eb = corrections[guard.base_trial]
        u = guard.next_correction(ub, update(ub, eb))
    # a full step is tried after each new lowest and overshoots once (1.5x the lowest before it); the half step
    # from the best correction then lowers the error 4x (a step of 0.4 would be exact): it converges where the
    # unguarded learning diverges, and no trial exceeds the lowest before it by more than that one overshoot
    lowest = np.minimum.accumulate(norms)
    assert all(norms[j] <= 1.5 * lowest[j - 1] * (1 + 1e-12) for j in range(1, len(norms)))
    assert lowest[-1] < 1e-2 * norms[0] and all(b < a for a, b in zip(norms[::2], norms[2::2]))
    assert steps[:4] == [1.0, 0.5, 1.0, 0.5] and max(steps) <= 1.0
    s = Safeguard(3, 0.2, 0.25)
    assert s.after(4, 0.1) == (Safeguard(4, 0.1, 0.5), True) and s.after(4, 0.3) == (Safeguard(3, 0.2, 0.125), False)
    assert Safeguard(0, 1.0, 1.0).after(1, 0.5)[0].step == 1.0  # capped
    lo, hi = np.array([[-1.0, -2.0]]), np.array([[1.0, 2.0]])
    mixed = Safeguard(0, 1.0, 0.3).next_correction(lo, hi)
    assert np.all(mixed >= lo) and np.all(mixed <= hi)
