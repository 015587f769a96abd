"""Sensor bank: pass-through, noise statistics, seeds, filters, quantisation, state, reconstruction."""

import math
import pickle

import numpy as np
import pytest
from scipy import stats

from flexarm import ArmModel, load_parameters, reconstruct_angles, rigid_configuration
from flexarm.integrator import PlantSimulator
from flexarm.model import N, joint_angles, joint_velocities, strain_gauge_angles
from flexarm.sensors import (
    ACCELEROMETERS,
    DEFAULT_SENSOR_FILE,
    ENCODERS,
    MEASURED_SIGNAL_NAMES,
    MEASURED_SIGNALS,
    N_SIGNALS,
    STRAIN_GAUGES,
    TACHOMETERS,
    TRUE_SIGNAL_NAMES,
    TRUE_SIGNALS,
    SensorBank,
    SensorSettings,
    SensorSettingsError,
    angle_to_curvature,
    as_dict,
    curvature_to_angle,
    load_sensor_settings,
    strain_gauge_segment_lengths,
    true_signals_from_state,
)

DT = 1e-3
DEG = math.pi / 180
#: Everything off: the bank must be the identity.
CLEAN = SensorSettings(noise_enabled=False)
RNG = np.random.default_rng(7)


@pytest.fixture(scope="module")
def params():
    return load_parameters()


@pytest.fixture(scope="module")
def model(params):
    return ArmModel(params)


def random_truth(n, rng=RNG):
    """n plausible true-signal vectors, shape (n, 12)."""
    scale = np.array([3.0, 2.5, 3.0, 5.0, *[0.01] * 3, *[0.2] * 3, 30.0, 60.0])
    return rng.uniform(-1, 1, (n, N_SIGNALS)) * scale


def run(bank, truth):
    return np.array([bank.measure(x) for x in truth])


def fitted_gain(bank, channel, f_hz, amplitude, settle_s, fit_periods=20):
    """Drive one channel with a sinusoid, fit a·sin + b·cos + c in steady state, return amplitude ratio."""
    n_settle = int(round(settle_s / DT))
    n_fit = int(round(fit_periods / f_hz / DT))
    t = np.arange(n_settle + n_fit) * DT
    u = amplitude * np.sin(2 * np.pi * f_hz * t + 0.3)
    x = np.zeros(N_SIGNALS)
    y = np.empty(t.size)
    for k, uk in enumerate(u):
        x[channel] = uk
        y[k] = bank.measure(x)[channel]
    tt, yy = t[n_settle:], y[n_settle:]
    basis = np.column_stack([np.sin(2 * np.pi * f_hz * tt), np.cos(2 * np.pi * f_hz * tt), np.ones_like(tt)])
    coef, *_ = np.linalg.lstsq(basis, yy, rcond=None)
    return math.hypot(coef[0], coef[1]) / amplitude


# -- signals and settings ---------------------------------------------------------------
def test_signal_tables():
    assert TRUE_SIGNAL_NAMES == ("q1", "q2", "qd1", "qd2", "eps1", "eps2", "eps3", "eps4", "eps5", "eps6",
                                 "acc1_n", "acc2_n")
    assert MEASURED_SIGNAL_NAMES == ("q1_m", "q2_m", "qd1_m", "qd2_m", *(f"eps{i}_m" for i in range(1, 7)),
                                     "acc1_m", "acc2_m")
    units = ["rad"] * 2 + ["rad/s"] * 2 + ["rad"] * 6 + ["m/s2"] * 2
    assert [s.unit for s in TRUE_SIGNALS] == units == [s.unit for s in MEASURED_SIGNALS]


def test_default_file_matches_dataclass_defaults():
    assert SensorSettings.from_toml(DEFAULT_SENSOR_FILE) == SensorSettings()
    s = SensorSettings()
    # The paper's figures.
    assert (s.encoder_noise_deg, s.tachometer_noise_deg_per_s, s.strain_gauge_noise_deg) == (0.1, 1.0, 0.05)
    assert (s.strain_gauge_cutoff_hz, s.accelerometer_cutoff_hz, s.adc_bits) == (100.0, 10.0, 12)
    assert not s.strain_gauge_filter and not s.accelerometer_filter


