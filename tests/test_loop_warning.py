"""No plant scheme is more than 5 % off the converged reference without the run saying so (issue 24, acceptance).

The decision (:func:`scenarios.analysis.stability.loop_stability`) is checked against every measured row of
docs/model.md's closed-loop table (docs/scheme-accuracy.json, ``loops``: each scheme's peak velocity error at 2, 5 and
10 s against
RK4 at 1.25 µs), and on short real runs whose case JSON must carry the warning.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from scenarios.analysis.metric_deviation import DEVIATION
from scenarios.analysis.sampled_loop import sampled_loop_growth
from scenarios.analysis.stability import E_FOLDS, loop_stability
from scenarios.config import load_scenario
from scenarios.reports.scheme_accuracy import JSON_PATH
from scenarios.reports.scheme_accuracy_parts import LOOP_REFERENCE, LOOP_SCHEMES, LOOPS
from scenarios.run.runner import run_scenario

PATHS = {"controller": "build/fmus/controller.fmu"}


def case_parameters(scenario: str, key: str, integrator: str, substeps: int) -> dict:
    s = load_scenario(scenario)
    case = next(c for c in s.cases if c.key == key)
    params = {inst: {**s.parameters.get(inst, {}), **case.parameters.get(inst, {})}
              for inst in set(s.parameters) | set(case.parameters)}
    params.setdefault("plant", {}).update(integrator=integrator, substeps=substeps)
    return params


def measured_rows():
    """(loop, scheme label, integrator, substeps, scenario, case, horizon, value or None, reference, status)."""
    loops = json.loads(Path(JSON_PATH).read_text())["loops"]
    for label, scenario, key in LOOPS:
        ref = loops[f"{label}|{LOOP_REFERENCE}"]["peak_velocity_error"]
        for s_label, integrator, sub in LOOP_SCHEMES:
            row = loops[f"{label}|{s_label}"]
            for mark, value in row["peak_velocity_error"].items():
                if value == "refused":  # the exponential scheme refuses to run past 3 s: the run says so
                    continue
                yield label, s_label, integrator, sub, scenario, key, float(mark), value, ref[mark], row["status"]


def test_every_row_more_than_5_percent_off_is_announced():
    """Every (scheme, loop, horizon) of the table more than 5 % off the reference gets a note that does not say the
    run shows the growth; every row whose note says it does is within 5 %. Rows: rodas4 on all three loops (up
    to −99.7 %), Gauss at 2 and 32 substeps per ms (up to +137.6 %, −66.4 %) are announced; Gauss at 128
    (3.6 % at most), 256 and the references are said to show the growth."""
    announced, shown, checked = 0, 0, 0
    for label, s_label, integrator, sub, scenario, key, horizon, value, ref, status in measured_rows():
        if s_label == LOOP_REFERENCE:
            continue
        stab = loop_stability(PATHS, "plant", "controller", case_parameters(scenario, key, integrator, sub),
                              1e-3, horizon)
        where = (label, s_label, horizon, value, ref, stab["note"])
        checked += 1
        if value is None:  # the run stopped (gauss 2/ms on γ = 1 at 10 s): its status says so
            assert status != "ok", where
            continue
        off = abs(value / ref - 1)
        says_shown = "shows that growth" in stab["note"]
        if off > DEVIATION:
            assert stab["note"] and not says_shown, where
            announced += 1
        if says_shown:
            assert off <= DEVIATION, where
            shown += 1
        if not stab["note"]:  # no note: neither loop grows by more than E_FOLDS over the horizon
            assert max(stab["e_folds_over_run"], stab["plant_e_folds_over_run"]) <= E_FOLDS, where
    assert checked >= 60 and announced >= 15 and shown >= 10, (checked, announced, shown)


def test_the_plant_loop_carries_the_scheme():
    """The run's plant sampled loop: RODAS4 damps the 5.7 kHz growth (γ = 1: −0.15 1/s against +3.27), Gauss at
    32 substeps per ms slows it (+3.20), at 256 and the RK4 references match it to 1e-3 1/s, exponential
    exactly (it is exact on linear dynamics); Jacobi stepping's two-step delay moves the growth to the 190 Hz
    link mode (+6.06 1/s on γ = 0.1), which every scheme resolves."""
    exact = sampled_loop_growth("gamma1", "200ms", 0.0, 0.0)["growth_per_s"]
    assert exact == pytest.approx(3.273, abs=0.005)
    rate = {(i, n): sampled_loop_growth("gamma1", "200ms", 0.0, 0.0, 1e-3, i, n)["growth_per_s"]
            for i, n in (("rodas4", 2), ("gauss", 32), ("gauss", 256), ("reference", 2), ("exponential", 2))}
    assert rate["rodas4", 2] < 0
    assert 0.03 < exact - rate["gauss", 32] < 0.2
    for key in (("gauss", 256), ("reference", 2), ("exponential", 2)):
        assert abs(rate[key] - exact) < 3e-3, (key, rate[key])
    jac = sampled_loop_growth("gamma0.1", "200ms", 0.0, 0.0, delay=2)
    assert jac["growth_per_s"] > 5 and 100 < jac["mode_frequency_hz"] < 300
    own = sampled_loop_growth("gamma0.1", "200ms", 0.0, 0.0, 1e-3, "gauss", 2, delay=2)
    assert abs(own["growth_per_s"] - jac["growth_per_s"]) < 0.01


def test_a_stable_loop_made_unstable_by_the_scheme_is_announced():
    """The other way round: a loop the exact plant keeps (nearly) stable that the scheme's own sampled loop makes
    grow is flagged as numerical growth (the decision function on made-up rates)."""
    from scenarios.analysis.stability import judge

    exact = {"growth_per_s": 0.1, "mode_frequency_hz": 5712.0, "aliased_frequency_hz": 288.0, "at_time_s": 0.2}
    note, dev = judge(exact, dict(exact, growth_per_s=2.0), 2.0, "gauss", 2, 1)
    assert "growth in this run is numerical" in note and dev > 1
    assert judge(exact, exact, 2.0, "gauss", 2, 1)[0] == ""


def _one_case(scenario: str, key: str, samples: int, **plant):
    s = copy.deepcopy(load_scenario(scenario))
    s.name = f"{scenario}-warn"
    s.cases = [c for c in s.cases if c.key == key]
    s.samples = samples
    for case in s.cases:
        case.parameters.setdefault("plant", {}).update(plant)
    return s


def test_a_gauss_run_that_misrepresents_the_growth_says_so_in_its_json(tmp_path):
    """γ = 1 with noise, Gauss at 32 substeps per ms (−66 % at 2 s in the closed-loop table), 1.2 s (3.9 e-folds):
    the results and the case JSON carry a warning that the run misrepresents the growth."""
    (r,) = run_scenario(_one_case("table1", "noise", 1200, integrator="gauss", substeps=32), tmp_path,
                        progress=False)
    stab = r.loop_stability
    assert stab["plant_integrator"] == "gauss" and stab["e_folds_over_run"] > E_FOLDS
    assert "misrepresents" in stab["note"] and stab["predicted_deviation"] > DEVIATION
    saved = json.loads((tmp_path / "table1-warn" / "noise.json").read_text())
    assert stab["note"] in saved["warnings"] and saved["loop_stability"]["note"] == stab["note"]


def test_jacobi_stepping_is_checked_with_its_delay(tmp_path):
    """Table 2's gains under a Jacobi master (torque two steps late): the paper's law measures the delay and
    predicts over it, so the check builds that loop (plant, the LQG design's filter and predictor, the paper's
    law on the predicted measurement), which grows only as the Gauss-Seidel loop does (the same gains fed the
    two-steps-old reconstruction grow through the 190 Hz link mode at about 6 1/s, which the check of the
    unpredicted loop still says), and the run's velocity error does not grow either (envelope fit from 0.2 s, well
    under 1 1/s)."""
    from flexarm.trajectory import load_trajectory
    from scenarios.analysis.sampled_loop import sampled_loop_growth
    from scenarios.reports.reexamine import envelope_growth, velocity_errors

    (r,) = run_scenario(_one_case("table2", "none", 600), tmp_path, progress=False, algorithm="jacobi")
    stab = r.loop_stability
    assert stab["delay_steps"] == 2 and stab["predicted_over_delay"], stab
    # the paper's law on the predicted measurement is the Gauss-Seidel loop: the same slow growth of the 5.7 kHz
    # bracket mode (0.987 1/s), to the filter's prediction (1e-4 relative; measured 4e-6)
    free = sampled_loop_growth("gamma0.1", "200ms", 0.0, 0.0)
    assert stab["growth_per_s"] == pytest.approx(free["growth_per_s"], rel=1e-4), (stab, free)
    assert stab["mode_frequency_hz"] == pytest.approx(free["mode_frequency_hz"], rel=1e-6)
    assert not stab["note"] and not r.warnings, (stab["note"], r.warnings)
    fitted = envelope_growth(r.series["time"], velocity_errors(r, load_trajectory()), 0.2)
    assert fitted < 1.0, fitted
    unpredicted = sampled_loop_growth("gamma0.1", "200ms", 0.0, 0.0, delay=2)["growth_per_s"]
    assert 5.0 < unpredicted < 7.0, unpredicted


# -- the loops not checked, and the LQG loop -----------------------------------------------------------------------
def test_the_unresolved_bracket_modes_follow_the_table():
    """A scheme is said to damp or misplace the bracket modes when it does more to one of them than every scheme the
    closed-loop table shows within 5 % of the reference (Gauss at 128 and 256 per ms, RK4 at 2.5 µs and finer):
    RODAS4 up to 160 per ms (10 1/s on the 21 kHz mode at 128), Gauss below 128 per ms, RK4 at 5 µs; not RODAS4
    at 192 and more, Gauss at 128 and 256, RK4 at 2.5 µs and finer, nor the exponential scheme (exact on linear
    modes; it refuses runs past 3 s). Structural damping is little below the largest bracket-mode growth of the
    committed gain schedules' exact loops (3.40 1/s, eq. 32 at 20 ms): ζ = 5e-5 (1.8 1/s on the 5.7 kHz mode)
    still warns, ζ = 0.005 (179 1/s) does not."""
    from scenarios.analysis.bracket_modes import RESOLVING_SCHEMES, unresolved_bracket_modes

    agreeing = {row[1] for row in measured_rows()}
    for _, s_label, *_, value, ref, status in measured_rows():
        if value is None or status != "ok" or abs(value / ref - 1) > DEVIATION:
            agreeing.discard(s_label)
    loops = json.loads(Path(JSON_PATH).read_text())["loops"]
    for s_label, *_ in LOOP_SCHEMES:  # a scheme refused at some horizon is not among them
        if any(row.get("peak_velocity_error", {}).get(m) == "refused" for key, row in loops.items()
               if key.endswith("|" + s_label) for m in ("2", "5", "10")):
            agreeing.discard(s_label)
    assert {(i, n) for label, i, n in LOOP_SCHEMES if label in agreeing} == set(RESOLVING_SCHEMES)
    assert "gauss, 128/ms" in agreeing and "gauss, 32/ms" not in agreeing
    for sub in (1, 2, 4, 16, 64, 128, 160):
        assert unresolved_bracket_modes("rodas4", sub, 0.0), sub
    assert not unresolved_bracket_modes("rodas4", 192, 0.0)  # RODAS4 at 5.2 µs damps 21 kHz by 1.6 1/s only
    for sub in (2, 4, 32, 64, 96):
        assert unresolved_bracket_modes("gauss", sub, 0.0), sub
    for integrator, sub in (("gauss", 128), ("gauss", 256), ("reference", 2), ("reference", 4), ("exponential", 2)):
        assert unresolved_bracket_modes(integrator, sub, 0.0) == {}, (integrator, sub)
    assert unresolved_bracket_modes("reference", 1, 0.0)
    from scenarios.analysis.bracket_modes import injected_growth

    inj = injected_growth()
    assert 3.3 < inj["growth_per_s"] < 3.5 and inj["gain_set"] == "eq32" and 5000 < inj["mode_frequency_hz"] < 6000
    assert list(unresolved_bracket_modes("rodas4", 2, 5e-5)) == ["bracket mode 1"]
    assert not unresolved_bracket_modes("rodas4", 2, 0.005) and not unresolved_bracket_modes("gauss", 32, 0.005)
    assert not unresolved_bracket_modes("gauss", 2, 1e-4)  # 3.6 1/s on the 5.7 kHz mode


def test_feedforward_only_cannot_be_misrepresented_by_the_scheme():
    """Open loop: along the slew (every 100 ms, no payload and 0.275 kg) the undamped plant's own growth (a slow
    joint mode of the frozen linearisation, up to +1.98 1/s) is the same under every scheme's one-step map to 1e-5
    1/s where it exceeds 0.01 1/s: no warning for controller_ff.

    Below 0.01 1/s the rate is round-off on the defective double eigenvalue 1 of the rigid-body modes: a perturbation
    delta of phi moves a 2x2 Jordan block's eigenvalue by about sqrt(delta * dt), i.e. a rate of about
    sqrt(n * eps * ||phi||_1 / dt) (about 1e-3 1/s here, ||phi||_1 ~ 2e5 from the stiff bracket modes), and each
    scheme's own rounding differs. The bound there is ten times that estimate (0.01 1/s): still only 0.1 e-fold over a
    10 s run, 30 times below the 3-e-fold warning, so no scheme can turn it into a growth the check would report."""
    import numpy as np

    from flexarm.model import ArmModel, numpy_kernels
    from flexarm.parameters import load_parameters
    from flexarm.trajectory import load_trajectory
    from scenarios.analysis.sampled_loop import plant_zoh

    traj, kern = load_trajectory(), numpy_kernels()
    largest = {}
    for payload in (0.0, 0.275):
        model = ArmModel(load_parameters(payload_mass=payload), kernels=kern)
        for k in range(0, traj.n_samples + 1, 100):
            A, B = model.linearize(traj.state(k))
            rate, roundoff = {}, 0.0
            for integrator, sub in (("exact", 2), ("rodas4", 2), ("gauss", 2), ("gauss", 32), ("reference", 2)):
                phi, _ = plant_zoh(A, B, 1e-3, integrator, sub, expm=kern.expm)
                rate[integrator, sub] = np.log(np.abs(np.linalg.eigvals(phi)).max()) / 1e-3
                roundoff = max(roundoff, np.sqrt(len(A) * np.finfo(float).eps * np.linalg.norm(phi, 1) / 1e-3))
            tol = 1e-5 if rate["exact", 2] > 0.01 else 10 * roundoff
            assert max(abs(r - rate["exact", 2]) for r in rate.values()) < tol, (payload, k, rate)
            largest[payload] = max(largest.get(payload, -1.0), rate["exact", 2])
    assert largest[0.0] == pytest.approx(1.98, abs=0.01) and largest[0.275] == pytest.approx(1.74, abs=0.01)
    params = {"plant": {"integrator": 1, "substeps": 2}, "controller": {}}
    ff = loop_stability({"controller": "build/fmus/controller_ff.fmu"}, "plant", "controller", params, 1e-3, 10.0)
    own = loop_stability({"controller": "my/own_pd.fmu"}, "plant", "controller", params, 1e-3, 10.0)
    assert not ff["checked"] and ff["note"] == ""
    assert not own["checked"] and "own_pd" in own["note"] and "5.7/13.2/21.2 kHz" in own["note"]
    assert "substeps = 4" in own["note"]


@pytest.mark.parametrize("delay,integral", [(0, False), (2, True), (3, False)])
def test_the_lqg_loop_matrix_is_the_controller(delay, integral):
    """The LQG closed-loop matrix steps exactly as flexarm.lqg.LqgController (filter, predictor across the delay,
    gain, integral action) on the linear plant with a payload the controller does not know: 30 samples from a
    random state, relative difference below 1e-10."""
    import numpy as np

    from flexarm.lqg import LqgState, lqg_controller
    from flexarm.model import ArmModel, numpy_kernels
    from flexarm.parameters import load_parameters
    from flexarm.trajectory import load_trajectory
    from scenarios.analysis.sampled_loop import lqg_closed_loop, plant_zoh

    ctl = lqg_controller("gamma0.1", "200ms", delay, integral, saturation=(1e6, 1e6))
    k0, nx, des = 420, 22, ctl.design
    i = ctl._index[k0]
    assert ctl._index[k0 + 30] == i  # one schedule point throughout
    kern = numpy_kernels()
    A, B = ArmModel(load_parameters(payload_mass=0.1), kernels=kern).linearize(load_trajectory().state(k0))
    pp, gp = plant_zoh(A, B, 1e-3, expm=kern.expm)
    w = des.weight_index("gamma0.1")
    K, K_xi = (des.K_integral[i, w, :, :nx], des.K_integral[i, w, :, nx:]) if integral else (des.K[i, w], None)
    F = lqg_closed_loop(pp, gp, des.Phi[i], des.Gamma[i], des.M[i], des.C, K, K_xi, delay)
    z = np.random.default_rng(1).normal(size=len(F)) * 1e-3
    o = nx * (delay + 1)
    state = LqgState(k0, z[o:o + nx].copy(), z[o + nx:o + nx + 2 * (delay + 1)].reshape(delay + 1, 2).copy(),
                     z[o + nx + 2 * (delay + 1):].copy() if integral else np.zeros(2), True)
    errors = [z[nx * j: nx * (j + 1)] for j in range(delay + 1)][::-1]  # e_{k−delay} .. e_k
    worst = 0.0
    for n in range(30):
        k = k0 + n
        tau, state = ctl.step(state, k, ctl._y_d[k - delay] + des.C @ errors[0])
        errors = errors[1:] + [pp @ errors[-1] + gp @ (tau - ctl.feedforward(k))]
        z = F @ z
        worst = max(worst, np.abs(z[:nx] - errors[-1]).max() / np.abs(errors[-1]).max())
    assert worst < 1e-10


def _lqg_case(samples: int, **changes):
    s = _one_case("lqg", "none", samples)
    for inst, values in changes.items():
        for case in s.cases:
            case.parameters.setdefault(inst, {}).update(values)
    return s


def test_an_unchecked_loop_on_a_damping_plant_says_so_in_its_json(tmp_path):
    """The LQG controller with the payload bank (nonlinear: not checked) on the default RODAS4 plant of the
    undamped arm: the results and the case JSON carry one warning naming the controller, the bracket modes this
    plant damps and the cure; with plant integrator = reference, substeps = 4 the same case has none."""
    bank = {"controller": {"estimator": "payload_bank"}}
    (r,) = run_scenario(_lqg_case(100, **bank), tmp_path / "rodas4", progress=False)
    stab = r.loop_stability
    assert not stab["checked"] and "payload" in stab["reason"] and stab["plant_integrator"] == "rodas4"
    assert "controller_lqg" in stab["note"] and "5.7/13.2/21.2 kHz" in stab["note"] and "substeps = 4" in stab["note"]
    saved = json.loads((tmp_path / "rodas4" / "lqg-warn" / "none.json").read_text())
    assert stab["note"] in saved["warnings"] and saved["loop_stability"]["note"] == stab["note"]
    (r,) = run_scenario(_lqg_case(100, plant={"integrator": "reference", "substeps": 4}, **bank),
                        tmp_path / "reference", progress=False)
    assert not r.loop_stability["checked"] and r.loop_stability["note"] == "" and r.warnings == []
    saved = json.loads((tmp_path / "reference" / "lqg-warn" / "none.json").read_text())
    assert saved["warnings"] == []


def test_the_lqg_check_predicts_the_run():
    """The LQG loop (one Kalman filter per point) is checked: lqg.toml as shipped (γ = 0.1 weights) is stable
    on the undamped arm (exact −0.048 1/s; RODAS4 −0.130, RK4 at 2.5 µs −0.03 on a slow mode), no warning, and
    with the reference plant (RK4 2.5 µs) its velocity error does not grow after the slew; with γ = 0 weights and
    the 0.275 kg payload the loop of the 0.4 s point grows through the 24 Hz link mode (+0.84 1/s, every scheme
    alike): the check takes the worst point over the whole run (3.2 e-folds over 3.8 s, a bound) and warns. Before
    the hold point existed the run's velocity error grew at that rate after the slew (0.88 1/s over 2.2-3.0 s, on
    the last slew point's gains); the hold (flexarm.lqg_design.HOLD_STATE_WEIGHT) now regulates it: over 2.2-3.0 s
    it decays (−2.8 1/s; bound: any decay), which is the regulator, not the check, being right.
    """
    import tempfile

    from flexarm.trajectory import load_trajectory
    from scenarios.reports.reexamine import envelope_growth, velocity_errors

    traj = load_trajectory()
    with tempfile.TemporaryDirectory() as folder:
        (r,) = run_scenario(_lqg_case(3000, plant={"integrator": "reference", "substeps": 2}), Path(folder),
                            progress=False)
        stab = r.loop_stability
        assert stab["checked"] and stab["note"] == "" and r.warnings == []
        assert stab["growth_per_s"] == pytest.approx(-0.048, abs=0.002) and stab["plant_growth_per_s"] < 0
        assert loop_stability({"controller": "controller_lqg.fmu"}, "plant", "controller",
                              {"controller": {"gain_set": "gamma0.1"}}, 1e-3, 3.0)["plant_growth_per_s"] \
            == pytest.approx(-0.130, abs=0.003)
        assert envelope_growth(r.series["time"], velocity_errors(r, traj), 2.2) < 0
        (r,) = run_scenario(_lqg_case(3800, plant={"payload_mass": 0.275}, controller={"gain_set": "gamma0"}),
                            Path(folder), progress=False)
    stab = r.loop_stability
    assert stab["checked"] and 24 < stab["mode_frequency_hz"] < 25 and "shows that growth" in stab["note"]
    assert stab["note"] in r.warnings
    t = r.series["time"]
    early = t <= 3.0
    fitted = envelope_growth(t[early], velocity_errors(r, traj)[early], 2.2)
    assert stab["growth_per_s"] == pytest.approx(0.84, abs=0.02) and stab["at_time_s"] < 2.0
    assert fitted < 0, fitted  # the hold after the slew regulates what the slew's last gains let grow


def test_the_loop_check_at_a_runs_start_loads_neither_numba_nor_scipy_linalg():
    """Every run checks its loop before the first step; Numba and scipy.linalg cost about a second of start-up
    (issue 23), and the check needs NumPy only (flexarm.model.numpy_kernels, flexarm.substeps)."""
    import subprocess
    import sys

    code = ("import sys\nfrom scenarios.analysis.stability import loop_stability\n"
            "for stem in ('controller', 'controller_lqg', 'my_controller'):\n"
            "    loop_stability({'c': f'x/{stem}.fmu'}, 'p', 'c', {}, 1e-3, 2.058)\n"
            "print(sorted(m for m in ('numba', 'scipy.linalg') if m in sys.modules))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "[]", proc.stdout


@pytest.mark.parametrize("scenario, samples, measured", [("table2", 3000, -0.19), ("table3", 10000, -0.116)])
def test_a_default_plant_off_on_the_rms_velocity_error_says_so(tmp_path, scenario, samples, measured):
    """The issue's two silent cases, the default rodas4 plant: Table 2 noise to 3 s (2.96 e-folds, under the peak's
    3; rms velocity error 0.799 against the converged plant's 0.986 deg/s, −19 %) and Table 3 noise to 10 s (−11.6 %).
    Each run now warns, naming the rms velocity error, and its JSON carries the predicted deviation of every error
    metric. The prediction is a model of the converged plant, which these runs do not run (the mode's amplitude,
    measured per gain set from these two cases' converged runs, scenarios/analysis/metric_deviation.py): it must
    be
    past 5 % with the measured sign, and its size within a factor of 2 of the measurement (the margin is the model's:
    one
    amplitude and the worst growth rate of the schedule, applied from t = 0)."""
    (r,) = run_scenario(_one_case(scenario, "noise", samples), tmp_path, progress=False)
    stab = r.loop_stability
    assert r.status == "ok" and stab["plant_integrator"] == "rodas4" and stab["e_folds_over_run"] <= E_FOLDS
    dev = stab["predicted_metric_deviation"]
    assert set(dev) == {"rms_velocity_error", "rms_position_error", "peak_velocity_error", "peak_position_error"}
    assert dev["rms_velocity_error"] < -DEVIATION and 0.5 < dev["rms_velocity_error"] / measured < 2
    warned = [w for w in r.warnings if "rms velocity error" in w]
    assert len(warned) == 1 and f"{dev['rms_velocity_error']:+.1%}" in warned[0], r.warnings
    saved = json.loads((tmp_path / f"{scenario}-warn" / "noise.json").read_text())
    assert warned[0] in saved["warnings"] and saved["loop_stability"]["predicted_metric_deviation"] == dev


def test_the_lqg_loop_left_automatic_is_checked_at_the_masters_delay():
    """`loop_delay_samples` not set is the FMU's start value, automatic: the controller predicts over the delay it
    measures, so the check builds the loop at the master's delay (it once took the unset value as 0 and reported
    the Jacobi loop as "not checked: loop_delay_samples = 0 where the jacobi master delays by 2")."""
    from scenarios.analysis.stability import loop_stability

    paths = {"controller": "build/fmus/controller_lqg.fmu"}
    params = {"controller": {"gain_set": 2, "schedule_period": 0.2}, "plant": {"integrator": 1, "substeps": 2}}
    jacobi = loop_stability(paths, "plant", "controller", params, 0.001, 2.058, algorithm="jacobi")
    assert jacobi["checked"] and jacobi["delay_steps"] == 2, jacobi.get("reason")
    assert jacobi["growth_per_s"] < 0  # the predicting loop is stable (the run: 0.0010 deg rms)
    explicit = loop_stability(paths, "plant", "controller", {**params, "controller": {
        **params["controller"], "loop_delay_samples": 0}}, 0.001, 2.058, algorithm="jacobi")
    assert not explicit["checked"] and "loop_delay_samples = 0" in explicit["reason"]  # an explicit 0 stays unchecked
