"""Iterative learning control (flexarm.ilc, scenarios/ilc/trials.py): the mathematics, the files, the FMU parameter,
and a short learning run through the FMUs (resumed from its journal)."""

from __future__ import annotations

import json
import shutil
import zipfile
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


def test_scenario_refuses_bad_settling_weights(tmp_path):
    from scenarios.config import ScenarioError
    from scenarios.ilc.scenario import load_ilc

    for key, value in (("settling_weight", "-1.0"), ("settling_weight", "2e6"), ("settling_tip_weight", "-5.0"),
                       ("settling_tip_weight", "true"), ("settling_model_payload_mass", "-0.1"),
                       ("settling_q_filter_cutoff_hz", "500.0"), ("evaluate_samples", "3000")):
        scen = tmp_path / "ilc_bad.toml"
        text = "\n".join(line for line in SCENARIO.read_text().splitlines() if not line.startswith(f"{key} ="))
        scen.write_text(text.replace("leak_weight = 1e-3", f"leak_weight = 1e-3\n{key} = {value}"))
        with pytest.raises(ScenarioError, match=rf"ilc\.{key}: (a|an) (factor|weight|payload|cut-off|integer) in \["):
            load_ilc(scen)
    scen.write_text(SCENARIO.read_text().replace("leak_weight = 1e-3",
                                                 "leak_weight = 1e-3\nsettling_q_filter_cutoff_hz = 3"))
    assert load_ilc(scen)[1].settling_q_filter_cutoff_hz == 3.0


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


def _learned_file(tmp_path, n: int):
    from flexarm.parameters import DEFAULT_PARAMETER_FILE
    from flexarm.provenance import sha256_file

    u = 0.05 * np.sin(np.arange(2 * n).reshape(n, 2) * 0.01)
    meta = {"trajectory_file": str(DEFAULT_TRAJECTORY_FILE), "trajectory_sha256": sha256_file(DEFAULT_TRAJECTORY_FILE),
            "parameter_file": str(DEFAULT_PARAMETER_FILE), "parameter_sha256": sha256_file(DEFAULT_PARAMETER_FILE)}
    return u, ilc.write_learned_feedforward(tmp_path / "u", u, 1e-3, meta)


def _carrying(fmu, tmp_path, name, npz=None, json=None):
    """A copy of the controller FMU `fmu` with `npz` and `json` (paths, or None to leave one out) as its learned
    correction in resources/, packed as they are (unchecked: to test what the FMU itself refuses)."""
    from flexarm.ilc import LEARNED_RESOURCE

    out = tmp_path / f"{name}_{fmu.name}"
    shutil.copyfile(fmu, out)
    with zipfile.ZipFile(out, "a") as z:
        for file, suffix in ((npz, ".npz"), (json, ".json")):
            if file is not None:
                z.write(file, f"resources/{Path(LEARNED_RESOURCE).with_suffix(suffix)}")
    return out


def _torques(fmu, n, params):
    from fmu_harness import _controller_inputs
    from native_fmus import run_fmpy

    names, rows = run_fmpy(fmu, n, _controller_inputs, params)
    return np.asarray(rows)[:, [names.index("tau1"), names.index("tau2")]]


