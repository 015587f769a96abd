"""The controller FMUs: one interface, same torques as flexarm.control, closed loop with the plant FMU."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu
from fmu_harness import Slave, built_fmus

from flexarm.control import TrackingController, tracking_errors
from flexarm.lqr import DEFAULT_GAIN_DIR, GainSchedule, as_trajectory, default_trajectory_path, desired_states
from flexarm.model import N, joint_angles, joint_velocities, strain_gauge_angles
from flexarm.sensors import MEASURED_SIGNAL_NAMES
from scenarios.master.values import parse_choices

ROOT = Path(__file__).resolve().parents[1]

DT = 1e-3
PAYLOAD = 0.275
CONTROLLERS = ("controller", "controller_ff", "controller_fb", "controller_dlqr")
USED = MEASURED_SIGNAL_NAMES[:10]  # q1_m .. eps6_m (the accelerometers are accepted, unused)

pytestmark = pytest.mark.skipif(
    not default_trajectory_path().is_file() or not any(DEFAULT_GAIN_DIR.glob("*.npz")),
    reason="flexarm/data/trajectory.npz or flexarm/data/gains/ not generated yet")


@pytest.fixture(scope="module")
def fmus() -> dict[str, Path]:
    return built_fmus()  # the test process's one build of every FMU (tests/fmu_harness.py)


@pytest.fixture(scope="module")
def unzipped(fmus, tmp_path_factory) -> dict[str, str]:
    return {name: extract(str(path), unzipdir=str(tmp_path_factory.mktemp(f"{name}_unzipped")))
            for name, path in fmus.items()}


@pytest.fixture(scope="module")
def trajectory():
    return as_trajectory(default_trajectory_path())


def measurements(z) -> np.ndarray:
    """Noiseless q, q̇, ε of a state, in USED order."""
    th, om = z[:N], z[N:]
    return np.concatenate([joint_angles(th), joint_velocities(om), strain_gauge_angles(th)])


# -- model description ---------------------------------------------------------------
@pytest.mark.parametrize("name", CONTROLLERS)
def test_validate_fmu_reports_no_problems(fmus, name):
    assert validate_fmu(str(fmus[name])) == []


def test_every_controller_has_the_same_interface(fmus):
    def interface(name):
        md = read_model_description(str(fmus[name]))
        return [(v.name, v.causality, v.variability, v.type, v.unit, v.start, v.min, v.max)
                for v in md.modelVariables]

    reference = interface("controller")
    for name in CONTROLLERS[1:]:
        assert interface(name) == reference, name
    ids = {read_model_description(str(fmus[n])).coSimulation.modelIdentifier for n in CONTROLLERS}
    assert len(ids) == len(CONTROLLERS)  # distinct binaries, loadable side by side


def test_inputs_are_the_sensor_outputs_and_outputs_the_plant_inputs(fmus):
    md = read_model_description(str(fmus["controller"]))
    sensors = read_model_description(str(fmus["sensors"]))
    plant = read_model_description(str(fmus["plant"]))
    by_name = {v.name: v for v in md.modelVariables}
    inputs = [v.name for v in md.modelVariables if v.causality == "input"]
    outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    # the loop's sample index and the plant's report of the torque it held (docs/control.md)
    assert inputs == [*MEASURED_SIGNAL_NAMES, "sample_index_m", "tau_lag", "tau1_applied", "tau2_applied"]
    assert [v.name for v in sensors.modelVariables if v.causality == "output"] == inputs[:13]
    assert outputs == ["tau1", "tau2", "tau_index", "loop_delay", "loop_delay_assumed", "slew_start_index"]
    assert [v.name for v in plant.modelVariables if v.causality == "input"] == outputs[:3]
    assert all(by_name[n].unit == "N.m" for n in outputs[:2]) and all(by_name[n].unit == "1" for n in outputs[2:])
    # direct feedthrough from the ten used measurements, not the accelerometers; the index follows the time alone,
    # the measured delay the index received
    want = {"tau1": list(USED), "tau2": list(USED), "tau_index": [], "loop_delay": ["sample_index_m"],
            "loop_delay_assumed": [], "slew_start_index": []}
    for unknown in md.outputs:
        assert [v.name for v in unknown.dependencies] == want[unknown.variable.name]
    assert by_name["schedule_period"].unit == "s"
    # No String (issues 12, 31): the choices are Integers listing their options in the description; a learned
    # feedforward is a file in the FMU's resources (fmu_build.learned), so a tool that cannot set strings uses it
    assert [v.name for v in md.modelVariables if v.type == "String"] == []
    for name, items, start in (("gain_set", ["gamma1", "gamma0.1", "gamma0", "eq32"], "2"),
                               ("omega7_estimate", ["tachometer", "rigid"], "1")):
        var = by_name[name]
        assert var.type == "Integer" and str(var.start) == start
        assert parse_choices(var.description) == {n: i + 1 for i, n in enumerate(items)}
        assert (int(var.min), int(var.max)) == (1, len(items))
    # No parameter named like another FMU's variable
    others = {v.name for v in [*sensors.modelVariables, *plant.modelVariables]}
    assert not [v.name for v in md.modelVariables if v.causality == "parameter" and v.name in others]
    assert (float(by_name["tau1_max"].start), float(by_name["tau2_max"].start)) == (7.0, 2.25)


def test_no_fmu_has_a_string_variable():
    """Issue 31: a tool that cannot set strings (OMSimulator has no String connectors) uses every FMU of ours
    fully, both kinds. A learned feedforward is a file in the controller FMU's resources, not a path parameter."""
    from native_fmus import native_fmus

    for fmu in [*built_fmus().values(), *native_fmus().values()]:
        md = read_model_description(str(fmu))
        assert [v.name for v in md.modelVariables if v.type == "String"] == [], fmu


