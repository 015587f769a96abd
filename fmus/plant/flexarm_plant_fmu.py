"""Plant FMU: the 11-element Sandia flexible arm (FMI 2.0 co-simulation).

A thin wrapper over :mod:`flexarm`: every equation lives in
:class:`flexarm.ArmModel` and :func:`flexarm.integrator.advance`; this module
only maps FMI variables to and from them. The module name is unique among
this project's FMUs (pythonfmu imports it by name; see
``fmus/common/flexarm_fmu_base.py``).

Interface (full table in ``docs/fmu-interface.md``):

Its inputs and outputs are the plant's rows of the signal catalogue
(``flexarm/data/signals.toml``):

* inputs ``tau1``, ``tau2`` (N·m), held constant over each step, and ``tau_index``, the index of the
  controller sample they were computed for (:mod:`flexarm.loop_index`);
* parameters ``payload_mass`` (kg), ``q1_0``, ``q2_0`` (rad), ``substeps``
  (per millisecond of the step), ``integrator`` (1 ``rodas4``, 2 ``exponential``,
  3 ``gauss``, 4 ``reference``), ``damping_ratio`` and ``link_stiffness_scale`` (a model error: the
  flexible links' springs that many times as stiff as the design model's);
* outputs at the communication point: element angles and rates, joint
  angles and rates, strain-gauge angles, tip position, link-tip
  accelerations and accelerometer signals; ``sample_index`` (the index of the sample the outputs belong
  to) and ``tau_lag`` (how late the torque held over the finished step was, -1 without an index).

Defaults (nothing set): the arm starts at rest and undeformed on the
committed trajectory's first state (``q1_0``, ``q2_0`` read from
``flexarm/data/trajectory.npz`` when the FMU is built), no payload beyond the
parameter file's, and the default experiment lasts the slew (1 ms steps).

A step whose integration leaves the finite numbers (absurd torques or step
sizes) is discarded (``fmi2Discard``; the state stays at the communication
point), as FMI intends for a step a smaller one may complete.

``substeps`` counts substeps **per millisecond**: a communication step of
h ms takes ceil(h · substeps) equal substeps, so the plant's accuracy does not
depend on the master's step (a 10 ms step at the default 2 takes 20 substeps
of 0.5 ms, as ten 1 ms steps would). With ``rodas4`` that is the nominal
substep: one whose embedded error estimate exceeds 3e-8 rad on an angle is
redone at half the length (``flexarm._kernels.advance``; docs/model.md).

Integration scheme (``integrator``; docs/model.md has each scheme's measured
accuracy against the reference, generated, and its cost):

* 1 ``rodas4`` (default): L-stable Rosenbrock, order 4. Adds no damping to the
  8 and 20 Hz link modes but 1.56e3, 3.12e3 and 4.05e3 1/s at the 5.7, 13.2
  and 21.2 kHz bracket modes at 2 substeps per ms: they vanish within a few
  ms, so a controller that destabilises a bracket mode looks stable.
* 2 ``exponential``: exponential Rosenbrock-Euler, order 2, exact for the
  linearised dynamics, but its energy error grows without bound: it refuses to
  step past t = 3 s (``flexarm.integrator.EXPONENTIAL_HORIZON_S``).
* 3 ``gauss``: 2-stage Gauss-Legendre collocation, order 4, symmetric: no
  numerical damping on any mode and a bounded energy error. It resolves the
  bracket modes' frequencies (hence their sampled-loop stability) only with
  fine substeps (about 32 per ms).
* 4 ``reference``: classical RK4 at 200 · ``substeps`` steps per ms (2.5 µs
  at the default): the converged solution, slow (for verification).

``damping_ratio`` (default 0, the paper's undamped model) gives every
flexible mode the modal damping ratio ζ (built at q = (0, 90°)); typical
values are 0.001-0.005 for monolithic aluminium links and 0.02-0.05 for
bolted brackets and joints (docs/model.md, with sources).

The accelerations are evaluated with the torque held over the step that
ended at the communication point (at the start time: the torque inputs as set
during initialisation), so no output depends directly on the current
inputs and a controller can be connected without an algebraic loop.
"""