@pytest.mark.parametrize("change, field, allowed", [
    ({"encoder_noise_deg": -0.1}, "encoder_noise_deg", "[0, inf)"),
    ({"accelerometer_noise_m_per_s2": float("nan")}, "accelerometer_noise_m_per_s2", "[0, inf)"),
    ({"strain_gauge_cutoff_hz": 0.0}, "strain_gauge_cutoff_hz", "(0, inf)"),
    ({"tachometer_full_scale_deg_per_s": -5.0}, "tachometer_full_scale_deg_per_s", "(0, inf)"),
    ({"strain_gauge_filter_order": 0}, "strain_gauge_filter_order", "[1, 8]"),
    ({"adc_bits": 12.0}, "adc_bits", "[2, 24]"),
    ({"encoder_counts_per_rev": 1}, "encoder_counts_per_rev", "[2, 16777216]"),
    ({"noise_seed": -1}, "noise_seed", "[0, 9223372036854775807]"),
    ({"noise_enabled": 1}, "noise_enabled", "true or false"),
    ({"strain_gauge_full_scale_curvature_per_m": (0.5, 0.0)}, "strain_gauge_full_scale_curvature_per_m[1]",
     "(0, inf)"),
])
def test_settings_validation_names_field_and_range(change, field, allowed):
    with pytest.raises(SensorSettingsError) as err:
        SensorSettings().replace(**change)
    assert field in str(err.value) and allowed in str(err.value)


def test_cutoff_must_be_below_nyquist(params):
    with pytest.raises(SensorSettingsError, match=r"accelerometer_cutoff_hz: 500.0 Hz .*\(0, 500\) Hz"):
        SensorBank(SensorSettings(accelerometer_cutoff_hz=500.0), params, DT)
    SensorBank(SensorSettings(accelerometer_cutoff_hz=499.0), params, DT)
    with pytest.raises(SensorSettingsError, match="dt"):
        SensorBank(SensorSettings(), params, 0.0)


def test_toml_loading_and_errors(tmp_path):
    good = tmp_path / "s.toml"
    good.write_text("[noise]\nseed = 42\n[strain_gauge]\nfilter = true\ncutoff_hz = 50.0\n")
    s = SensorSettings.from_toml(good)
    assert (s.noise_seed, s.strain_gauge_filter, s.strain_gauge_cutoff_hz) == (42, True, 50.0)
    assert s.encoder_noise_deg == 0.1  # unspecified keys keep the defaults
    assert load_sensor_settings(good, noise_enabled=False).noise_enabled is False
    bad = tmp_path / "bad.toml"
    bad.write_text("[encoder]\nnoise_degrees = 0.1\n")
    with pytest.raises(SensorSettingsError, match=r"\[encoder\] noise_degrees: unknown"):
        SensorSettings.from_toml(bad)
    bad.write_text("[tachometer]\nnoise_deg_per_s = -1.0\n")
    with pytest.raises(SensorSettingsError, match="tachometer_noise_deg_per_s"):
        SensorSettings.from_toml(bad)


# -- pass-through and true signals --------------------------------------------------------
def test_everything_off_returns_true_signals_exactly(params):
    bank = SensorBank(CLEAN, params, DT)
    truth = random_truth(500)
    assert np.array_equal(run(bank, truth), truth)
    named = dict(zip(TRUE_SIGNAL_NAMES, truth[0]))
    assert np.array_equal(bank.measure(named), truth[0])
    assert as_dict(truth[0])["acc2_m"] == truth[0, 11]


def test_true_signals_from_state(model):
    z = np.concatenate([rigid_configuration(0.4, 1.1) + RNG.normal(0, 0.01, N), RNG.normal(0, 1, N)])
    tau = np.array([3.0, -1.0])
    x = true_signals_from_state(model, z, tau)
    th, om = z[:N], z[N:]
    assert np.array_equal(x[ENCODERS], joint_angles(th))
    assert np.array_equal(x[TACHOMETERS], joint_velocities(om))
    assert np.array_equal(x[STRAIN_GAUGES], strain_gauge_angles(th))
    # Accelerometer axis: normal to the last segment of each link.
    acc = model.link_tip_accelerations(th, om, tau)
    for row, p in enumerate((4, 10)):
        normal = np.array([-np.sin(th[p]), np.cos(th[p])])
        assert x[ACCELEROMETERS][row] == pytest.approx(acc[row] @ normal, rel=1e-12, abs=1e-12)