def test_docs_name_every_controller(fmus):
    """Every variable of every FMU: tests/test_fmu_robustness.py; here the controller variants themselves."""
    doc = (ROOT / "docs" / "fmu-interface.md").read_text()
    assert all(f"`{name}`" in doc for name in CONTROLLERS)


# -- numbers ---------------------------------------------------------------------------
CASES = [
    ("controller", dict(gain_set="gamma1", schedule_period=0.2), "gamma1", "200ms", "ff+fb"),
    ("controller", dict(gain_set="gamma0", schedule_period=0.02, tau1_max=3.0, tau2_max=1.0),
     "gamma0", "20ms", "ff+fb"),
    ("controller", dict(gain_set="eq32", schedule_period=0.0, omega7_estimate="rigid"), "eq32", "single", "ff+fb"),
    ("controller_ff", dict(gain_set="gamma0.1"), None, None, "ff"),
    ("controller_fb", dict(gain_set="gamma0.1", schedule_period=0.2), "gamma0.1", "200ms", "fb"),
    ("controller_dlqr", dict(gain_set="gamma0.1", schedule_period=0.2), "dlqr-gamma0.1", "200ms", "ff+fb"),
]


@pytest.mark.parametrize("fmu,params,gains,schedule,mode", CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(CASES)])
def test_torques_equal_flexarm_control_bit_for_bit(fmus, unzipped, trajectory, fmu, params, gains, schedule, mode):
    if gains is not None and not (DEFAULT_GAIN_DIR / f"{gains}_{schedule}.npz").is_file():
        pytest.skip(f"gain file {gains}_{schedule} not generated")
    law = TrackingController(default_trajectory_path(), GainSchedule.load(gains, schedule) if gains else None,
                             mode=mode, saturation=(params.get("tau1_max", 7.0), params.get("tau2_max", 2.25)),
                             omega7=params.get("omega7_estimate", "tachometer"))
    rng = np.random.default_rng(0)
    n = trajectory.n_samples + 200  # past the slew: the hold
    ctrl = Slave(fmus[fmu], unzipped[fmu], fmu, **params)
    try:
        for k in range(n):
            if k % 7 == 0 or k > n - 5:  # a subsample of the points, all steps taken
                z = desired_states(trajectory)[min(k, trajectory.n_samples)]
                y = measurements(z) + rng.normal(0.0, [1e-2] * 4 + [1e-4] * 6)
                ctrl.set_vector(USED, y)
                ctrl.set_vector(["acc1_m", "acc2_m"], rng.normal(0.0, 10.0, 2))  # ignored
                tau = ctrl.get(["tau1", "tau2"])
                expected = law.torque_at(k, y[0:2], y[2:4], y[4:10])
                np.testing.assert_array_equal(tau, expected, err_msg=f"k = {k}")
            ctrl.step()
        assert not ctrl.errors()
    finally:
        ctrl.close()