from __future__ import annotations

import math

import numpy as np
from flexarm_fmu_base import (
    FlexarmSlave,
    StepDiscarded,
    Var,
    pin_module_namespace,
    slew,
    slew_experiment,
    variable_table,
)

from flexarm.integrator import (
    DEFAULT_SUBSTEPS,
    INTEGRATORS,
    MAX_SUBSTEPS,
    IntegrationError,
    advance,
    check_horizon,
)
from flexarm.loop_index import index_of_time, torque_lag
from flexarm.model import (
    ArmModel,
    N,
    rigid_configuration,
)
from flexarm.parameters import LINK_STIFFNESS_SCALE_RANGE, load_parameters
from flexarm.signals import signals

pin_module_namespace(globals())  # pythonfmu 0.7.0 drops a reference per instantiation (see there)

#: The committed trajectory's start angles and length: the defaults (q1_0, q2_0, default experiment).
_SLEW = slew()


#: Outputs that use the torque present at initialisation (no step has ended yet): the accelerations and the
#: torque "held"; tau_lag uses the tau_index present then. The angles, rates and positions use the parameters only.
_AT_START = {"link1_tip_ax": ("tau1", "tau2"), "link1_tip_ay": ("tau1", "tau2"), "link2_tip_ax": ("tau1", "tau2"),
             "link2_tip_ay": ("tau1", "tau2"), "acc1_n": ("tau1", "tau2"), "acc2_n": ("tau1", "tau2"),
             "tau_lag": ("tau_index",), "tau1_applied": ("tau1",), "tau2_applied": ("tau2",)}


def _signal(s) -> Var:
    # Inputs are held over the step; outputs are functions of the state and the torque of the
    # finished step: no direct feedthrough from the inputs (empty dependencies). At initialisation they
    # depend on the inputs of _AT_START only, so that a master solving initialisation as one system finds
    # no algebraic loop through the controller (OMSimulator did, and failed on the LQG's archives).
    if s.causality == "input":
        return Var(s.name, "input", "continuous", s.unit, s.description, 0.0)
    return Var(s.name, "output", "continuous", s.unit, s.description, depends_on=(),
               initial_depends_on=_AT_START.get(s.name, ()))


VARIABLES = variable_table([
    *[_signal(s) for s in signals("plant", "input")],
    ("payload_mass", "parameter", "fixed", "kg", "Extra point mass at the tip of link 2",
     float(load_parameters().payload_mass), (0.0, 10.0)),
    ("q1_0", "parameter", "fixed", "rad", "Initial joint-1 angle (arm undeformed and at rest); "
     "default: the trajectory's first sample", _SLEW["q1_0"], (-2 * math.pi, 2 * math.pi)),
    ("q2_0", "parameter", "fixed", "rad", "Initial joint-2 (elbow) angle, relative to link 1; "
     "default: the trajectory's first sample", _SLEW["q2_0"], (-math.pi, math.pi)),
    ("substeps", "parameter", "fixed", "1",
     "Integrator substeps per millisecond of the communication step (a step of h ms takes ceil(h * substeps), so "
     "the accuracy does not depend on the step size); rodas4 halves a substep whose error estimate exceeds "
     "3e-8 rad on an angle; the reference scheme takes 200 RK4 steps per substep",
     int(DEFAULT_SUBSTEPS), (1, MAX_SUBSTEPS)),
    ("integrator", "parameter", "fixed", "1",
     "Integration scheme: rodas4 is L-stable and damps the kHz bracket modes; exponential adds no numerical "
     "damping but refuses to run past 3 s (unbounded energy error); gauss (Gauss-Legendre, order 4) adds no "
     "damping and keeps the energy error bounded (resolves the bracket modes from about 32 substeps); reference "
     "is RK4 at 2.5 us (slow, for verification); choices: 1 = rodas4, 2 = exponential, 3 = gauss, 4 = reference",
     1, (1, len(INTEGRATORS))),
    ("damping_ratio", "parameter", "fixed", "1",
     "Modal structural damping ratio of every flexible mode (0: the paper's undamped model)", 0.0, (0.0, 1.0)),
    ("link_stiffness_scale", "parameter", "fixed", "1",
     "Factor on the stiffness of the flexible links' springs (the six the strain gauges read; the brackets keep "
     "theirs): a model error, e.g. 1.05 for links 5 % stiffer than the model the slew and gains were designed on",
     1.0, LINK_STIFFNESS_SCALE_RANGE),
    *[_signal(s) for s in signals("plant", "output")],  # = flexarm.model.OBSERVABLE_NAMES
])


