"""Drive one FMU step by step through fmpy's low-level FMU2Slave, with its log captured (test helper)."""

from __future__ import annotations

import numpy as np
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

from scenarios.master import logging_callbacks

DT = 1e-3


class Slave:
    """An FMU driven step by step through fmpy's FMU2Slave, with its log captured."""

    def __init__(self, fmu_path, unzipdir, name="fmu", **params):
        self.md = read_model_description(str(fmu_path))
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.messages: list[tuple[int, str]] = []

        def logger(component, instance, status, category, message):
            self.messages.append((status, message.decode()))

        self._callbacks = cb = logging_callbacks(logger)  # referenced as long as the instance lives
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=unzipdir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(callbacks=cb, loggingOn=True)
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.set(**params)
        self.fmu.exitInitializationMode()
        self.time = 0.0

    def set(self, **values):
        for name, value in values.items():
            var = self.vars[name]
            setter = {"Real": self.fmu.setReal, "Integer": self.fmu.setInteger, "Boolean": self.fmu.setBoolean,
                      "String": self.fmu.setString}[var.type]
            setter([var.valueReference], [value])

    def set_vector(self, names, values):
        self.fmu.setReal([self.vars[n].valueReference for n in names], [float(v) for v in values])

    def get(self, names) -> np.ndarray:
        return np.array(self.fmu.getReal([self.vars[n].valueReference for n in names]))

    def step(self, h=DT):
        self.fmu.doStep(self.time, h)
        self.time += h

    def errors(self) -> list[str]:
        return [m for s, m in self.messages if s >= 3]

    def close(self):
        self.fmu.terminate()
        self.fmu.freeInstance()
