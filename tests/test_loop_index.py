"""The loop measures its own delay (issue 31): sample indices carried through plant, sensors and controller.

The rules live in flexarm/loop_index.py (Python FMUs) and fmus/native/common/loop_index.h (native FMUs); the
FMU tests below run both kinds, so they hold the two together.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmu_harness import built_fmus
from native_fmus import native_fmus

from flexarm import loop_index
from flexarm.parameters import DATA_DIR
from flexarm.signals import INDEX_GROUP, catalogue
from scenarios.config import load_scenario
from scenarios.run.setup import prepare


def test_the_index_rules():
    assert loop_index.index_of_time(0.0) == 1.0  # sample 0 carries 1: a zero fill is never sample 0
    assert loop_index.index_of_time(2.058) == 2059.0
    assert loop_index.index_of_time(7e-3 + 3e-10) == 8.0  # a master's time in doubles or nanoseconds
    assert loop_index.index_of_time(-1e-3) == loop_index.NO_SAMPLE
    assert loop_index.received_index(1.0) == 0 and loop_index.received_index(2059.0) == 2058
    for nothing in (0.0, -3.0, 0.5, 2.5, math.nan, math.inf):  # fmpy's zero fill, garbage: no sample
        assert loop_index.received_index(nothing) is None, nothing
    assert loop_index.torque_lag(5e-3, 6.0) == 0.0  # computed for sample 5, held from t = 5 ms
    assert loop_index.torque_lag(5e-3, 4.0) == 2.0
    assert loop_index.torque_lag(5e-3, 0.0) == loop_index.NO_INDEX_LAG


def test_the_indices_count_the_trajectorys_samples():
    with np.load(DATA_DIR / "trajectory.npz", allow_pickle=False) as data:
        assert np.allclose(np.diff(data["t"]), loop_index.SAMPLE_PERIOD, rtol=0, atol=1e-12)


def test_the_index_signals_wire_by_name_in_a_loop():
    """plant.sample_index -> sensors, sensors.sample_index_m -> controller, controller.tau_index -> plant."""
    rows = {(s.fmu, s.causality, s.name) for s in catalogue() if s.group == INDEX_GROUP}
    assert rows == {("plant", "input", "tau_index"), ("plant", "output", "sample_index"),
                    ("plant", "output", "tau_lag"), ("plant", "output", "tau1_applied"),
                    ("plant", "output", "tau2_applied"), ("controller", "input", "tau_lag"),
                    ("controller", "input", "tau1_applied"), ("controller", "input", "tau2_applied"),
                    ("sensors", "input", "sample_index"),
                    ("sensors", "output", "sample_index_m"), ("controller", "input", "sample_index_m"),
                    ("controller", "output", "tau_index"), ("controller", "output", "loop_delay"),
                    ("controller", "output", "loop_delay_assumed"), ("controller", "output", "slew_start_index")}


@pytest.fixture(scope="module", params=["python", "native"])
def kind_fmus(request) -> tuple[str, dict[str, Path]]:
    return request.param, (built_fmus() if request.param == "python" else native_fmus())


class _Slave:
    """One FMU on fmpy's FMU2Slave, by variable name."""

    def __init__(self, path: Path, name: str):
        md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                               modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        self.slave.instantiate()
        self.slave.setupExperiment(startTime=0.0)
        self.slave.enterInitializationMode()

    def set(self, **values):
        self.slave.setReal([self.vr[n] for n in values], [float(v) for v in values.values()])

    def get(self, *names) -> list[float]:
        return self.slave.getReal([self.vr[n] for n in names])

    def close(self):
        self.slave.terminate()
        self.slave.freeInstance()


def test_the_plant_says_which_sample_its_outputs_are_and_how_late_its_torque_was(kind_fmus):
    _, fmus = kind_fmus
    plant = _Slave(fmus["plant"], "plant")
    try:
        plant.slave.exitInitializationMode()
        # nothing set: the torque of initialisation came with no index
        assert plant.get("sample_index", "tau_lag") == [1.0, -1.0]
        h = 1e-3
        for k, (tau_index, lag) in enumerate([(1.0, 0.0), (2.0, 0.0), (1.0, 2.0), (0.0, -1.0), (4.5, -1.0),
                                              (6.0, 0.0)]):
            plant.set(tau1=0.1, tau2=0.0, tau_index=tau_index)
            plant.slave.doStep(currentCommunicationPoint=k * h, communicationStepSize=h)
            assert plant.get("sample_index", "tau_lag") == [k + 2.0, lag], (k, tau_index)
        plant.slave.doStep(currentCommunicationPoint=6 * h, communicationStepSize=10 * h)  # a 10 ms step
        assert plant.get("sample_index") == [17.0]
    finally:
        plant.close()