def test_curvature_angle_conversion(params):
    a = strain_gauge_segment_lengths(params)
    # One third of each flexible link (paper: 0.46 m and 0.49 m).
    assert a == pytest.approx([0.46 / 3] * 3 + [0.49 / 3] * 3, rel=1e-12)
    kappa = np.array([0.1, -0.2, 0.05, 1.0, -2.0, 0.5])
    eps = curvature_to_angle(kappa, a)
    assert eps == pytest.approx(kappa * a, rel=1e-15)
    assert angle_to_curvature(eps, a) == pytest.approx(kappa, rel=1e-14)
    bank = SensorBank(CLEAN, params, DT)
    y = bank.measure(np.concatenate([np.zeros(4), eps, np.zeros(2)]))
    assert bank.curvatures(y) == pytest.approx(kappa, rel=1e-14)


# -- noise ------------------------------------------------------------------------------
NOISE_SETTINGS = SensorSettings(noise_enabled=True, noise_seed=2024, accelerometer_noise_m_per_s2=0.5)
N_NOISE = 20000


@pytest.fixture(scope="module")
def noise_run(params):
    bank = SensorBank(NOISE_SETTINGS, params, DT)
    truth = random_truth(N_NOISE, np.random.default_rng(3))
    return bank, truth, run(bank, truth) - truth


def test_noise_uniform_bounds_variance_and_ks(noise_run):
    bank, _, err = noise_run
    expected = np.array([0.1 * DEG] * 2 + [1.0 * DEG] * 2 + [0.05 * DEG] * 6 + [0.5] * 2)
    assert np.array_equal(bank.noise_amplitude, expected)
    for ch, a in enumerate(expected):
        e = err[:, ch]
        assert np.all(np.abs(e) <= a * (1 + 1e-12)), MEASURED_SIGNAL_NAMES[ch]
        # sd of the sample variance of U(-a, a) is a²/3 · sqrt(0.8/n) (0.63 % here): allow 5 sd.
        assert np.var(e) == pytest.approx(a**2 / 3, rel=5 * math.sqrt(0.8 / N_NOISE))
        assert abs(np.mean(e)) < 5 * a / math.sqrt(3 * N_NOISE)
        p = stats.kstest(e, "uniform", args=(-a, 2 * a)).pvalue
        assert p > 1e-3, (MEASURED_SIGNAL_NAMES[ch], p)
    # The KS test has power: a reference 5 % too narrow is rejected.
    a0 = expected[0]
    assert stats.kstest(err[:, 0], "uniform", args=(-0.95 * a0, 2 * 0.95 * a0)).pvalue < 1e-6


def test_channels_of_one_bank_are_uncorrelated(noise_run):
    _, _, err = noise_run
    r = np.corrcoef(err.T)
    off = r[~np.eye(N_SIGNALS, dtype=bool)]
    assert np.max(np.abs(off)) < 5 / math.sqrt(N_NOISE)


def test_same_seed_same_stream_other_seed_other_stream(params):
    truth = random_truth(300)
    y1 = run(SensorBank(NOISE_SETTINGS, params, DT), truth)
    y2 = run(SensorBank(NOISE_SETTINGS, params, DT), truth)
    assert np.array_equal(y1, y2)
    y3 = run(SensorBank(NOISE_SETTINGS.replace(noise_seed=2025), params, DT), truth)
    assert not np.any(y1 == y3)
    # reset() restarts the stream; reset(seed) switches it.
    bank = SensorBank(NOISE_SETTINGS, params, DT)
    run(bank, truth[:17])
    bank.reset()
    assert np.array_equal(run(bank, truth), y1)
    bank.reset(seed=2025)
    assert np.array_equal(run(bank, truth), y3)


def test_different_seeds_are_independent(params):
    zeros = np.zeros((N_NOISE, N_SIGNALS))
    e1 = run(SensorBank(NOISE_SETTINGS.replace(noise_seed=11), params, DT), zeros)
    e2 = run(SensorBank(NOISE_SETTINGS.replace(noise_seed=12), params, DT), zeros)
    for ch in range(N_SIGNALS):
        r = np.corrcoef(e1[:, ch], e2[:, ch])[0, 1]
        assert abs(r) < 5 / math.sqrt(N_NOISE), (MEASURED_SIGNAL_NAMES[ch], r)


def test_noise_stream_does_not_depend_on_other_settings(params):
    """Each channel's noise depends on the seed and the sample index only."""
    truth = np.zeros((200, N_SIGNALS))
    base = run(SensorBank(NOISE_SETTINGS, params, DT), truth)
    other = run(SensorBank(NOISE_SETTINGS.replace(strain_gauge_filter=True, accelerometer_noise_m_per_s2=0.0,
                                                  adc_quantization=True), params, DT), truth)
    assert np.array_equal(base[:, ENCODERS], other[:, ENCODERS])


