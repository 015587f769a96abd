"""No plant scheme is more than 5 % off the converged reference without the run saying so (issue 24, acceptance).

The decision (:func:`scenarios.stability.loop_stability`) is checked against every measured row of docs/model.md's
closed-loop table (docs/scheme-accuracy.json, ``loops``: each scheme's peak velocity error at 2, 5 and 10 s against
RK4 at 1.25 µs), and on short real runs whose case JSON must carry the warning.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from scenarios.config import load_scenario
from scenarios.runner import run_scenario
from scenarios.scheme_accuracy import JSON_PATH, LOOP_REFERENCE, LOOP_SCHEMES, LOOPS
from scenarios.stability import DEVIATION, E_FOLDS, loop_stability, sampled_loop_growth

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
    from scenarios.stability import judge

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
    """Table 2's gains under a Jacobi master (torque two steps late) grow through the 190 Hz link mode at about
    6 1/s; over 0.6 s (3.6 e-folds) the run says so, that its plant shows the growth, and the run's velocity error
    does grow at that rate (envelope fit from 0.2 s within 30 %)."""
    from flexarm.trajectory import load_trajectory
    from scenarios.reexamine import envelope_growth, velocity_errors

    (r,) = run_scenario(_one_case("table2", "none", 600), tmp_path, progress=False, algorithm="jacobi")
    stab = r.loop_stability
    assert stab["delay_steps"] == 2 and "Jacobi" in stab["note"] and "shows that growth" in stab["note"]
    assert stab["note"] in r.warnings
    fitted = envelope_growth(r.series["time"], velocity_errors(r, load_trajectory()), 0.2)
    assert abs(fitted / stab["growth_per_s"] - 1) < 0.3, (fitted, stab["growth_per_s"])
