"""Reference FMU ``reference``: the minimum-time slew as the controllers see it (FMI 2.0 co-simulation).

A thin wrapper over :class:`flexarm.reference.ReferenceSignals`. No inputs; one parameter, ``lead_samples``
(Integer 0..1000, samples of 1 ms, default 0; see below). At communication point t_k its outputs are those
of sample k = round(t_k / 1 ms) + lead_samples of the committed trajectory
(``flexarm/data/trajectory.npz``, bundled with its provenance file; the SHA-256 of the parameter file it
records is checked when the FMU initialises): the desired states ``theta_ref1..11``, ``omega_ref1..11``,
the joint references ``q1_ref, q2_ref`` (q2 = θ7 − θ6), ``qd1_ref, qd2_ref``, the feedforward torques
``tau1_ff, tau2_ff`` (0 after the slew), the desired tip ``tip_x_ref, tip_y_ref`` and ``progress`` (k / n,
1 from t_f on). After t_f the final state is held. A step must be a whole number of milliseconds (within
1e-9 s; 0 samples: nothing happens).

``lead_samples`` = L: the outputs lead the time by L samples, for a master whose stepping delays them on
their way to the plant (Jacobi: the controller's torques computed from the outputs of t_k reach the plant
at t_k+1, so L = the communication step in samples; :func:`flexarm.reference.lead_samples_for`). With it the
feedforward torque of sample k acts over sample k, as with L = 0 in a Gauss-Seidel master.

Names: the signal catalogue (``flexarm/data/signals.toml``, fmu "reference"), so a user controller whose
inputs carry these names is wired to it by name. Interface: ``docs/own-controller.md``.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
from flexarm_feedthrough import FeedthroughSlave, whole_samples
from flexarm_fmu_base import Var, own_data_dir, pin_module_namespace, slew_experiment, variable_table

from flexarm.lqr import default_trajectory_path
from flexarm.reference import MAX_LEAD_SAMPLES, ReferenceSignals
from flexarm.signals import signals

pin_module_namespace(globals())  # pythonfmu 0.7.0 drops a reference per instantiation (see there)

VARIABLES = variable_table([
    Var("lead_samples", "parameter", "fixed", None,
        "Samples of 1 ms by which the outputs lead the time: at t they are those of sample round(t / 1 ms) + "
        "lead_samples. 0 for a Gauss-Seidel master; the communication step in samples for a Jacobi master "
        "(the controller's torques reach the plant one step late)",
        0, 0, MAX_LEAD_SAMPLES, type="Integer"),
    *[Var(s.name, "output", "continuous", s.unit, s.description, depends_on=(), initial_depends_on=())
      for s in signals("reference", "output")],
])


@functools.lru_cache(maxsize=4)
def _reference(data: str | None) -> ReferenceSignals:
    """The reference table of this FMU's own trajectory (`data`: its resources/flexarm/data, or None)."""
    return ReferenceSignals(default_trajectory_path() if data is None else Path(data) / "trajectory.npz")


class FlexarmReference(FeedthroughSlave):
    """The committed slew's reference signals, sampled every 1 ms, the final state held after t_f."""

    VARIABLES = VARIABLES
    description = "Sandia two-link flexible arm: reference signals of the minimum-time slew (1 ms samples)"
    default_experiment = slew_experiment()

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.ref: ReferenceSignals | None = None

    def setup(self) -> None:
        if self.ref is None:
            self.ref = _reference(own_data_dir(self.resources))

    def evaluate(self) -> np.ndarray:
        return self.ref.at_time(self.time, int(self.value("lead_samples")))

    def samples_in_step(self, t: float, h: float) -> int:
        return whole_samples(h, self.ref.dt, "the reference's sample (the trajectory's sample time)")

    def set_sample_state(self, state: dict) -> None:
        self.setup()