# -- filters ----------------------------------------------------------------------------
FILTERS_ON = SensorSettings(noise_enabled=False, strain_gauge_filter=True, accelerometer_filter=True)


@pytest.mark.parametrize("group, fc", [(STRAIN_GAUGES, 100.0), (ACCELEROMETERS, 10.0)])
def test_filter_gain_at_cutoff_and_dc(params, group, fc):
    for ch in range(group.start, group.stop):
        bank = SensorBank(FILTERS_ON, params, DT)
        g = fitted_gain(bank, ch, fc, 0.01, settle_s=20 / fc)
        assert 20 * math.log10(g) == pytest.approx(-3.0103, abs=0.5)
        # Pre-warping makes it exact; without it the 100 Hz filter would read −3.31 dB.
        assert 20 * math.log10(g) == pytest.approx(-3.0103, abs=0.01)
        # Well above the cut-off a 2nd-order low-pass attenuates strongly; well below it passes.
        bank.reset()
        assert fitted_gain(bank, ch, 4 * fc, 0.01, settle_s=20 / fc) < 10 ** (-18 / 20)
        bank.reset()
        assert fitted_gain(bank, ch, fc / 20, 0.01, settle_s=40 / fc, fit_periods=4) == pytest.approx(1, abs=0.01)
    # DC gain 1: a step settles at its final value.
    bank = SensorBank(FILTERS_ON, params, DT)
    x = np.zeros(N_SIGNALS)
    bank.measure(x)
    x[group] = 0.02
    y = run(bank, np.tile(x, (int(40 / fc / DT), 1)))
    assert y[-1, group] == pytest.approx(x[group], rel=1e-9)
    assert np.max(np.abs(y[:, group] - x[group])) > 1e-3  # it did take time to settle


def test_filter_starts_in_steady_state_and_leaves_other_channels(params):
    bank = SensorBank(FILTERS_ON, params, DT)
    x = random_truth(1)[0]
    y = run(bank, np.tile(x, (50, 1)))
    # Up to rounding: the 10 Hz filter's poles are near z = 1, which amplifies it a little.
    assert np.max(np.abs(y - x)) < 1e-12 * np.max(np.abs(x))
    # Encoders and tachometers are not filtered.
    truth = random_truth(100)
    y = run(bank, truth)
    assert np.array_equal(y[:, :4], truth[:, :4])
    assert not np.allclose(y[:, STRAIN_GAUGES], truth[:, STRAIN_GAUGES])


# -- quantisation -------------------------------------------------------------------------
def test_quantisation_error_within_half_lsb(params):
    s = SensorSettings(noise_enabled=False, encoder_quantization=True, adc_quantization=True)
    bank = SensorBank(s, params, DT)
    assert bank.encoder_lsb == pytest.approx(2 * math.pi / 4096)
    lsb = bank.adc_lsb.copy()
    lsb[ENCODERS] = bank.encoder_lsb
    assert bank.adc_lsb[TACHOMETERS] == pytest.approx(2 * 720 * DEG / 4096)
    assert bank.adc_lsb[ACCELEROMETERS] == pytest.approx(2 * 98.0665 / 4096)
    assert bank.adc_lsb[STRAIN_GAUGES] == pytest.approx(
        2 * np.repeat([0.5, 5.0], 3) * strain_gauge_segment_lengths(params) / 4096)
    # Inside the full scale (the encoders have none: a multi-turn counter).
    fs = np.where(np.isfinite(bank.full_scale), bank.full_scale, 50.0)
    truth = RNG.uniform(-1, 1, (5000, N_SIGNALS)) * (fs - lsb)
    y = run(bank, truth)
    err = y - truth
    assert np.all(np.abs(err) <= lsb / 2 * (1 + 1e-9))
    assert np.max(np.abs(err) / lsb) > 0.49  # the bound is reached, not trivially met
    codes = y / lsb
    assert np.allclose(codes, np.round(codes), atol=1e-6)
    # Saturation of the A/D channels at codes -2048 and 2047.
    y = bank.measure(np.where(np.isfinite(bank.full_scale), 3 * bank.full_scale, 0.0))
    assert np.allclose(y[2:], 2047 * lsb[2:], rtol=1e-12)
    y = bank.measure(np.where(np.isfinite(bank.full_scale), -3 * bank.full_scale, 0.0))
    assert np.allclose(y[2:], -2048 * lsb[2:], rtol=1e-12)


