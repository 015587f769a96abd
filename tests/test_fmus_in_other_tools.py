"""Our FMUs as a tool user meets them (issue 12): dropped into a plain FMI loop or fmpy's CLI, nothing set.

No test here uses our master to drive the FMUs under test: the loops are written
the way a newcomer would write them on fmpy, wiring the FMUs by variable name.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmu_harness import built_fmus

from flexarm.trajectory import load_trajectory
from scenarios.config import load_scenario
from scenarios.metrics import METRICS, table_metrics
from scenarios.run import runner
from scenarios.run.setup import desired_trajectory, prepare


@pytest.fixture(scope="module")
def fmus():
    return built_fmus()


def _plain_gauss_seidel(paths: dict[str, str], n_steps: int, h: float) -> dict[str, np.ndarray]:
    """plant -> sensors -> controller -> plant, wired by name, every parameter at its default.

    At each communication point: read the plant, set the sensors' inputs of the same names, read
    the sensors, set the controller's inputs, read the torques, set the plant's; then step all.
    """
    order = ["plant", "sensors", "controller"]
    mds = {k: read_model_description(paths[k]) for k in order}
    slaves, vrs = {}, {}
    for k in order:
        md = mds[k]
        slaves[k] = FMU2Slave(guid=md.guid, unzipDirectory=extract(paths[k]),
                              modelIdentifier=md.coSimulation.modelIdentifier, instanceName=k)
        vrs[k] = {v.name: v.valueReference for v in md.modelVariables}
    links = []  # (src, dst, names) for every output that has an input of the same name downstream
    for src, dst in (("plant", "sensors"), ("sensors", "controller"), ("controller", "plant")):
        outs = [v.name for v in mds[src].modelVariables if v.causality == "output"]
        ins = {v.name for v in mds[dst].modelVariables if v.causality == "input"}
        links.append((src, dst, [n for n in outs if n in ins]))
    for k in order:
        slaves[k].instantiate()
        slaves[k].setupExperiment(startTime=0.0)
        slaves[k].enterInitializationMode()
        slaves[k].exitInitializationMode()
    state = [f"theta{i}" for i in range(1, 12)] + [f"omega{i}" for i in range(1, 12)]
    rows, taus = [], []
    try:
        for k in range(n_steps + 1):
            for src, dst, names in links:
                values = slaves[src].getReal([vrs[src][n] for n in names])
                slaves[dst].setReal([vrs[dst][n] for n in names], values)
            rows.append(slaves["plant"].getReal([vrs["plant"][n] for n in state]))
            taus.append(slaves["controller"].getReal([vrs["controller"]["tau1"], vrs["controller"]["tau2"]]))
            if k < n_steps:
                for name in order:
                    slaves[name].doStep(currentCommunicationPoint=k * h, communicationStepSize=h)
    finally:
        for s in slaves.values():
            s.terminate()
            s.freeInstance()
    z = np.array(rows)
    return {"theta": z[:, :11], "omega": z[:, 11:], "tau": np.array(taus)}


def test_three_fmus_wired_by_name_with_nothing_set_give_table2(fmus):
    """Issue 12 acceptance: Table 2 without payload and noise, equal to our master's run of the scenario."""
    sc = load_scenario("table2")
    case = next(c for c in sc.cases if c.key == "none")
    assert case.parameters["plant"]["payload_mass"] == 0.0 and not case.parameters["sensors"]["noise_enabled"]
    paths = {k: str(fmus[k]) for k in ("plant", "sensors", "controller")}
    setup = prepare(sc, names={k: v for k, v in paths.items()})
    with setup.open_master() as m:
        _, ours = runner.simulate_case(setup, m, case.parameters)

    # The default experiment: the slew, read from the data
    experiments = {k: read_model_description(p).defaultExperiment for k, p in paths.items()}
    traj = desired_trajectory()
    duration = float(traj.t[-1] - traj.t[0])
    for k, e in experiments.items():
        assert (float(e.startTime), float(e.stopTime), float(e.stepSize)) == (0.0, duration, 1e-3), k
    n = int(round(duration / 1e-3))
    assert n == setup.n_steps

    plain = _plain_gauss_seidel(paths, n, 1e-3)
    theirs = table_metrics(plain["tau"], plain["theta"], plain["omega"], setup.desired["theta"],
                           setup.desired["omega"])
    print("\nplain fmpy loop, defaults:", {k: round(v, 6) for k, v in theirs.items()})
    for key in METRICS:
        assert theirs[key] == ours[key], key  # bit for bit: same FMUs, same stepping
    assert theirs["rms_position_error"] < 0.01  # and it is the paper's tracking, not a 66 deg miss


@pytest.mark.parametrize("name", ["plant", "sensors", "controller", "controller_ff", "controller_fb",
                                  "controller_dlqr", "controller_lqg"])
def test_fmpy_cli_simulates_each_fmu_with_no_options(fmus, name, tmp_path):
    """``fmpy simulate X.fmu``: the default experiment runs to the end of the slew without an error."""
    cli = [sys.executable, "-m", "fmpy.cli", "simulate", str(fmus[name])]
    proc = subprocess.run(cli, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr and "rror" not in proc.stdout + proc.stderr, proc.stdout + proc.stderr
    # the same run, its result written out to check it covers the slew with finite numbers
    out = tmp_path / f"{name}.csv"
    proc = subprocess.run([*cli, "--output-file", str(out)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    data = np.genfromtxt(out, delimiter=",", names=True)
    assert data["time"][0] == 0.0 and data["time"][-1] == pytest.approx(float(load_trajectory().t[-1]), abs=1e-9)
    assert all(np.all(np.isfinite(data[c])) for c in data.dtype.names)
    if name == "controller_lqg":  # fmpy's own output interval (4 ms): the 1 ms filter samples inside the step
        assert np.diff(data["time"]).max() > 3.9e-3


_FRESH = r"""
import json, sys
from fmpy import simulate_fmu
paths = json.loads(sys.argv[1])
assert "flexarm" not in sys.modules and "pythonfmu" not in sys.modules
rows = {}
for name in ("plant", "sensors", "controller", "controller_dlqr"):  # the plant (lean) first
    result = simulate_fmu(paths[name], stop_time=0.05, output_interval=1e-3)
    rows[name] = len(result)
ours = sorted({n.split(".")[0] for n in sys.modules if "flexarm" in n.split(".")[0]})
print(json.dumps({"rows": rows, "public": "flexarm" in sys.modules, "ours": ours}))
"""


def test_fmus_loaded_into_one_fresh_process_each_use_their_own_modules(fmus, tmp_path):
    """A process that loads the (lean) plant first, then the others: each FMU imports its own code, under names
    private to its build (fmu_build/isolate.py), and nothing under the public name ``flexarm``."""
    import json
    import os

    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run([sys.executable, "-c", _FRESH, json.dumps({k: str(v) for k, v in fmus.items()})],
                         capture_output=True, text=True, timeout=600, cwd=tmp_path, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert set(result["rows"].values()) == {51}
    assert not result["public"]
    packages = {n for n in result["ours"] if n.startswith("_flexarm_") and "_fmu_" not in n
                and not n.startswith(("_flexarm_feedthrough", "_flexarm_controller_base"))}
    assert len(packages) == 4, result["ours"]  # one private flexarm per FMU
