"""The paper's qualitative findings (notes section 4), checked on full three-FMU runs of the shipped scenarios.

Each test names the finding and says whether it HOLDS or DOES NOT HOLD in our model (with the calibrated
parameters, t_f = 2.058 s); where it does not, the test asserts what our model does instead. The numbers
and their interpretation are in docs/findings.md (generated data: docs/findings-data.md,
``python -m scenarios.reports.reexamine``). Runs use the default plant (RODAS4, no damping) unless the test is
about the integrator: then the non-dissipative scheme (plant integrator = 2, exponential) is used too.
"""

import copy

import numpy as np
import pytest

from flexarm import ArmModel
from flexarm.control import PEAK_TORQUE
from flexarm.lqr import GainSchedule, effective_gain, zoh
from flexarm.trajectory import load_trajectory
from scenarios.config import load_scenario
from scenarios.run.runner import run_scenario

SCENARIOS = ("table1", "table2", "table3", "compare_ff_fb", "compare_schedule")
EXPONENTIAL = "exponential"  # the plant FMU's integrator choice of the non-dissipative scheme (value 2)


def with_plant(scenario, **plant):
    """The scenario with plant parameters set on every case (e.g. integrator, damping_ratio)."""
    s = copy.deepcopy(scenario)
    s.name = scenario.name + "-" + "-".join(f"{k}{v}" for k, v in plant.items())
    for case in s.cases:
        case.parameters.setdefault("plant", {}).update(plant)
    return s


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("findings")
    metrics = {}
    for name in SCENARIOS:
        for r in run_scenario(load_scenario(name), out, progress=False):
            metrics[(name, r.key)] = r.metrics
    return metrics


@pytest.fixture(scope="module")
def exponential_runs(tmp_path_factory):
    """Tables 1 and 2 with the non-dissipative integrator: (table, case) -> (status, metrics)."""
    out = tmp_path_factory.mktemp("findings_exponential")
    results = {}
    for name in ("table1", "table2"):
        for r in run_scenario(with_plant(load_scenario(name), integrator=EXPONENTIAL), out, progress=False):
            results[(name, r.key)] = (r.status, r.metrics)
    return results


def rms_pos(m):
    return m["rms_position_error"]


def rms_vel(m):
    return m["rms_velocity_error"]


@pytest.mark.parametrize("table", ["table1", "table2", "table3"])
def test_every_case_stays_within_the_motor_limits(runs, table):
    """Paper: peak torques stay within 7.0 and 2.25 N·m in every case. HOLDS (RODAS4 plant)."""
    for case in ("none", "noise", "tip", "tip_noise"):
        m = runs[(table, case)]
        assert m is not None, f"{table}:{case} unbounded"
        assert m["peak_tau1"] <= PEAK_TORQUE[0] + 1e-9 and m["peak_tau2"] <= PEAK_TORQUE[1] + 1e-9


@pytest.mark.parametrize("table", ["table1", "table2", "table3"])
def test_payload_degrades_velocity_tracking_far_more_than_position(runs, table):
    """Paper: with the 0.275 kg payload velocity errors reach 150-190 deg/s while positions stay within ~10 deg.

    HOLDS: ours 94-126 deg/s peak velocity error, 9.8-15 deg peak position error."""
    none, tip = runs[(table, "none")], runs[(table, "tip")]
    assert rms_vel(tip) > 5 * rms_vel(none)
    assert tip["peak_position_error"] < 20.0
    assert tip["peak_velocity_error"] > 5 * tip["peak_position_error"]


def test_gamma1_is_the_most_noise_sensitive(runs):
    """Paper: gamma = 1 is fragile under noise. HOLDS in ordering only (rms position error with noise / without:
    gamma 1 > 0.1 > 0); the runs stay bounded (see the next tests)."""
    amplification = {t: rms_pos(runs[(t, "noise")]) / rms_pos(runs[(t, "none")])
                     for t in ("table1", "table2", "table3")}
    assert amplification["table1"] > amplification["table2"] > amplification["table3"] > 1.0