# -- state ------------------------------------------------------------------------------
def test_get_set_state_reproduces_bit_for_bit(params):
    s = SensorSettings(noise_enabled=True, noise_seed=5, strain_gauge_filter=True, accelerometer_filter=True,
                       adc_quantization=True, encoder_quantization=True, accelerometer_noise_m_per_s2=0.2)
    truth = random_truth(300)
    bank = SensorBank(s, params, DT)
    run(bank, truth[:100])
    snap = pickle.loads(pickle.dumps(bank.get_state()))
    first = run(bank, truth[100:])
    bank.set_state(snap)
    assert np.array_equal(run(bank, truth[100:]), first)
    # Into a fresh instance (as an FMU's setFMUstate would), and the snapshot is not aliased.
    other = SensorBank(s, params, DT)
    other.set_state(snap)
    assert np.array_equal(run(other, truth[100:]), first)
    assert other.n_samples == 300
    # A fresh, unprimed snapshot re-primes the filters on the next sample.
    fresh = SensorBank(s, params, DT)
    snap0 = fresh.get_state()
    a = run(fresh, truth[:50])
    fresh.set_state(snap0)
    assert np.array_equal(run(fresh, truth[:50]), a)
    with pytest.raises(ValueError, match="strain_filter"):
        SensorBank(CLEAN, params, DT).set_state(snap)


# -- reconstruction (eqs. 21-31) ------------------------------------------------------------
def test_reconstruction_exact_with_rigid_brackets(model, params):
    bank = SensorBank(CLEAN, params, DT)
    for _ in range(10):
        th = rigid_configuration(RNG.uniform(-np.pi, np.pi), RNG.uniform(-2.5, 2.5))
        # Deform the links only; brackets stay rigid (θ2 = θ1, θ6 = θ5, θ8 = θ7).
        bend = np.zeros(N)
        bend[[2, 3, 4]] = np.cumsum(RNG.normal(0, 0.01, 3))
        bend[5:] = bend[4]
        bend[[8, 9, 10]] += np.cumsum(RNG.normal(0, 0.1, 3))
        th = th + bend
        th[1], th[5], th[7] = th[0], th[4], th[6]
        z = np.concatenate([th, RNG.normal(0, 1, N)])
        y = bank.measure(true_signals_from_state(model, z, RNG.normal(0, 1, 2)))
        assert np.max(np.abs(reconstruct_angles(y[ENCODERS], y[STRAIN_GAUGES]) - th)) < 1e-12


def test_reconstruction_of_simulated_state_is_off_by_the_bracket_deflections(model, params):
    sim = PlantSimulator(model, np.concatenate([rigid_configuration(-0.6, 1.4), np.zeros(N)]))
    tau = np.array([5.0, -1.5])
    for _ in range(150):
        sim.step(tau, DT)
    th = sim.theta.copy()
    y = SensorBank(CLEAN, params, DT).measure(true_signals_from_state(model, sim.z, tau))
    th_rec = reconstruct_angles(y[ENCODERS], y[STRAIN_GAUGES])
    # Rigid-bracket assumption: element i is off by minus the bracket deflections proximal to it.
    d = np.zeros(N)
    d[1], d[5], d[7] = th[1] - th[0], th[5] - th[4], th[7] - th[6]
    assert np.max(np.abs(th_rec - (th - np.cumsum(d)))) < 1e-12
    assert 0 < np.max(np.abs(d)) < 1e-3  # deformed, but stiff brackets
    assert np.max(np.abs(strain_gauge_angles(th))) > 1e-3  # the links did bend



def test_rewind_repeats_the_samples_since_a_checkpoint():
    """checkpoint/rewind (what the sensors FMU does per sample) repeats noise and filter output bit for bit."""
    from flexarm.sensors import SensorBank, SensorSettings

    bank = SensorBank(SensorSettings(noise_enabled=True, noise_seed=11, strain_gauge_filter=True,
                                     accelerometer_filter=True))
    x = np.linspace(0.1, 1.2, 12)
    bank.measure(x)
    mark = bank.checkpoint()
    first = [bank.measure(x * (1 + 0.1 * k)) for k in range(3)]
    bank.rewind(mark)
    again = [bank.measure(x * (1 + 0.1 * k)) for k in range(3)]
    assert all(np.array_equal(a, b) for a, b in zip(first, again))
    assert bank.n_samples == 4
    with pytest.raises(ValueError, match="checkpoint"):
        bank.rewind({**mark, "n_samples": 99})