def test_the_sensors_pass_on_the_index_of_the_sample_they_measured(kind_fmus):
    _, fmus = kind_fmus
    sensors = _Slave(fmus["sensors"], "sensors")
    try:
        sensors.slave.exitInitializationMode()
        assert sensors.get("sample_index_m") == [0.0]  # nothing measured yet: a master's zero fill reads so
        for k in range(3):
            sensors.set(q1=0.1 * k, sample_index=k + 1.0)
            assert sensors.get("sample_index_m", "q1_m") == pytest.approx([k + 1.0, 0.1 * k], abs=1e-3)
            sensors.slave.doStep(currentCommunicationPoint=k * 1e-3, communicationStepSize=1e-3)
    finally:
        sensors.close()


@pytest.mark.parametrize("fmu, parameters", [("controller", {}), ("controller_dlqr", {}),
                                             ("controller_lqg", {}), ("controller_lqg", {"loop_delay_samples": 2})])
def test_a_controller_says_which_sample_its_torques_are_for(kind_fmus, fmu, parameters):
    """Feedthrough: the torques read at t_k are sample k's; held (delay > 0): also sample k's, computed at
    the fmi2DoStep of t_(k-1)."""
    _, fmus = kind_fmus
    controller = _Slave(fmus[fmu], fmu)
    try:
        for name, value in parameters.items():
            controller.slave.setInteger([controller.vr[name]], [value])
        controller.slave.exitInitializationMode()
        for k in range(4):
            assert controller.get("tau_index") == [k + 1.0], k
            controller.slave.doStep(currentCommunicationPoint=k * 1e-3, communicationStepSize=1e-3)
    finally:
        controller.close()


def _run(kind: str, fmus: dict[str, Path], scenario: str, case: str, algorithm: str, n: int = 40) -> dict:
    sc = load_scenario(scenario)
    folder = next(iter(fmus.values())).parent
    setup = prepare(sc, fmu_dir=folder, native_fmu_dir=folder, build=False, kind=kind, algorithm=algorithm)
    parameters = next(c for c in sc.cases if c.key == case).parameters
    extra = [("plant", "sample_index"), ("plant", "tau_lag"), ("sensors", "sample_index_m"),
             ("controller", "tau_index"), ("controller", "slew_start_index")]
    with setup.open_master(algorithm) as m:
        out = m.run(setup.case_parameters(parameters), setup.record + extra, n, sc.step_size)
    assert out["status"] == "ok", out["message"]
    return {name: np.asarray(out["signals"][f"{inst}.{name}"]) for inst, name in extra}


def test_in_a_gauss_seidel_loop_every_index_is_the_current_sample(kind_fmus):
    kind, fmus = kind_fmus
    s = _run(kind, fmus, "table2", "none", "gauss-seidel")
    k = np.arange(len(s["sample_index"]))
    assert np.array_equal(s["sample_index"], k + 1.0)
    assert np.array_equal(s["sample_index_m"], k + 1.0)  # the measurement of this very sample
    assert np.array_equal(s["tau_index"], k + 1.0)  # measured delay: tau_index - sample_index_m = 0
    assert np.array_equal(s["tau_lag"][1:], np.zeros(len(k) - 1))  # every torque held from its own sample
    assert np.array_equal(s["slew_start_index"], np.ones(len(k)))  # the slew starts at t = 0


def test_in_a_jacobi_loop_the_indices_measure_two_samples_of_delay(kind_fmus):
    """Jacobi at 1 ms with separate sensors: the torques of sample k + 1 (computed at the fmi2DoStep of t_k,
    from the sensors' output read at t_k) use the plant's sample k - 1: d = 2, what lqg_jacobi sets."""
    kind, fmus = kind_fmus
    s = _run(kind, fmus, "lqg_jacobi", "none", "jacobi")
    k = np.arange(len(s["sample_index"]))
    assert np.array_equal(s["sample_index"], k + 1.0)
    assert np.array_equal(s["sample_index_m"][1:], k[1:] * 1.0)  # read at t_k: the sensors sampled t_(k-1)
    assert np.array_equal(s["tau_index"], k + 1.0)
    delay = s["tau_index"][2:] - s["sample_index_m"][1:-1]
    assert np.array_equal(delay, np.full(len(delay), 2.0))
    assert np.array_equal(s["tau_lag"][1:], np.zeros(len(k) - 1))