def test_controller_fmus_add_the_learned_correction_python_and_native_alike(tmp_path):
    """Both kinds of controller FMU carrying a learned correction in their resources (fmu_build.learned): the Python
    one equals the library law with
    the same correction bit for bit; the native one equals the Python one to 1e-13 N·m (their K·m products sum in
    different orders: the unlearned controllers differ by the same ~1e-14 N·m), a run past the file's end and the
    saturation included; a missing, stale or edited file (its seal broken) is refused by both."""
    from fmu_harness import _controller_inputs, built_fmus
    from native_fmus import native_fmus

    n = 2200  # past the slew (2058 samples) and past the correction's 400 samples
    u, path = _learned_file(tmp_path, 400)
    from fmu_build.learned import with_learned_feedforward

    py, native = built_fmus()["controller"], native_fmus()["controller"]
    py_learned = with_learned_feedforward(py, path, tmp_path / "py_controller.fmu")
    native_learned = with_learned_feedforward(native, path, tmp_path / "native_controller.fmu")
    got = _torques(py_learned, n, {})
    law = TrackingController(DEFAULT_TRAJECTORY_FILE, "gamma0.1", feedforward_correction=u)
    keys = ("q1_m", "q2_m", "qd1_m", "qd2_m", *(f"eps{i}_m" for i in range(1, 7)))
    expect = np.array([law.torque_from_measurements(k, [_controller_inputs(k)[x] for x in keys])
                       for k in range(n + 1)])
    assert np.array_equal(got, expect)
    plain = _torques(py, n, {})
    assert not np.array_equal(plain[:400], got[:400]) and np.array_equal(plain[400:], got[400:])
    native_got, native_plain = _torques(native_learned, n, {}), _torques(native, n, {})
    assert np.abs(native_got - got).max() <= 1e-13 and np.abs(native_plain - plain).max() <= 1e-13
    # the correction itself is applied identically: learned − unlearned agree where nothing saturates
    free = (np.abs(got) < [7.0, 2.25]).all(axis=1) & (np.abs(plain) < [7.0, 2.25]).all(axis=1)
    assert np.abs((native_got - native_plain)[free] - (got - plain)[free]).max() <= 1e-13
    from flexarm.ilc import read_learned_feedforward

    stale = ilc.write_learned_feedforward(tmp_path / "stale", u, 1e-3,
                                          dict(read_learned_feedforward(path).metadata, parameter_sha256="0" * 64))
    # a broken seal of the .json (one digit of it changed; a byte added that JSON does not see): both kinds
    # refuse it, as flexarm.ilc.read_learned_feedforward does
    text = path.with_suffix(".json").read_text()
    seal = text.split('"json_sha256": "')[1][:64]
    broken = []
    for name, edited in (("seal", text.replace(seal, ("1" if seal[0] != "1" else "2") + seal[1:])),
                         ("space", text.replace("{", "{ ", 1))):
        shutil.copyfile(path, tmp_path / f"{name}.npz")
        (tmp_path / f"{name}.json").write_text(edited)
        broken.append(tmp_path / f"{name}.npz")
        with pytest.raises(StaleDataError, match="json_sha256"):
            read_learned_feedforward(broken[-1])
    with pytest.raises(StaleDataError):  # the packing refuses what the FMUs would refuse
        with_learned_feedforward(py, stale, tmp_path / "refused.fmu")
    for fmu in (py, native):
        carrying = [_carrying(fmu, tmp_path, "stale", stale, stale.with_suffix(".json")),
                    _carrying(fmu, tmp_path, "no_json", path),  # one file of the pair missing
                    _carrying(fmu, tmp_path, "no_npz", None, path.with_suffix(".json")),
                    *(_carrying(fmu, tmp_path, b.stem, b, b.with_suffix(".json")) for b in broken)]
        for bad in carrying:
            with pytest.raises(Exception):  # noqa: B017 - fmpy raises its own exception type for fmi2Error
                _torques(bad, 2, {})
        # packed again without a correction: the controller's own torques
        assert np.array_equal(_torques(with_learned_feedforward(carrying[0], None, tmp_path / "stripped.fmu"), 5,
                                       {}), (plain if fmu == py else native_plain)[:6])


def test_ilc_scenario_learns_through_the_fmus_and_resumes(tmp_path):
    """Two trials of a short ILC scenario through the Python FMUs, then a third after a 'restart': the journal
    keeps the first two, the third runs with the correction they produced, and the error falls."""
    from scenarios.config import ScenarioError
    from scenarios.ilc.trials import run_ilc

    text = SCENARIO.read_text().replace("samples = 3058", "samples = 400").replace("trials = 50", "trials = 2")
    text = text.replace('evaluate_cases = ["learn", "payload_0p2", "payload_0p35"]', 'evaluate_cases = ["learn"]')
    scen = tmp_path / "ilc_short.toml"
    scen.write_text(text)
    out = tmp_path / "out"
    first = run_ilc(scen, out, plots=False, progress=lambda s: None)
    assert first["stopped"] is None and [r["trial"] for r in first["trials"]] == [0, 1]
    assert [r["seed"] for r in first["trials"]] == [1, 2]
    journal = (out / "ilc_payload" / "journal.jsonl").read_text().splitlines()
    assert len(journal) == 3  # config + two trials
    second = run_ilc(scen, out, plots=False, progress=lambda s: None, trials=3)
    assert [r["trial"] for r in second["trials"]] == [0, 1, 2]
    assert second["trials"][0] == first["trials"][0]  # not rerun
    rms = [r["metrics"]["slew_rms_position_error"] for r in second["trials"]]
    assert rms[2] < rms[1] < rms[0]
    ev = second["evaluation"]["learn"]
    assert ev["learned"]["metrics"]["slew_rms_position_error"] < ev["unlearned"]["metrics"]["slew_rms_position_error"]
    from scenarios.reports.ilc_report import MARKER, render  # the page renders such a summary (its figures in it)

    page = render(second, [("study", second)], None, second)
    assert page.startswith(MARKER) and f"| 2 | {rms[2]:.4f} |" in page and "Jacobi stepping" in page
    learned = ilc.read_learned_feedforward(out / "ilc_payload" / "learned_feedforward.npz")
    assert learned.metadata["trials_learned_from"] == 3 and learned.correction.shape == (400, 2)
    # the learned controller as one self-contained FMU: the final correction inside it, its SHA-256 recorded
    fmu = out / "ilc_payload" / second["learned_controller"]["file"]
    from flexarm.provenance import sha256_file

    assert sha256_file(fmu) == second["learned_controller"]["sha256"]
    with zipfile.ZipFile(fmu) as z:
        packed = z.read("resources/learned_feedforward.npz")
    assert packed == (out / "ilc_payload" / "learned_feedforward.npz").read_bytes()
    for written in ("evaluation.json", "learned_feedforward.json"):  # no absolute path of this machine
        content = (out / "ilc_payload" / written).read_text()
        assert str(tmp_path) not in content and '"/' not in content, written
    # a number edited in a trial's journal line is refused, naming the line, never reported in trials.csv
    jpath = out / "ilc_payload" / "journal.jsonl"
    lines = jpath.read_text().splitlines()
    rec = json.loads(lines[2])
    rec["metrics"]["slew_rms_position_error"] /= 10
    jpath.write_text("\n".join([*lines[:2], json.dumps(rec), *lines[3:]]) + "\n")
    with pytest.raises(ScenarioError, match=r"line_sha256.*\(line 3\)"):
        run_ilc(scen, out, plots=False, progress=lambda s: None, trials=3)
    jpath.write_text("\n".join(lines) + "\n")
    # another configuration in the same folder is refused, not mixed
    scen.write_text(text.replace("leak_weight = 1e-3", "leak_weight = 2e-3"))
    with pytest.raises(ScenarioError, match="another configuration"):
        run_ilc(scen, out, plots=False, progress=lambda s: None)
    shutil.rmtree(out)


