"""The controllers' and sensors' per-sample arithmetic has one source (issue 33 item 4): flexarm.control_law and
flexarm.sensor_law, from which the native C is generated (fmu_build/law_codegen.py). The native FMUs' parity with
the Python ones is checked through the FMUs in tests/test_native_controllers.py, test_native_lqg.py,
test_native_sensors.py and test_loop_delay.py; here, the generator, the rules and the hand-written C."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from flexarm import control_law as law
from flexarm import filter_law, sensor_law
from flexarm.gain_schedule import schedule_index
from fmu_build import law_codegen

ca = pytest.importorskip("casadi")
NATIVE = Path(__file__).resolve().parents[1] / "fmus" / "native"
NATIVE_CONTROLLER = NATIVE / "controller"


def _functions(make=law_codegen.law_functions) -> dict:
    return {f.name().removeprefix("generated_"): f for f in make()}


def _eval(f, *args) -> np.ndarray:
    return np.array(f(*[np.ravel(a) for a in args])).ravel()


def test_the_generated_law_is_the_library_s_arithmetic():
    """CasADi evaluates the generated functions operation by operation as their C does (no FMA: the C is built
    with -ffp-contract=off), in order; the library's products go through BLAS, which may sum in another order. So
    they agree to the rounding of those sums: n ulp of the sum of the terms' magnitudes for n terms (22 for K E,
    10 + 22 for K (E m_d), 10 for the torque, plus its two subtractions); the saturation is exact."""
    rng = np.random.default_rng(7)
    f = _functions()
    for _ in range(50):
        k, e = rng.normal(size=(2, 22)) * 10.0 ** rng.integers(-3, 3), rng.normal(size=(22, 10))
        m_d, m = rng.normal(size=10), rng.normal(size=10)
        ff, limit = rng.normal(size=2) * 5, np.array([7.0, 2.25])
        ke = law.gain_on_measurements(k, e)
        bound = 22 * np.finfo(float).eps * (np.abs(k) @ np.abs(e))
        assert np.all(np.abs(_eval(f["gain_on_measurements"], k, e).reshape(2, 10) - ke) <= bound)
        offset = law.gain_offsets(k[None], law.reconstructed_states(m_d[None], e))[0]
        bound = 32 * np.finfo(float).eps * (np.abs(k) @ (np.abs(e) @ np.abs(m_d)))
        assert np.all(np.abs(_eval(f["gain_offset"], k, e, m_d) - offset) <= bound)
        tau = law.tracking_torque(ff, ke, m, offset, limit)
        bound = np.finfo(float).eps * (12 * (np.abs(ke) @ np.abs(m)) + 2 * (np.abs(ff) + np.abs(offset)))
        assert np.all(np.abs(_eval(f["tracking_torque"], ff, ke, m, offset, limit) - tau) <= bound)
        assert np.all(np.abs(tau) <= limit)
        assert np.array_equal(_eval(f["saturate"], ff * 3, limit), law.saturate(ff * 3, limit))


def test_the_generated_corrected_feedforward_is_the_library_s():
    f = _functions()["corrected_feedforward"]
    for ff, corr in (([1.5, -0.25], [1e-3, -2e-3]), ([-0.0, 0.0], [0.0, -0.0]), ([7.0, 2.25], [np.nan, 0.0])):
        want = law.corrected_feedforward(np.array(ff), np.array(corr))
        np.testing.assert_array_equal(_eval(f, ff, corr), want)


def test_the_switching_rule_is_the_schedules_rule():
    """A set is in force from its own sample on, though k·dt is a few ulp off its time; the generated rule is the
    library's, and schedule_index counts it (the native controllers scan with it)."""
    f = _functions()["has_switched"]
    times = np.array([0.0, 0.2, 0.4, 0.6])
    dt = 1e-3
    for k in range(0, 900):
        t = k * dt
        expected = max(int(np.searchsorted(times, t + 1e-9, side="right")) - 1, 0)
        assert schedule_index(times, t) == expected
        for s in times[1:]:
            assert bool(_eval(f, s, t)[0]) == bool(law.has_switched(s, t))
    assert law.has_switched(0.2, 0.2 - 0.5e-9) and not law.has_switched(0.2, 0.2 - 2e-9)
    assert schedule_index(times, 0.2 - 0.5e-9) == 1 and schedule_index([0.5, 1.0], 0.0) == 0