def test_fmpy_simulate_ssps_zero_fill_reads_as_no_sample_yet(kind_fmus):
    """fmpy's simulate_ssp sets every connected input to 0 over its first step: the plant's torque then
    carries no index (tau_lag -1 after that step), and the sensors' first measurement is of no sample. The
    controller sees the placeholder at its first fmi2DoStep and starts the slew one sample later: the torques
    published after that step are the slew's sample 0, for the master's sample 1 (tau_index 2), and every torque
    after reaches the plant in its own sample (tau_lag 0)."""
    kind, fmus = kind_fmus
    s = _run(kind, fmus, "lqg_jacobi", "none", "fmpy-ssp", n=10)  # rows: after steps 0..9 (as simulate_ssp's)
    assert s["tau_lag"][0] == loop_index.NO_INDEX_LAG
    assert s["sample_index_m"][0] == loop_index.NO_SAMPLE  # the sensors sampled the zero-filled input
    assert np.array_equal(s["tau_lag"][1:], np.zeros(9))
    assert np.array_equal(s["slew_start_index"], np.full(10, 2.0))
    assert np.array_equal(s["tau_index"], np.arange(2.0, 12.0))  # the master's samples 1..10


#: How close the late run's angles come to the Jacobi run's, one sample earlier, rad: to rounding (about 2e-13
#: measured, both kinds; the states pass through 300 samples of the same arithmetic in another order of
#: exchanges, so 1e-9 leaves four orders for compilers and platforms). The LQG too: in the Jacobi master the
#: measurement of sample 0 present when it computes sample 1 (before the switch to the measured delay) is no
#: measurement of sample 1, and in simulate_ssp that input is the placeholder; both run sample 1 from the
#: trajectory (1e-5 rad apart before that rule).
SHIFT_TOLERANCE = {"table2": 1e-9, "lqg_jacobi": 1e-9}


@pytest.mark.parametrize("scenario, case", [("table2", "none"), ("lqg_jacobi", "none")])
def test_in_fmpy_simulate_ssp_the_slew_is_the_jacobi_slew_one_sample_later(kind_fmus, scenario, case):
    """The first millisecond of fmpy's simulate_ssp holds no torque, and the arm at rest stays at rest: the
    controller's late start (slew_start_index 2) makes the run the Jacobi master's, one sample later. The arm's
    angles of the master's sample k + 1 are the Jacobi run's of sample k (within SHIFT_TOLERANCE)."""
    kind, fmus = kind_fmus
    sc = load_scenario(scenario)
    folder = next(iter(fmus.values())).parent
    runs = {}
    for algorithm in ("jacobi", "fmpy-ssp"):
        setup = prepare(sc, fmu_dir=folder, native_fmu_dir=folder, build=False, kind=kind, algorithm=algorithm)
        parameters = next(c for c in sc.cases if c.key == case).parameters
        with setup.open_master(algorithm) as m:
            out = m.run(setup.case_parameters(parameters), setup.record, 300, sc.step_size)
        assert out["status"] == "ok", out["message"]
        runs[algorithm] = np.column_stack([out["signals"][f"plant.theta{i}"] for i in range(1, 12)])
    jacobi, late = runs["jacobi"], runs["fmpy-ssp"]  # rows: t_0 .. t_300; t_1 .. t_300 (no sample at t = 0)
    np.testing.assert_array_equal(late[0], jacobi[0])  # the arm has not moved over the first, torqueless step
    assert np.abs(late[-1] - jacobi[-1]).max() > 1e-4  # by the end of 300 samples the slew has moved: a shift shows
    np.testing.assert_allclose(late, jacobi[:-1], rtol=0, atol=SHIFT_TOLERANCE[scenario])


def test_whether_the_master_read_the_outputs_is_part_of_the_fmu_state(kind_fmus):
    """The first step's late start (slew_start_index 2: the master exchanged nothing before it) depends on whether
    an output was read since initialisation. A state saved before any read, restored (directly or serialised)
    after a read and a step, gives the first step of a master that reads nothing again, as a fresh instance does."""
    _, fmus = kind_fmus
    fresh = _Slave(fmus["controller"], "controller")
    try:
        fresh.slave.exitInitializationMode()
        fresh.slave.doStep(currentCommunicationPoint=0.0, communicationStepSize=1e-3)
        unread = fresh.get("slew_start_index", "tau1", "tau2")
    finally:
        fresh.close()
    assert unread[0] == 2.0
    controller = _Slave(fmus["controller"], "controller")
    try:
        controller.slave.exitInitializationMode()
        saved = controller.slave.getFMUState()
        serialised = controller.slave.serializeFMUState(saved)
        for restore in (lambda: controller.slave.setFMUState(saved),
                        lambda: controller.slave.setFMUState(controller.slave.deserializeFMUState(serialised))):
            restore()  # back to t = 0, before any read
            controller.get("tau_index")  # a master that exchanges values: the slew starts at t = 0
            controller.slave.doStep(currentCommunicationPoint=0.0, communicationStepSize=1e-3)
            assert controller.get("slew_start_index") == [1.0]
            restore()
            controller.slave.doStep(currentCommunicationPoint=0.0, communicationStepSize=1e-3)
            assert controller.get("slew_start_index", "tau1", "tau2") == unread
        controller.slave.freeFMUState(saved)
    finally:
        controller.close()