class FlexarmPlant(FlexarmSlave):
    """The Sandia two-link flexible arm as an FMI 2.0 co-simulation slave.

    State: z = (theta_1..theta_11 rad, omega_1..omega_11 rad/s), advanced by
    :func:`flexarm.integrator.advance` (the ``integrator`` scheme, ``substeps`` equal
    substeps per millisecond of whatever step the master asks).
    """

    VARIABLES = VARIABLES
    description = "Sandia two-link flexible arm, 11-element model (plant)"
    default_experiment = slew_experiment()

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.model: ArmModel | None = None
        self._model_key: tuple | None = None
        self.z = np.zeros(2 * N)
        self.tau_held = np.zeros(2)  # torque of the last finished step (for the accelerations)
        self.last_error = 0.0

    def _build_model(self) -> None:
        key = (self.value("payload_mass"), self.value("damping_ratio"), self.value("link_stiffness_scale"))
        if self.model is None or self._model_key != key:
            self.model = ArmModel(load_parameters(payload_mass=key[0]).with_link_stiffness(key[2]),
                                  damping_ratio=key[1])
            self._model_key = key

    def _integrator(self) -> str:
        return INTEGRATORS[int(self.value("integrator")) - 1]

    def _torque(self) -> np.ndarray:
        return np.array([self.value("tau1"), self.value("tau2")])

    def initialize(self) -> None:
        self._build_model()
        z = np.concatenate([rigid_configuration(self.value("q1_0"), self.value("q2_0")), np.zeros(N)])
        tau = self._torque()
        self.set_outputs(self._outputs(z, tau, self.time, self.time))
        self.z, self.tau_held, self.last_error = z, tau, 0.0

    def step(self, t: float, h: float) -> None:
        tau = self._torque()
        # fmi2Error (not a discard: no smaller step helps), the message naming the scheme, the limit and the cure
        check_horizon(self._integrator(), t + h - self.start_time)
        try:
            z, err = advance(self.model, self.z, tau, h, self.value("substeps"), self._integrator())
        except IntegrationError as exc:  # FMI's discard: not done, a smaller step (or more substeps) may do
            raise StepDiscarded(f"{exc} (tau1 = {float(tau[0])!r} N.m, tau2 = {float(tau[1])!r} N.m, h = {h!r} s, "
                                f"substeps = {self.value('substeps')})") from None
        outputs = self._outputs(z, tau, t + h, t)
        # Commit only after everything succeeded: a failed step leaves the state untouched.
        self.set_outputs(outputs)
        self.z, self.tau_held, self.last_error = z, tau, err

    def _outputs(self, z: np.ndarray, tau: np.ndarray, t: float, held_from: float) -> np.ndarray:
        """All outputs in table order for state z at time t and torque tau held since `held_from`.

        flexarm.model.OBSERVABLE_NAMES, then the sample indices (``sample_index``, ``tau_lag``; see
        :mod:`flexarm.loop_index`; the tau_index present now came with tau) and the torque held
        (``tau1_applied``, ``tau2_applied``).
        """
        return np.concatenate([self.model.observables(z, tau),
                               [index_of_time(t), torque_lag(held_from, self.value("tau_index")), *tau]])

    def get_internal_state(self) -> dict:
        return {"z": self.z.tolist(), "tau_held": self.tau_held.tolist(), "last_error": self.last_error}

    def set_internal_state(self, state: dict) -> None:
        z = np.array(state["z"], dtype=float)
        if z.shape != (2 * N,):
            raise ValueError(f"z: expected {2 * N} state values, got {z.shape}")
        self._build_model()
        self.z = z
        self.tau_held = np.array(state["tau_held"], dtype=float)
        self.last_error = float(state["last_error"])
