"""Controllers that misbehave, as a user might write them: small pythonfmu FMUs built by the tests (issue 35).

Each one feeds the slew's feedforward through (``tau_i = tau_i_ff``, from the reference FMU) and behaves
until ``fail_at`` (s, default 1 s); from the first ``fmi2DoStep`` that starts at or after it, it misbehaves:

* ``raise``: ``do_step`` raises (pythonfmu returns fmi2Fatal);
* ``hang``: ``do_step`` never returns;
* ``exit``: ``do_step`` ends its process with ``os._exit(7)``;
* ``slow``: every ``do_step`` takes 2 s.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

KINDS = {"raise": "Raising", "hang": "Hanging", "exit": "Exiting", "slow": "Slow"}

_SOURCE = '''\
import ctypes
import os
import time

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

# pythonfmu 0.7.0 drops one reference to this module's namespace per fmi2Instantiate (see examples/own_controller).
ctypes.pythonapi.Py_IncRef(ctypes.py_object(globals()))


class {cls}(Fmi2Slave):
    description = "feedforward only, then {kind} in do_step from fail_at on (tests/bad_controllers.py)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        for name in ("tau1_ff", "tau2_ff"):
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input))
        self.fail_at = 1.0
        self.register_variable(Real("fail_at", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.tunable, description="s"))
        self.register_variable(Real("tau1", causality=Fmi2Causality.output, getter=lambda: self.tau1_ff))
        self.register_variable(Real("tau2", causality=Fmi2Causality.output, getter=lambda: self.tau2_ff))

    def do_step(self, current_time, step_size):
        if current_time >= self.fail_at - 1e-9:
            {action}
        return True
'''

_ACTIONS = {
    "raise": 'raise RuntimeError(f"a bug in the controller at t = {current_time}")',
    "hang": "while True:\n                time.sleep(0.05)",
    "exit": "os._exit(7)",
    "slow": "time.sleep(2.0)",
}


def build_bad_controller(kind: str, folder: Path) -> Path:
    """Build the `kind` controller (one of :data:`KINDS`) into `folder`; returns the .fmu's path."""
    cls = KINDS[kind]
    folder.mkdir(parents=True, exist_ok=True)
    script = folder / f"{cls.lower()}_controller.py"
    script.write_text(_SOURCE.format(cls=cls, kind=kind, action=_ACTIONS[kind]))
    subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(script), "-d", str(folder)],
                   check=True, capture_output=True, text=True)
    return folder / f"{cls}.fmu"
