"""The master's stepping loop in C (scenarios/master/step_loop.c) is the Python loop, bit for bit (issue 34).

The C loop makes the same FMI calls in the same order on the same buffers, so every recorded value, the number of
steps done and the outcome must be the Python loop's exactly: in each stepping (Gauss-Seidel, Jacobi, fmpy's
simulate_ssp), with noise, when a signal leaves the bounds, when an FMU fails mid-run, and with progress reported
at the same points. ``FLEXARM_MASTER_LOOP=python`` selects the Python loop.
"""

from __future__ import annotations

import pytest
from bad_controllers import build_bad_controller
from fmu_harness import built_fmus
from native_fmus import native_fmus

from scenarios.config import load_scenario
from scenarios.master import step_loop
from scenarios.master.cosim import Connection, Master
from scenarios.run.setup import prepare


@pytest.fixture(scope="module")
def native_dir():
    return next(iter(native_fmus().values())).parent


def _counting_c_calls(monkeypatch) -> list:
    """Calls of the C loop in this test (none when the Python loop runs)."""
    calls, run = [], step_loop.CompiledLoop.run

    def counted(self, *args):
        calls.append(args)
        return run(self, *args)

    monkeypatch.setattr(step_loop.CompiledLoop, "run", counted)
    return calls


def _run(monkeypatch, loop: str, fmu_dir, scenario: str, algorithm: str, parameters: dict, n: int, **kwargs):
    monkeypatch.setenv(step_loop.LOOP_VARIABLE, loop)
    c_calls = _counting_c_calls(monkeypatch)
    setup = prepare(load_scenario(scenario), fmu_dir, build=False)
    params = setup.case_parameters(parameters)
    progress = []
    with setup.open_master(algorithm) as m:
        result = m.run(params, setup.record, n, progress=lambda k, total: progress.append(k), **kwargs)
    assert bool(c_calls) == (loop == "c")
    return result, progress


def _same(a: dict, b: dict) -> None:
    assert (a["status"], a["message"], a["steps_done"]) == (b["status"], b["message"], b["steps_done"])
    assert a["time"].tobytes() == b["time"].tobytes()
    for name in a["signals"]:
        assert a["signals"][name].tobytes() == b["signals"][name].tobytes(), name


def test_this_machine_compiles_the_loop():
    """CI has a C compiler: the C loop is what runs there (so the comparisons below compare two loops)."""
    assert step_loop.loop_function() is not None


@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi", "fmpy-ssp"])
def test_the_c_loop_gives_the_python_loops_run_bit_for_bit(monkeypatch, native_dir, algorithm):
    runs = [_run(monkeypatch, loop, native_dir, "table2", algorithm, {"sensors": {"noise_enabled": True}}, 700)
            for loop in ("python", "c")]
    _same(runs[0][0], runs[1][0])
    assert runs[0][0]["status"] == "ok" and runs[0][0]["steps_done"] == 700
    assert runs[0][1] == runs[1][1] and runs[0][1][-1] == 700  # progress at the same points


def test_a_signal_out_of_bounds_ends_both_loops_at_the_same_step(monkeypatch, native_dir):
    """A bound the slew's torques pass at some step: the same step, signal and message, NaN after, in both."""
    runs = [_run(monkeypatch, loop, native_dir, "table2", "gauss-seidel", {}, 800, divergence_limit=3.0)[0]
            for loop in ("python", "c")]
    assert runs[0]["status"] == "unbounded" and 0 < runs[0]["steps_done"] < 800
    _same(runs[0], runs[1])


def test_an_fmu_that_fails_mid_run_ends_both_loops_alike(monkeypatch, tmp_path):
    """A controller whose fmi2DoStep fails (pythonfmu: fmi2Fatal) at 0.1 s, in this process: the same outcome,
    the same steps done, the same rows, NaN after the last one gathered."""
    bad = build_bad_controller("raise", tmp_path)
    fmus = built_fmus()
    runs = []
    for loop in ("python", "c"):
        monkeypatch.setenv(step_loop.LOOP_VARIABLE, loop)
        c_calls = _counting_c_calls(monkeypatch)
        with Master({"ref": fmus["reference"], "c": bad}, ["ref", "c"],
                    [Connection("ref", "tau1_ff", "c", "tau1_ff"), Connection("ref", "tau2_ff", "c", "tau2_ff")]) as m:
            runs.append(m.run({"c": {"fail_at": 0.1}}, [("c", "tau1"), ("ref", "tau1_ff")], 300))
        assert bool(c_calls) == (loop == "c")
    assert runs[0]["status"] == "error" and runs[0]["outcome"].fmu_status == "fatal"
    _same(runs[0], runs[1])
    assert str(runs[0]["outcome"].as_dict()) == str(runs[1]["outcome"].as_dict())


def test_fmu_functions_wrapped_in_python_run_the_python_loop(monkeypatch, native_dir):
    """A master whose FMU functions are not the library's (a test's or a tool's wrapper around fmi2DoStep) must
    call the wrapper: the C loop would call the library behind it. The run is then the Python loop's."""
    from scenarios.master import units

    raw, wrapped_calls = units.fmu2_raw_functions, []

    def wrapping(slave):
        get_real, set_real, do_step = raw(slave)

        def step(component, t, h, new_step):
            wrapped_calls.append(t)
            return do_step(component, t, h, new_step)
        return get_real, set_real, step

    reference, _ = _run(monkeypatch, "python", native_dir, "table2", "gauss-seidel", {}, 50)
    monkeypatch.setattr(units, "fmu2_raw_functions", wrapping)
    monkeypatch.setenv(step_loop.LOOP_VARIABLE, "c")
    c_calls = _counting_c_calls(monkeypatch)
    setup = prepare(load_scenario("table2"), native_dir, build=False)
    with setup.open_master() as m:
        result = m.run(setup.case_parameters({}), setup.record, 50)
    assert c_calls == [] and len(wrapped_calls) == 3 * 50
    _same(reference, result)