@pytest.mark.parametrize("params", [{"loop_delay_samples": 2, "integral_action": True},
                                    {"estimator": 2, "schedule_period": 0.2}], ids=["kalman-delay2-integral", "bank"])
def test_controller_lqg_adds_the_learned_correction_python_and_native_alike(tmp_path, params):
    """controller_lqg (both kinds) carrying a learned correction in its resources: the Python FMU equals the library
    law with the same correction bit for bit (the filter's input is τ − τ_ff, the correction included); the native one
    equals the Python one to 1e-10 of the peak torque (as without a correction, tests/test_native_lqg.py); the
    correction changes the torques; a stale file is refused by both."""
    from fmu_harness import built_fmus
    from native_fmus import native_fmus, run_fmpy
    from test_native_lqg import MEASURED, lqg_inputs

    from flexarm.lqg import lqg_controller
    from flexarm.lqg_bank import bank_controller

    n = 600
    u, path = _learned_file(tmp_path, 400)
    from fmu_build.learned import with_learned_feedforward

    py, native = built_fmus()["controller_lqg"], native_fmus()["controller_lqg"]

    def torques(fmu, p):
        names, rows = run_fmpy(fmu, n, lqg_inputs, p)
        return np.asarray(rows)[:, [names.index("tau1"), names.index("tau2")]]

    got = torques(with_learned_feedforward(py, path, tmp_path / "py_lqg.fmu"), params)
    plain = torques(py, params)
    delay = params.get("loop_delay_samples", 0)
    integral = params.get("integral_action", False)
    law = (bank_controller("gamma0.1", "200ms", delay, integral, feedforward_correction=u) if "estimator" in params
           else lqg_controller("gamma0.1", "200ms", delay, integral, feedforward_correction=u))
    state, expect = law.initial_state(), []
    for k in range(n + 1):  # the FMU computes sample k from the inputs of sample k - d (lqg_inputs(0) before)
        m = law.design.C @ law.z[0] if k < delay else [lqg_inputs(max(k - 1, 0) if delay else k)[x] for x in MEASURED]
        tau, state = law.step(state, k, m)
        expect.append(tau)
    assert not np.array_equal(got, plain)
    native_got = torques(with_learned_feedforward(native, path, tmp_path / "native_lqg.fmu"), params)
    assert np.abs(native_got - got).max() <= 1e-10 * np.abs(got).max()
    np.testing.assert_array_equal(got, np.array(expect))
    from flexarm.ilc import read_learned_feedforward

    stale = ilc.write_learned_feedforward(tmp_path / "stale", u, 1e-3,
                                          dict(read_learned_feedforward(path).metadata, trajectory_sha256="0" * 64))
    for fmu in (py, native):
        with pytest.raises(Exception):  # noqa: B017 - fmpy raises its own exception type for fmi2Error
            torques(_carrying(fmu, tmp_path, "stale", stale, stale.with_suffix(".json")), params)


