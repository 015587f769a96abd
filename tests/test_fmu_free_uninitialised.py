"""Freeing an instance that was never initialised, after its Python slave logged at creation, must not crash.

pythonfmu 0.7.0 delivers what the Python slave logs in ``__init__`` only at
its next call; when that call is ``fmi2FreeInstance``, its destructor
delivered it through a logger object it had already deleted (a
use-after-free: a flaky segfault of a master whose wiring failed right after
loading the FMUs). The FMI front end (fmus/common/fmi2_shim.c,
``deliver_queued_log``) now delivers such messages during
``fmi2Instantiate``. The instances run in a subprocess, so that a crash fails
this test instead of ending the test session.

The host here imports a ``flexarm`` that differs from the copy bundled in
the FMU (a copy with one comment line added). Before the FMUs imported their
bundled library under private names, the slaves warned about it at creation;
now the host's copy never reaches them, and the test checks that, and that
every free still succeeds.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import flexarm
from scenarios.config import load_scenario
from scenarios.run.fmus import DEFAULT_FMU_DIR, resolve_fmus

#: Imports the flexarm copy given as argv[1], then instantiates and frees each FMU of argv[2:] three times,
#: calling nothing in between (the third time fmi2Reset, which makes a new Python slave, before freeing);
#: prints the log as JSON: [phase, status, message] per message.
HOST = """
import importlib.util, json, sys
from pathlib import Path
copy = Path(sys.argv[1])
spec = importlib.util.spec_from_file_location("flexarm", copy / "__init__.py", submodule_search_locations=[str(copy)])
module = importlib.util.module_from_spec(spec)
sys.modules["flexarm"] = module
spec.loader.exec_module(module)
from fmpy.fmi2 import FMU2Slave
from scenarios.master.fmu_files import read_description, unpack
from scenarios.master.fmi_callbacks import logging_callbacks
phase, log = ["instantiate"], []
def logger(component, instance, status, category, message):
    log.append([phase[0], status, message.decode(errors="replace")])
callbacks = logging_callbacks(logger)
for path in sys.argv[2:]:
    md = read_description(path)
    folder = unpack(path)
    for k in range(3):
        slave = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                          instanceName=f"{md.modelName}{k}")
        phase[0] = "instantiate"
        slave.instantiate(callbacks=callbacks, loggingOn=True)
        if k == 2:
            phase[0] = "reset"
            slave.reset()
        phase[0] = "free"
        slave.freeInstance()
print(json.dumps(log))
"""


@pytest.fixture(scope="module")
def fmu_paths() -> list[str]:
    paths = resolve_fmus(load_scenario("table2"), DEFAULT_FMU_DIR)
    return [str(paths["sensors"]), str(paths["controller"])]


def test_free_after_a_warning_at_instantiation_does_not_crash(fmu_paths, tmp_path):
    copy = tmp_path / "flexarm"
    shutil.copytree(Path(flexarm.__file__).parent, copy, ignore=shutil.ignore_patterns("__pycache__"))
    with open(copy / "__init__.py", "a") as f:
        f.write("# a copy that differs from the one bundled in the FMUs\n")
    proc = subprocess.run([sys.executable, "-X", "faulthandler", "-c", HOST, str(copy), *fmu_paths],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, f"host exited with {proc.returncode} (-11: segfault):\n{proc.stderr[-3000:]}"
    log = json.loads(proc.stdout.strip().splitlines()[-1])
    # Each FMU imports its own privately named copy of flexarm (issue 21 item 4), so the host's differing copy
    # no longer reaches the slaves and none of them warns about it; the frees still all succeed ...
    assert [m for phase, status, m in log if "differs from the copy bundled" in m] == [], log
    # ... and nothing was left to deliver when the instance was freed.
    assert [entry for entry in log if entry[0] == "free"] == []