def test_gamma1_with_noise_goes_unbounded_within_the_slew(runs, exponential_runs):
    """Paper: gamma = 1 with noise becomes numerically unbounded within the 2.058 s run.

    DOES NOT HOLD as stated. With the non-dissipative plant the gamma = 1 loop IS unstable, but with and
    without noise alike (its 5.7 kHz bracket mode grows at about 3 1/s, linear ZOH analysis); within the
    2.058 s slew it reaches only ~150-190 deg/s peak velocity error (tau2 saturating), far from unbounded,
    and it keeps growing after the slew (docs/findings.md). With RODAS4 it looks stable (~8 deg/s). The run's
    own samples say so: its status is "diverging" (scenarios/run/verdict.py), with every step done and its metrics."""
    for case in ("none", "noise"):
        status, m = exponential_runs[("table1", case)]
        assert status == "diverging" and m is not None  # bounded within the slew, and growing
        assert m["peak_velocity_error"] > 10 * runs[("table1", case)]["peak_velocity_error"]
        assert m["peak_tau2"] == pytest.approx(PEAK_TORQUE[1])  # the elbow motor saturates
    noise, quiet = exponential_runs[("table1", "noise")][1], exponential_runs[("table1", "none")][1]
    assert noise["peak_velocity_error"] < 2 * quiet["peak_velocity_error"]  # noise is not the cause


def test_bracket_instability_needs_almost_no_damping():
    """Paper (cause of the divergence): 'the lack of joint dampening in the model and the one millisecond
    step'. HOLDS for the sampled loop's bracket mode: undamped, gamma = 1 grows (ln rho > 0 at some scheduled
    set); a modal damping ratio of 0.005, far below a bolted arm's, makes every set stable."""
    traj = load_trajectory()
    sched = GainSchedule.load("gamma1")

    def worst_rate(ratio):
        model = ArmModel(damping_ratio=ratio)
        rates = []
        for t_k, gain in zip(sched.times, sched.gains):
            A, B = model.linearize(traj.state(min(int(round(t_k / 1e-3)), traj.n_samples)))
            phi, gam = zoh(A, B)
            rates.append(np.log(np.abs(np.linalg.eigvals(phi - gam @ effective_gain(gain))).max()) / 1e-3)
        return max(rates)

    assert worst_rate(0.0) > 1.0  # 1/s (measured 3.27)
    assert worst_rate(0.005) < 0.0  # measured -0.15


def test_gamma01_tolerates_noise_and_payload(runs):
    """Paper: gamma = 0.1 stays bounded with noise and payload; noise costs little position accuracy. HOLDS."""
    for case in ("noise", "tip", "tip_noise"):
        assert runs[("table2", case)] is not None
    assert rms_pos(runs[("table2", "noise")]) < 0.1  # deg
    assert rms_pos(runs[("table2", "tip_noise")]) < 1.2 * rms_pos(runs[("table2", "tip")])


def test_noise_multiplies_gamma01_velocity_errors(runs, exponential_runs):
    """Paper (Table 2): noise multiplies the gamma = 0.1 velocity errors 4.7x (peak) and 3.6x (rms).

    DOES NOT HOLD: ours 1.00-1.05x under both integrators, so the integrator is not the cause; the noise
    reaching the loop is (about ten times the stated amplitudes reproduces the paper's ratios,
    docs/findings.md)."""
    ratios = [rms_vel(runs[("table2", "noise")]) / rms_vel(runs[("table2", "none")])]
    ratios.append(rms_vel(exponential_runs[("table2", "noise")][1]) / rms_vel(exponential_runs[("table2", "none")][1]))
    assert all(1.0 <= r < 1.2 for r in ratios), ratios


def test_velocity_weighting_helps_with_the_payload(runs):
    """Paper: gamma = 0 tracks the payload worst in velocity (Table 3: 184.6 deg/s peak vs 152.8 at gamma 0.1).
    HOLDS (ours 125.5 vs 104.4 deg/s)."""
    assert rms_vel(runs[("table3", "tip")]) > rms_vel(runs[("table2", "tip")])
    assert runs[("table3", "tip")]["peak_velocity_error"] > runs[("table2", "tip")]["peak_velocity_error"]


def test_feedforward_plus_feedback_beats_either_alone(runs):
    """Paper: the combination tracks closer than feedforward only or feedback only, most of all with a payload.
    HOLDS."""
    m = {k: runs[("compare_ff_fb", k)] for k in ("ff", "fb", "both", "ff_tip", "fb_tip", "both_tip")}
    for suffix in ("", "_tip"):
        both = m["both" + suffix]
        for alone in ("ff" + suffix, "fb" + suffix):
            assert rms_pos(both) < rms_pos(m[alone]), alone
            assert rms_vel(both) < rms_vel(m[alone]), alone
    # the payload is the modelling error that feedforward alone cannot handle
    assert rms_pos(m["ff_tip"]) > 10 * rms_pos(m["both_tip"])