def test_a_change_of_the_law_reaches_the_generated_c(tmp_path, monkeypatch):
    """The worked example of docs/architecture.md: the schedules' tolerance changed in flexarm/control_law.py alone
    is the constant the native C compares with."""
    out = tmp_path / "default"
    out.mkdir()
    law_codegen.generate_control_law(out)
    assert "1.0000000000000001e-09" in (out / "control_law.c").read_text()
    monkeypatch.setattr(law, "SWITCH_TOLERANCE_S", 2.5e-7)
    changed = tmp_path / "changed"
    changed.mkdir()
    law_codegen.generate_control_law(changed)
    text = (changed / "control_law.c").read_text()
    assert "2.4999999999999999e-07" in text and "1.0000000000000001e-09" not in text


def test_a_change_of_the_filter_design_reaches_the_generated_c(tmp_path, monkeypatch):
    """The filters' design is one source too: a Butterworth whose cut-off is not pre-warped, written in
    flexarm/filter_design.py alone, is what the native sensors' generated C computes (and the library's design)."""
    from flexarm import filter_design

    default = tmp_path / "default"
    default.mkdir()
    law_codegen.generate_sensor_law(default)
    monkeypatch.setattr(filter_design, "prewarp_argument", lambda cutoff_hz, sample_rate_hz: 1.25 * cutoff_hz
                        / sample_rate_hz)
    changed = tmp_path / "changed"
    changed.mkdir()
    law_codegen.generate_sensor_law(changed)
    text = (changed / "sensor_law.c").read_text()
    assert text != (default / "sensor_law.c").read_text() and "1.2500000000000000e+00" in text
    assert math.isclose(filter_design.butterworth_lowpass(2, 100.0, 1000.0)[0][0, 0],
                        filter_design.butterworth_sections(2, math.tan(0.125))[0][0][0], rel_tol=0, abs_tol=0)


def test_the_hand_written_controller_c_does_no_arithmetic_of_the_law():
    """The rule, the gain products, the learned feedforward's sum and the saturation come from control_law_api.h in
    every controller's C; a second copy written by hand would let the kinds drift apart again."""
    for c in sorted(NATIVE_CONTROLLER.glob("*.c")):
        text = c.read_text()
        assert not re.search(r"\bfmin\s*\(|\bfmax\s*\(", text), f"{c.name}: a saturation by hand"
        assert not re.search(r"\+\s*1e-9\b", text), f"{c.name}: the schedules' tolerance by hand"
        assert not re.search(r"[+-]=?\s*\(?[^;]*->correction\[", text), f"{c.name}: the learned correction by hand"
    uses = {c.name for c in NATIVE_CONTROLLER.glob("*.c") if '#include "control_law_api.h"' in c.read_text()}
    assert {"controller.c", "controller_lqg.c", "lqg_bank.c", "lqg_core.c"} <= uses


