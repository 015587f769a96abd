"""A user's controller for the flexarm-fmi arm: joint PD plus the slew's feedforward, as a pythonfmu FMU.

Build (pythonfmu 0.7.0, from the repository root)::

    pythonfmu build -f examples/own_controller/own_pd.py -d build/examples

which writes ``build/examples/OwnPD.fmu``. Run it in a shipped scenario::

    python -m scenarios run table2 --controller build/examples/OwnPD.fmu

Law, at each communication point t_k (direct feedthrough: the torques are computed from the inputs set at
t_k when the master reads them)::

    tau_i = sat( ff * tau_i_ff + kp_i (q_i_ref[-d] - q_i_m) + kd_i (qd_i_ref[-d] - qd_i_m) ),  |tau_i| <= tau_i_max

d = ``loop_delay_samples``: the samples between the plant state the measurements show and the sample whose
torques use them. The measurements are compared with the reference of their own instant: with d > 0 (a
Jacobi master, whose inputs at a read are those present at the last ``fmi2DoStep``) the one present d samples
before that (``[-d]``; kept at each ``fmi2DoStep``, one entry per 1 ms sample of the step; before d samples
exist, the first one kept). The feedforward is the one present now. d = 0 in a Gauss-Seidel master (our
default); in a Jacobi master (libcosim, fmpy's ``simulate_ssp``) d = 2 per millisecond of the step (through
the sensors FMU, then this one), with the reference FMU's ``lead_samples`` at the step in samples, which the
scenario runner sets (docs/own-controller.md, "Jacobi masters").

Inputs by name: ``q1_m, q2_m, qd1_m, qd2_m`` (the sensors FMU's encoders and tachometers) and
``q1_ref, q2_ref, qd1_ref, qd2_ref, tau1_ff, tau2_ff`` (the reference FMU's outputs; the scenario master adds
the reference FMU because these inputs carry its names). Walk-through: docs/own-controller.md.
"""

import ctypes
from collections import deque

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real
from pythonfmu.enums import Fmi2Status

# pythonfmu 0.7.0 drops one reference to this module's namespace per fmi2Instantiate (a master that
# instantiates twice would crash): keep one more (see fmus/common/flexarm_fmu_pythonfmu.py).
ctypes.pythonapi.Py_IncRef(ctypes.py_object(globals()))

MEASURED = ("q1_m", "q2_m", "qd1_m", "qd2_m")
REFERENCE = ("q1_ref", "q2_ref", "qd1_ref", "qd2_ref", "tau1_ff", "tau2_ff")
# Chosen for both masters: in a Jacobi master larger rate gains (kd1 = 1, kd2 = 0.1) let the loop delay make a
# link-1 vibration of the undamped arm grow (docs/own-controller.md, "Jacobi masters").
GAINS = {"kp1": (80.0, "N.m/rad"), "kd1": (0.25, "N.m.s/rad"), "kp2": (2.0, "N.m/rad"), "kd2": (0.01, "N.m.s/rad")}
COMPARED = ("q1_ref", "q2_ref", "qd1_ref", "qd2_ref")  # the reference the measurements are compared with
SAMPLE = 1e-3  # the reference's sample, s
MAX_DELAY = 10  # loop_delay_samples allowed: 0..MAX_DELAY


class OwnPD(Fmi2Slave):
    """Joint PD + feedforward; parameters kp1, kd1, kp2, kd2, use_feedforward, tau1_max, tau2_max."""

    author = "a flexarm-fmi user"
    description = "Joint PD plus feedforward for the Sandia two-link flexible arm (example)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        for name in MEASURED + REFERENCE:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input))
        for name, (value, unit) in GAINS.items():
            setattr(self, name, value)
            self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.tunable, description=f"gain, {unit}"))
        self.use_feedforward = True
        self.register_variable(Boolean("use_feedforward", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.tunable, description="add tau_ff"))
        self.tau1_max, self.tau2_max = 7.0, 2.25  # the motors' peak torques, N.m
        for name in ("tau1_max", "tau2_max"):
            self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.tunable, description="saturation, N.m"))
        self.loop_delay_samples = 0
        self.register_variable(Integer("loop_delay_samples", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.fixed,
                                       description=f"samples between the plant state measured and the torques "
                                                   f"using it (0..{MAX_DELAY}): 0 Gauss-Seidel, 2 Jacobi at 1 ms"))
        self.past = deque(maxlen=1)  # the compared reference of the last d + 1 samples (exit_initialization_mode)
        self.register_variable(Real("tau1", causality=Fmi2Causality.output, getter=lambda: self.torque(1)))
        self.register_variable(Real("tau2", causality=Fmi2Causality.output, getter=lambda: self.torque(2)))

    def exit_initialization_mode(self):
        self.past = deque(maxlen=min(max(int(self.loop_delay_samples), 0), MAX_DELAY) + 1)

    def torque(self, i):
        """Torque of joint i (1 or 2), N.m, from the inputs present now and the reference d samples ago."""
        g = getattr
        if self.loop_delay_samples > 0 and self.past:  # Jacobi: the inputs read are those of the last fmi2DoStep
            ref = dict(zip(COMPARED, self.past[0]))
        else:
            ref = {name: g(self, name) for name in COMPARED}
        tau = (g(self, f"kp{i}") * (ref[f"q{i}_ref"] - g(self, f"q{i}_m"))
               + g(self, f"kd{i}") * (ref[f"qd{i}_ref"] - g(self, f"qd{i}_m")))
        if self.use_feedforward:
            tau += g(self, f"tau{i}_ff")
        limit = g(self, f"tau{i}_max")
        return min(max(tau, -limit), limit)

    def do_step(self, current_time, step_size):
        """Keep the reference present now, once per 1 ms sample of the step (the torques read a past one)."""
        d, n = self.loop_delay_samples, round(step_size / SAMPLE)
        if not 0 <= d <= MAX_DELAY or abs(step_size - n * SAMPLE) > 1e-9:
            self.log(f"loop_delay_samples = {d} (allowed 0..{MAX_DELAY}), step_size = {step_size!r} s (allowed: "
                     f"whole multiples of {SAMPLE} s)", Fmi2Status.error)
            return False
        present = tuple(getattr(self, name) for name in COMPARED)
        self.past.extend([present] * min(n, MAX_DELAY + 1))
        return True