def test_gain_schedule_period_makes_little_difference(runs):
    """Paper: gains every 200 ms, every 20 ms or one set make little difference. HOLDS."""
    for suffix in ("", "_tip"):
        rms = [rms_pos(runs[("compare_schedule", k + suffix)]) for k in ("s200ms", "s20ms", "single")]
        vel = [rms_vel(runs[("compare_schedule", k + suffix)]) for k in ("s200ms", "s20ms", "single")]
        assert max(rms) / min(rms) < 1.25
        assert max(vel) / min(vel) < 1.25


def test_findings_2_5_12_quote_the_reference_runs():
    """The horizon figures of findings 2, 5 and 12 in docs/findings.md are those of the reference-plant runs in
    docs/scheme-accuracy.json (its generated block is checked by tests/test_integrator.py): no hand-typed number
    that a fresh run contradicts."""
    import json
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    h = json.loads((root / "docs" / "scheme-accuracy.json").read_text())["horizons"]
    doc = (root / "docs" / "findings.md").read_text()
    rows = {n: next(line for line in doc.splitlines() if line.startswith(f"| {n} |")) for n in (2, 5, 12)}

    def pv(key, t):
        return h[key]["peak_velocity_error"][t]

    quoted = {2: [f"{pv('gamma1|none', '2.058'):.0f} (no noise) / {pv('gamma1|noise', '2.058'):.0f} (noise)",
                  f"{pv('gamma1|none', '5'):.0f} / {pv('gamma1|noise', '5'):.0f} deg/s by 5 s",
                  f"{pv('gamma1|none', '10'):.0f} / {pv('gamma1|noise', '10'):.0f}"],
              5: [f"{pv('gamma0.1|noise', '3'):.1f} deg/s up to 3 s", f"{pv('gamma0.1|noise', '5'):.0f} at 5 s",
                  f"{pv('gamma0.1|noise', '7'):.0f} at 7 s", f"{pv('gamma0.1|noise', '10'):.0f} at 10 s"],
              12: [f"from {h['eq32|tip|0.005']['settled_1mm_s']:.2f} s",
                   f"{h['eq32|tip|0']['tip_error_mm']['10']:.1f} mm off at 10 s"]}
    assert h["eq32|tip|0"]["settled_1mm_s"] is None and "never settles" in rows[12]
    for n, texts in quoted.items():
        for text in texts:
            assert text in rows[n], (n, text, rows[n])
    # the exponential scheme's figures past 4 s are gone (the words they came in: the 10 s reference runs may
    # reach the same number at another time, e.g. eq. 32 at 7 s)
    assert not re.search(r"1880 deg/s by 5 s|1\.2 1/s", doc)


def test_a_run_whose_loop_is_unstable_says_so(tmp_path):
    """γ = 1 undamped (linear growth +3.27 1/s at the bracket mode) over 1 s (3.3 e-folds): under the default
    RODAS4 plant the run looks quiet, so its results carry a warning naming the growth and the cure; under the
    reference plant the note says the run shows it; the same loop over 0.5 s is warned only for the one table metric
    it moves more than 5 % (issue 35 item 5), and γ = 0.1 with ζ = 0.005 gets no note (issue 24 item 5)."""
    s = load_scenario("table1")
    s.cases = [c for c in s.cases if c.key == "none"]
    s.samples = 1000
    (r,) = run_scenario(s, tmp_path, progress=False)
    stab = r.loop_stability
    assert stab["growth_per_s"] == pytest.approx(3.27, abs=0.01)
    assert "rodas4" in stab["note"] and "does not show" in stab["note"] and "reference" in stab["note"]
    assert r.warnings == [stab["note"]]
    (r,) = run_scenario(with_plant(s, integrator="reference"), tmp_path, progress=False)
    assert "shows that growth" in r.loop_stability["note"]
    s.samples = 500  # 1.6 e-folds: too little growth for the growth warning, but the rodas4 plant's damped bracket
    (r,) = run_scenario(s, tmp_path, progress=False)  # mode leaves the rms velocity error 5.8 % below the
    note = r.loop_stability["note"]  # converged plant's (measured: 0.5785 against 0.6142 deg/s, reference at 16/ms)
    assert r.loop_stability["growth_per_s"] > 0 and "grows" in note and "rms velocity error" in note
    assert "shows that growth" not in note and "peak" not in note and r.warnings == [note]
    s2 = load_scenario("table2")
    s2.cases = [c for c in s2.cases if c.key == "none"]
    s2.samples = 20
    (r,) = run_scenario(with_plant(s2, damping_ratio=0.005), tmp_path, progress=False)
    assert r.loop_stability["growth_per_s"] < 0 and r.loop_stability["note"] == ""