def test_outputs_follow_the_inputs_set_at_the_same_point(fmus, unzipped, trajectory):
    # a sample where the feedforward is well inside the torque limits
    margin = np.max(np.abs(trajectory.tau[:-1]) / [7.0, 2.25], axis=1)
    k = int(np.argmin(margin[100:-100])) + 100
    ctrl = Slave(fmus["controller"], unzipped["controller"], "ctrl", gain_set="gamma1")
    try:
        ctrl.get(["tau1", "tau2"])  # read at t = 0, as a master that exchanges values: the slew starts at t = 0
        for _ in range(k):
            ctrl.step()
        y = measurements(desired_states(trajectory)[k])
        ctrl.set_vector(USED, y)
        on_track = ctrl.get(["tau1", "tau2"])
        np.testing.assert_allclose(on_track, trajectory.tau[k], atol=1e-9)  # zero error: pure feedforward
        ctrl.set_vector(["q1_m"], [y[0] + 0.01])
        off_track = ctrl.get(["tau1", "tau2"])
        assert off_track[0] < on_track[0]  # q1 ahead of the plan: shoulder torque reduced at once
        state = ctrl.fmu.getFMUstate()
        ctrl.step()
        after = ctrl.get(["tau1", "tau2"])
        ctrl.fmu.setFMUstate(state)
        ctrl.fmu.freeFMUstate(state)
        ctrl.time -= DT
        np.testing.assert_array_equal(ctrl.get(["tau1", "tau2"]), off_track)
        ctrl.step()
        np.testing.assert_array_equal(ctrl.get(["tau1", "tau2"]), after)
    finally:
        ctrl.close()


@pytest.mark.parametrize("read_first", [True, False])
def test_a_master_that_exchanged_nothing_gets_the_slew_a_sample_later(fmus, unzipped, trajectory, read_first):
    """Stepped with its inputs at their start values (0: a master's placeholder) and nothing read before the first
    fmi2DoStep, as fmpy's simulate_ssp does, the controller knows no torque of its reached the plant over that step:
    it starts the slew one sample later and says so (slew_start_index 2, the FMI log). A master that read the
    torques at t = 0 had them to give the plant: the slew starts at t = 0."""
    ctrl = Slave(fmus["controller"], unzipped["controller"], "late" if not read_first else "read")
    try:
        if read_first:
            ctrl.get(["tau1", "tau2"])
        rows = []
        for _ in range(4):
            ctrl.step()
            rows.append(ctrl.get(["tau1", "tau2", "tau_index", "slew_start_index"]))
        rows = np.array(rows)  # after the step from t_(j-1): the torques of the master's sample j, j = 1..4
    finally:
        ctrl.close()
    late = 0 if read_first else 1
    np.testing.assert_array_equal(rows[:, 3], np.full(4, 1.0 + late))
    np.testing.assert_array_equal(rows[:, 2], np.arange(2.0, 6.0))  # tau_index names the master's sample
    np.testing.assert_allclose(rows[:, :2], trajectory.tau[1 - late:5 - late], atol=1e-9)  # the feedforward


def closed_loop(fmus, unzipped, trajectory, controller: str, n: int, **params) -> np.ndarray:
    """Plant FMU (0.275 kg payload) + controller FMU, perfect measurement; states (n + 1, 22)."""
    theta0 = desired_states(trajectory)[0, :N]
    q0 = joint_angles(theta0)
    plant = Slave(fmus["plant"], unzipped["plant"], "plant", payload_mass=PAYLOAD, q1_0=q0[0], q2_0=q0[1])
    ctrl = Slave(fmus[controller], unzipped[controller], controller, **params)
    names = [f"theta{i + 1}" for i in range(N)] + [f"omega{i + 1}" for i in range(N)]
    plant_out = ["q1", "q2", "qd1", "qd2", *(f"eps{i}" for i in range(1, 7)), "acc1_n", "acc2_n"]
    try:
        states = [plant.get(names)]
        for _ in range(n):
            ctrl.set_vector(MEASURED_SIGNAL_NAMES, plant.get(plant_out))  # plant.q1 -> controller.q1_m, ...
            plant.set_vector(["tau1", "tau2"], ctrl.get(["tau1", "tau2"]))
            plant.step()
            ctrl.step()
            states.append(plant.get(names))
        assert not plant.errors() and not ctrl.errors()
        return np.array(states)
    finally:
        plant.close()
        ctrl.close()