def _exact_rows(a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A x with each row's rounded products summed exactly (math.fsum), then rounded once."""
    return np.array([math.fsum(a_r * x) for a_r in a])


def test_the_generated_filter_law_sums_nearly_exactly():
    """The LQG's filter, predictor and feedback (flexarm.filter_law) generated with compensated sums: each product
    row within 1 ulp of its exactly summed products plus n² eps² of their magnitudes (Neumaier's bound), where the
    library's BLAS and a plain sum in order may be n eps of the magnitudes off. A row whose first and last terms
    (±1e18) cancel shows the difference: a plain sum in order loses the twenty terms between them."""
    f, eps = _functions(law_codegen.filter_law_functions), np.finfo(float).eps
    rng = np.random.default_rng(5)
    for _ in range(20):
        phi, gam, x, du = rng.normal(size=(22, 22)), rng.normal(size=(22, 2)), rng.normal(size=22), rng.normal(size=2)
        phi[0, 0], phi[0, 21], x[0], x[21] = 1e18, -1e18, 1.0, 1.0  # row 0: its first and last term cancel
        got = _eval(f["time_update_drift"], phi, gam, x, du, np.zeros(22))
        in_order = sum(phi[0] * x, 0.0) + gam[0] @ du  # a plain sum loses the twenty terms between them
        assert abs(in_order - got[0]) > 0.1 * abs(got[0] - gam[0] @ du)
        ab = np.abs(phi) @ np.abs(x) + np.abs(gam) @ np.abs(du)
        exact = _exact_rows(phi, x) + _exact_rows(gam, du)
        assert np.all(np.abs(got - exact) <= 2 * eps * np.abs(exact) + 24**2 * eps**2 * ab)
        assert np.all(np.abs(got - filter_law.time_update(phi, gam, x, du)) <= 24 * eps * ab)
        gain, c, m, m_d = rng.normal(size=(22, 10)), rng.normal(size=(10, 22)), rng.normal(size=10), rng.normal(
            size=10)
        want = filter_law.corrected(x, gain, c, m, m_d)
        bound = 32 * eps * (np.abs(x) + np.abs(gain) @ (np.abs(m) + np.abs(m_d) + np.abs(c) @ np.abs(x)))
        e = _eval(f["innovation"], x, c, m, m_d)
        assert np.all(np.abs(_eval(f["updated"], x, gain, e) - want) <= bound)
        drift = rng.normal(size=22)
        assert np.array_equal(_eval(f["time_update_drift"], phi, gam, x, du, drift), got + drift)
        assert np.all(np.abs(_eval(f["measured"], c, x) - _exact_rows(c, x)) <= eps * np.abs(c @ x)
                      + 22**2 * eps**2 * (np.abs(c) @ np.abs(x)))
        cmd, k, k_xi, xi = rng.normal(size=2), rng.normal(size=(2, 22)), rng.normal(size=(2, 2)), rng.normal(size=2)
        bound = 26 * eps * (np.abs(cmd) + np.abs(k) @ np.abs(x) + np.abs(k_xi) @ np.abs(xi))
        assert np.all(np.abs(_eval(f["free_torque"], cmd, k, x) - filter_law.free_torque(cmd, k, x)) <= bound)
        assert np.all(np.abs(_eval(f["free_torque_integral"], cmd, k, x, k_xi, xi)
                             - filter_law.free_torque(cmd, k, x, k_xi, xi)) <= bound)


def test_the_generated_bank_law_is_the_library_s_batched_one():
    """The payload bank's law per filter (likelihood, feedback) and over its filters (the weighted torque and
    estimate) as the library forms it for all filters at once; the generated sums run over LAW_BANK_FILTERS = 12
    filters, the unused ones weighted 0, which changes no bit. Bounds: n eps of the terms' magnitudes (BLAS)."""
    f, eps, n = _functions(law_codegen.filter_law_functions), np.finfo(float).eps, law_codegen.BANK_FILTERS
    rng = np.random.default_rng(13)
    for nf in (3, 9, n):
        e, s_inv = rng.normal(size=(nf, 10)), rng.normal(size=(nf, 10, 10))
        log_p, log_det = rng.normal(size=nf), rng.normal(size=nf)
        want = filter_law.log_likelihood_update(log_p, e, s_inv, log_det)  # batched, as BankController
        for i in range(nf):
            got = float(f["log_likelihood_update"](log_p[i], e[i], s_inv[i].ravel(), log_det[i]))
            scale = np.abs(e[i]) @ np.abs(s_inv[i]) @ np.abs(e[i]) + abs(log_det[i]) + abs(log_p[i])
            assert abs(got - want[i]) <= 24 * eps * scale
        k, x, k_xi, xi = rng.normal(size=(nf, 2, 22)), rng.normal(size=(nf, 22)), rng.normal(size=(nf, 2, 2)), \
            rng.normal(size=2)
        u = filter_law.feedback(k, x, k_xi, xi)
        for i in range(nf):
            bound = 26 * eps * (np.abs(k[i]) @ np.abs(x[i]) + np.abs(k_xi[i]) @ np.abs(xi))
            assert np.all(np.abs(_eval(f["feedback_integral"], k[i], x[i], k_xi[i], xi) - u[i]) <= bound)
            assert np.all(np.abs(_eval(f["feedback"], k[i], x[i]) - k[i] @ x[i]) <= bound)
        w, cmd = rng.dirichlet(np.ones(nf)), rng.normal(size=2)
        pad = lambda a: np.concatenate([a, np.zeros((n - len(a), *a.shape[1:]))])  # noqa: E731
        tau = _eval(f["bank_free_torque"], cmd, pad(w), pad(u))
        bound = 14 * eps * (np.abs(cmd) + w @ np.abs(u))
        assert np.all(np.abs(tau - filter_law.bank_free_torque(cmd, w, u)) <= bound)
        x_sel = _eval(f["weighted_estimate"], pad(w), pad(x))
        assert np.all(np.abs(x_sel - filter_law.weighted_estimate(w, x)) <= 14 * eps * (w @ np.abs(x)))


def test_the_generated_bank_posterior_is_the_library_s_bit_for_bit():
    """The posterior's normalisation, floor and normalisation again, over LAW_BANK_FILTERS = 12 entries with the
    models present marked: the absent ones (−inf) change no bit of NumPy's left fold, and a floored model, ±inf
    and NaN come out as the library's. exp and log1p here are CasADi's (the C library's, as NumPy's logaddexp's);
    the generated C calls the portable ones, held to NumPy's by the native bank's parity tests."""
    f = _functions(law_codegen.filter_law_functions)["normalised_posterior"]
    n, log_floor = law_codegen.BANK_FILTERS, math.log(1e-4)
    rng = np.random.default_rng(21)
    cases = [rng.normal(scale=s, size=nm) for nm in (1, 3, 9, 11) for s in (0.1, 30.0)]
    cases += [np.array([0.0, -50.0, -3.0]), np.array([2.0, 2.0, 2.0]), np.array([-np.inf, 0.0, 1.0]),
              np.array([np.nan, 0.0, 1.0]), np.array([1.0, np.inf, 0.0])]
    for log_p in cases:
        with np.errstate(invalid="ignore"):  # NaN and inf - inf: the cases meant
            want_log_p, want_p = filter_law.normalised_posterior(log_p, log_floor)
        nm = len(log_p)
        padded = np.concatenate([log_p, np.full(n - nm, 7.0)])  # what stands past the models must not matter
        got = f(padded, (np.arange(n) < nm).astype(float), log_floor)
        got_log_p, got_p = np.array(got[0]).ravel(), np.array(got[1]).ravel()
        np.testing.assert_array_equal(got_log_p[:nm], want_log_p)
        # p = exp(log p): NumPy's exp and the one CasADi evaluates with may round apart, by an ulp
        finite = np.isfinite(want_p)
        np.testing.assert_array_equal(np.isnan(got_p[:nm]), np.isnan(want_p))
        assert (np.abs(got_p[:nm][finite] - want_p[finite]) <= np.finfo(float).eps * want_p[finite]).all()
        assert (got_log_p[nm:] == -np.inf).all() and (got_p[nm:] == 0).all()
    floored = filter_law.normalised_posterior(np.array([0.0, -50.0]), log_floor)[0]
    assert floored[1] > -50.0  # the floor acts: the test above would see a wrong floor


def test_the_generated_reseeding_and_drift_are_the_library_s():
    """The quiet filter takes the unloaded model's estimate only below the threshold (NaN: never), bit for bit; the
    drift Ψ Δα is a compensated sum against NumPy's, so within 13 eps of Σ|Ψ||Δα| (11 terms, as the rows above)."""
    f = _functions(law_codegen.filter_law_functions)
    rng = np.random.default_rng(17)
    quiet, unloaded = rng.normal(size=22), rng.normal(size=22)
    for p_0, takes in ((1e-6, True), (0.5, False), (1e-3, False), (np.nan, False)):
        want = filter_law.reseeded(p_0, 1e-3, quiet, unloaded)
        np.testing.assert_array_equal(_eval(f["reseeded"], p_0, 1e-3, quiet, unloaded), want)
        np.testing.assert_array_equal(want, unloaded if takes else quiet)
    eps = np.finfo(float).eps
    for _ in range(20):
        psi, da = rng.normal(size=(22, 11)) * 10.0 ** rng.integers(-6, 2), rng.normal(size=11) * 50
        got = _eval(f["state_drift"], psi, da)
        assert np.all(np.abs(got - filter_law.state_drift(psi, da)) <= 13 * eps * (np.abs(psi) @ np.abs(da)))


def test_the_generated_covariance_step_is_the_library_s_time_varying_filter():
    """The predictor's time-varying filter (flexarm.lqg_design.transient_gains) on the committed design, 200
    samples from the predictor's large prior: the generated step (CasADi's products and LDLᵀ solve, row-major
    buffers read as transposes) against the library's (NumPy's products and LU solve). Both are backward stable,
    but the large prior makes C P Cᵀ + V's condition number up to 4e6 in the first samples and the recursion
    carries each sample's rounding on through P: measured at most 1.4e-9 of the largest gain over 300 samples
    (1e-11 once the filter has settled), so 1e-8. The runs' parity is the native tests'."""
    from flexarm.lqg import PREDICTOR_PRIOR, lqg_controller

    f = law_codegen.covariance_step_function()
    design = lqg_controller().design
    c, v = design.C, design.V
    p_lib = PREDICTOR_PRIOR * design.P_prior[0]
    p_gen = p_lib.copy()
    for j in range(200):
        i = min(j // 50, len(design.Phi) - 1)
        want_gain, p_lib = filter_law.covariance_step(p_lib, c, v, design.Phi[i], design.W[i])
        got = f(*[a.T for a in (p_gen, c, v, design.Phi[i], design.W[i])])  # the C's row-major buffers
        got_gain, p_gen = np.array(got[0]).T, np.array(got[1]).T
        assert np.abs(got_gain - want_gain).max() <= 1e-8 * np.abs(want_gain).max(), j
        np.testing.assert_array_equal(p_gen, p_gen.T)  # symmetrised, as the library's
    assert np.abs(p_gen - p_lib).max() <= 1e-8 * np.abs(p_lib).max()


def test_the_generated_anti_windup_integrates_only_an_unsaturated_sample():
    """ξ + dt C_q x when τ = τ_free, else ξ: a saturated torque, or a NaN one (never equal), holds the integrator,
    in the library and in the generated C alike."""
    f = _functions(law_codegen.filter_law_functions)["integrated"]
    rng = np.random.default_rng(9)
    c_q, x, xi, dt = rng.normal(size=(2, 22)), rng.normal(size=22), rng.normal(size=2), 1e-3
    for tau, tau_free, moves in (([1.0, 2.0], [1.0, 2.0], True), ([7.0, 2.0], [9.0, 2.0], False),
                                 ([np.nan, 0.0], [np.nan, 0.0], False)):
        tau, tau_free = np.array(tau), np.array(tau_free)
        want = filter_law.integrated(xi, dt, c_q, x, tau, tau_free)
        got = _eval(f, xi, dt, c_q, x, tau, tau_free)
        assert np.allclose(got, want, rtol=0, atol=1e-15 * np.abs(want).max())  # sums as in the test above
        assert (not np.array_equal(want, xi)) == moves and (not np.array_equal(got, xi)) == moves


def test_the_hand_written_lqg_c_does_no_arithmetic_of_the_filters():
    """The LQG FMU's filter, predictor, feedback and anti-windup, the payload bank's per sample (posterior,
    re-seeding) and its drift, and the predicting paper's law's measurement are the generated ones; the hand C only
    says which sample and which design point."""
    core = (NATIVE_CONTROLLER / "lqg_core.c").read_text()
    estimate = core[core.index("void lqg_estimate"):core.index("void lqg_schedule_index")]
    propagate = core[core.index("void lqg_propagate"):core.index("void lqg_feedforward")]
    assert "law_innovation(" in estimate and "law_updated(" in estimate and "law_time_update_drift(" in propagate
    assert "lqg_mat_vec" not in estimate + propagate
    riccati = core[core.index("int lqg_transient_gains"):]
    assert "law_covariance_step(" in riccati and not re.search(r"\bsqrt\(|NEUMAIER|mat_mul", core)
    lqg = (NATIVE_CONTROLLER / "controller_lqg.c").read_text()
    assert "lqg_mat_vec" not in lqg and "law_free_torque" in lqg and "law_integrated(" in lqg
    assert "lqg_mat_vec" not in (NATIVE_CONTROLLER / "controller.c").read_text()
    bank = (NATIVE_CONTROLLER / "lqg_bank.c").read_text()
    step = bank[bank.index("void bank_step"):]
    assert "lqg_mat_vec" not in step and "law_log_likelihood_update(" in step and "law_bank_free_torque(" in step
    assert "law_reseeded(" in step and "law_state_drift(" in bank and "lqg_mat_vec" not in bank
    assert "law_normalised_posterior(" in step and not re.search(r"\b(flexarm_)?(exp|log1p|logaddexp)\(", step)


def test_the_generated_sensor_law_is_the_library_s_bit_for_bit():
    """One channel at a time the generated functions run the library's operations in its order, so the two agree
    to the last bit, signed zeros and halves included (the quantiser rounds halves to even, as NumPy)."""
    f = _functions(law_codegen.sensor_law_functions)
    rng = np.random.default_rng(11)
    for _ in range(200):
        sos, s0, s1, x = rng.normal(size=6), rng.normal(), rng.normal(), rng.normal() * 10.0 ** rng.integers(-6, 2)
        y, n0, n1 = sensor_law.filter_section(sos, np.array([s0]), np.array([s1]), np.array([x]))
        got = f["filter_section"](sos, s0, s1, x)
        assert [float(g) for g in got] == [y[0], n0[0], n1[0]]
        zi = rng.normal(size=2)
        assert np.array_equal(_eval(f["primed_state"], zi, x), sensor_law.primed_state(zi, x))
        a, u = abs(rng.normal()), rng.random()
        assert float(f["with_noise"](x, a, u)) == sensor_law.with_noise(np.array([x]), a, np.array([u]))[0]
    lsb = 0.25
    for x in (-0.3 * lsb, -0.5 * lsb, 0.5 * lsb, 1.5 * lsb, 2.5 * lsb, -2.5 * lsb, 1e3, -1e3, 0.1, -0.0, 7.0 * lsb,
              2.0**60, np.inf, -np.inf, np.nan):  # a diverged signal stays NaN, as in NumPy: never a bound
        for lo, hi in ((-8.0, 7.0), (-np.inf, np.inf)):
            want = sensor_law.quantize(np.array([x]), lsb, lo, hi)[0]
            got = float(f["quantize"](x, lsb, lo, hi))
            assert np.array_equal(got, want, equal_nan=True), (x, lo, got, want)
            assert np.isnan(got) or np.signbit(got) == np.signbit(want), (x, lo, got, want)
    limit, saturate = np.array([7.0, 2.25]), _functions()["saturate"]
    for tau in ([np.nan, -0.0], [np.inf, -np.inf], [-0.0, 0.0]):  # the controllers' saturation: the same rule
        got, want = _eval(saturate, np.array(tau), limit), law.saturate(np.array(tau), limit)
        real = ~np.isnan(want)  # a NaN's sign bit means nothing
        assert np.array_equal(got, want, equal_nan=True) and np.array_equal(np.signbit(got[real]),
                                                                            np.signbit(want[real])), tau
    assert sensor_law.quantize(np.array([0.5 * lsb, 1.5 * lsb]), lsb, -8, 7).tolist() == [0.0, 2 * lsb]


def test_the_generated_channel_scales_are_the_library_s_bit_for_bit():
    """Each channel's noise half-width and quantum from the settings (degrees to radians, the gauges' curvature
    full scale times their segment, 2 FS / 2^bits, the code range), as the Python sensors compute them."""
    f = law_codegen.channel_scales_function()
    rng = np.random.default_rng(5)
    for bits in (8, 10, 12, 16):
        args = [*rng.uniform(0.0, 2.0, 4), float(rng.integers(256, 100000)), rng.uniform(100, 1000),
                rng.uniform(0.1, 10.0, 2), rng.uniform(0.01, 0.2, 6), rng.uniform(10, 200), 2.0 ** bits]
        want = sensor_law.channel_scales(*args)
        for w, g in zip(want, f(*args)):
            np.testing.assert_array_equal(np.array(g).ravel(), np.ravel(w))
        assert want[4] == -(2 ** (bits - 1)) and want[5] == 2 ** (bits - 1) - 1


def test_the_hand_written_sensors_c_does_no_arithmetic_of_the_law():
    """The sensors' C keeps the state; the per-sample arithmetic and the filters' design are the generated law's
    (flexarm/filter_design.py): no complex arithmetic, pole pairing or 2×2 solve by hand."""
    text = (NATIVE / "sensors" / "sensors.c").read_text()
    assert '#include "sensor_law_api.h"' in text and "law_butterworth_order_8" in text
    for by_hand in (r"\bhypot\s*\(", r"\bCplx\b", r"flexarm_(cos|sin)\s*\(", r"\bpow\s*\(", r"\*\s*deg\b",
                    r"2\.0\s*\*\s*full_scale"):
        assert not re.search(by_hand, text), by_hand
    for by_hand in (r"\bnearbyint\s*\(", r"2\.0\s*\*\s*u\[", r"s\[4\]\s*\*", r"zi\[k\]\[j\]\s*\*"):
        assert not re.search(by_hand, text), by_hand