def test_an_fmu_error_in_the_middle_of_a_trial_stops_the_campaign(tmp_path, monkeypatch, capsys):
    """The controller returns fmi2Error from fmi2DoStep at t = 0.2 s of trial 1 (as a failing FMU does): the
    campaign stops there (no trial 2, no learned file, no evaluation), the journal keeps the failed trial, and
    ``python -m scenarios run`` says which trial, step and FMU, and exits non-zero; run again, it stays stopped."""
    from scenarios.__main__ import main
    from scenarios.master import units

    text = SCENARIO.read_text().replace("samples = 3058", "samples = 300").replace("trials = 50", "trials = 3")
    text = text.replace('evaluate_cases = ["learn", "payload_0p2", "payload_0p35"]', 'evaluate_cases = ["learn"]')
    scen = tmp_path / "ilc_fail.toml"
    scen.write_text(text)
    raw, runs = units.fmu2_raw_functions, []

    def failing(slave):
        get_real, set_real, do_step = raw(slave)
        if slave.instanceName != "controller":
            return get_real, set_real, do_step

        def step(component, t, h, new_step):
            if t == 0.0:
                runs.append(t)
            return 3 if len(runs) == 2 and t >= 0.2 else do_step(component, t, h, new_step)  # 3: fmi2Error
        return get_real, set_real, step

    monkeypatch.setattr(units, "fmu2_raw_functions", failing)
    out = tmp_path / "out"
    args = ["run", str(scen), "--out", str(out), "--no-plots", "--quiet"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "stopped: trial 1: error" in err and "t = 0.2" in err and "controller" in err, err
    folder = out / "ilc_payload"
    journal = [json.loads(line) for line in (folder / "journal.jsonl").read_text().splitlines()]
    assert [r.get("status") for r in journal[1:]] == ["ok", "error"]
    assert not (folder / "learned_feedforward.npz").exists()
    summary = json.loads((folder / "evaluation.json").read_text())
    assert summary["evaluation"] == {} and len(summary["trials"]) == 2
    assert main(args) == 1 and len((folder / "journal.jsonl").read_text().splitlines()) == 3  # stays stopped


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


def test_the_ilc_page_is_its_committed_results(capsys):
    """docs/ilc.md's generated parts are what docs/ilc_results.json and docs/ilc_floor.json render to, from the
    scenario and data files as they are (no runs: the runs take 15-20 minutes; their commands regenerate all)."""
    from scenarios.ilc import floor as ilc_floor
    from scenarios.reports import ilc_report

    assert ilc_floor.main(["--check"]) == 0, capsys.readouterr().err
    assert ilc_report.main(["--check"]) == 0, capsys.readouterr().err


def test_run_all_says_it_leaves_the_ilc_scenarios_out(capsys):
    """`run all` runs the single-run scenarios and says, in one line, which ILC scenarios it does not run (here it
    stops at once, refusing an unknown case, before running anything)."""
    from scenarios.__main__ import main

    assert main(["run", "all", "--case", "no_such_case"]) != 0
    lines = [x for x in capsys.readouterr().err.splitlines() if "ILC" in x]
    assert len(lines) == 1 and "ilc_payload" in lines[0] and "ilc_lqg_jacobi" in lines[0], lines


@pytest.mark.parametrize("options, named", [
    (["--controller", "my/MyController.fmu"], "--controller my/MyController.fmu"),
    (["--set", "plant.payload_mass=0.2"], "--set plant.payload_mass=0.2"),
    (["--case", "learn"], "--case learn"),
])
def test_an_ilc_scenario_refuses_the_options_it_would_not_honour(tmp_path, capsys, options, named):
    """`--controller`, `--set` and `--case` on an ILC scenario: exit 2 with a sentence naming the option and why, before
    anything runs or is written; never our controller's figures under the user's name (issue 32 item 6)."""
    from scenarios.__main__ import EXIT_REFUSED, main

    code = main(["run", "ilc_payload", "--out", str(tmp_path / "out"), "--quiet", "--no-plots", *options])
    err = capsys.readouterr().err
    assert code == EXIT_REFUSED == 2 and named in err and "learns the feedforward of its own controller" in err, err
    assert not (tmp_path / "out").exists()


def test_an_ilc_scenario_refuses_a_controller_that_reads_no_learned_feedforward(tmp_path):
    """controller_fb has no feedforward to correct: the ILC run is refused before any trial, naming the FMU and
    the controllers that learn, rather than learning a correction nobody applies."""
    from scenarios.config import ScenarioError
    from scenarios.ilc.trials import run_ilc

    text = SCENARIO.read_text().replace('controller = "controller"', 'controller = "controller_fb"', 1)
    scen = tmp_path / "ilc_fb.toml"
    scen.write_text(text.replace("samples = 3058", "samples = 10"))
    with pytest.raises(ScenarioError, match=r"controller_fb\.fmu does not read a learned feedforward.*"
                                             r"FlexarmControllerLQG"):
        run_ilc(scen, tmp_path / "out", plots=False, progress=lambda s: None)
    assert not (tmp_path / "out" / "ilc_payload" / "journal.jsonl").exists()