def test_closed_loop_with_payload_tracks_better_than_feedforward(fmus, unzipped, trajectory):
    n = trajectory.n_samples
    np.testing.assert_allclose(desired_states(trajectory)[0, N:], 0.0, atol=1e-12)  # starts at rest
    fb = tracking_errors(closed_loop(fmus, unzipped, trajectory, "controller", n, gain_set="gamma0.1"), trajectory)
    ff = tracking_errors(closed_loop(fmus, unzipped, trajectory, "controller_ff", n), trajectory)
    print(f"\n0.275 kg payload, {n} steps: pos rms ff+fb {fb['pos_rms']:.3f} deg, ff {ff['pos_rms']:.3f} deg; "
          f"pos peak {fb['pos_peak']:.3f} / {ff['pos_peak']:.3f} deg")
    assert fb["pos_rms"] < ff["pos_rms"]


# -- errors ----------------------------------------------------------------------------
@pytest.mark.parametrize("params,word", [
    (dict(schedule_period=0.1), "schedule_period"),
])
def test_bad_parameters_fail_initialisation_with_their_name(fmus, unzipped, params, word):
    ctrl = Slave(fmus["controller"], unzipped["controller"], "bad", start=False)
    try:
        ctrl.fmu.setupExperiment(startTime=0.0)
        ctrl.fmu.enterInitializationMode()
        ctrl.set(**params)
        with pytest.raises(FMICallException, match="fmi2ExitInitializationMode") as exc:
            ctrl.fmu.exitInitializationMode()
        assert exc.value.status == 3  # fmi2Error
        assert any(word in m for m in ctrl.errors()), ctrl.errors()
        assert ctrl.status("doStep", 0.0, DT) == 3  # still in initialisation mode
    finally:
        ctrl.close()


@pytest.mark.parametrize("name,value,allowed", [("gain_set", 5, "1 (gamma1), 2 (gamma0.1), 3 (gamma0), 4 (eq32)"),
                                                 ("gain_set", 0, "4 (eq32)"),
                                                 ("omega7_estimate", 3, "1 (tachometer), 2 (rigid)")])
def test_choices_outside_the_options_are_rejected(fmus, unzipped, name, value, allowed):
    ctrl = Slave(fmus["controller"], unzipped["controller"], "bad", start=False)
    try:
        ctrl.fmu.setupExperiment(startTime=0.0)
        ctrl.fmu.enterInitializationMode()
        with pytest.raises(FMICallException, match="fmi2SetInteger") as exc:
            ctrl.set(**{name: value})
        assert exc.value.status == 3  # fmi2Error
        assert any(name in m and allowed in m for m in ctrl.errors()), ctrl.errors()
    finally:
        ctrl.close()


def test_out_of_range_saturation_is_rejected(fmus, unzipped):
    ctrl = Slave(fmus["controller_ff"], unzipped["controller_ff"], "bad", start=False)
    try:
        ctrl.fmu.setupExperiment(startTime=0.0)
        ctrl.fmu.enterInitializationMode()
        with pytest.raises(FMICallException, match="fmi2SetReal"):
            ctrl.set(tau1_max=0.0)
        assert any("tau1_max" in m and "allowed range" in m for m in ctrl.errors())
    finally:
        ctrl.close()


def test_steps_off_the_sample_grid_are_rejected(fmus, unzipped):
    ctrl = Slave(fmus["controller_ff"], unzipped["controller_ff"], "grid")
    try:
        with pytest.raises(FMICallException):
            ctrl.fmu.doStep(0.0, 0.5e-3)
        assert any("step_size" in m and "whole multiple" in m for m in ctrl.errors())
        ctrl.step(2e-3)  # a multiple of the sample time is fine
    finally:
        ctrl.close()


@pytest.mark.parametrize("name", CONTROLLERS)
def test_many_instances_in_one_process(fmus, unzipped, name):
    """pythonfmu 0.7.0 drops a reference to the slave module per instantiation (see pin_module_namespace)."""
    for i in range(6):
        ctrl = Slave(fmus[name], unzipped[name], f"{name}{i}")
        ctrl.step()
        ctrl.close()
