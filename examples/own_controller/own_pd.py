"""A user's controller for the flexarm-fmi arm: joint PD plus the slew's feedforward, as a pythonfmu FMU.

Build (pythonfmu 0.7.0, from the repository root)::

    pythonfmu build -f examples/own_controller/own_pd.py -d build/examples

which writes ``build/examples/OwnPD.fmu``. Run it in a shipped scenario::

    python -m scenarios run table2 --controller build/examples/OwnPD.fmu

Law, at each communication point t_k (direct feedthrough: the torques are computed from the inputs set at
t_k when the master reads them)::

    tau_i = sat( ff * tau_i_ff + kp_i (q_i_ref - q_i_m) + kd_i (qd_i_ref - qd_i_m) ),  |tau_i| <= tau_i_max

Inputs by name: ``q1_m, q2_m, qd1_m, qd2_m`` (the sensors FMU's encoders and tachometers) and
``q1_ref, q2_ref, qd1_ref, qd2_ref, tau1_ff, tau2_ff`` (the reference FMU's outputs; the scenario master adds
the reference FMU because these inputs carry its names). Walk-through: docs/own-controller.md.
"""

import ctypes

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

# pythonfmu 0.7.0 drops one reference to this module's namespace per fmi2Instantiate (a master that
# instantiates twice would crash): keep one more (see fmus/common/flexarm_fmu_pythonfmu.py).
ctypes.pythonapi.Py_IncRef(ctypes.py_object(globals()))

MEASURED = ("q1_m", "q2_m", "qd1_m", "qd2_m")
REFERENCE = ("q1_ref", "q2_ref", "qd1_ref", "qd2_ref", "tau1_ff", "tau2_ff")
GAINS = {"kp1": (80.0, "N.m/rad"), "kd1": (1.0, "N.m.s/rad"), "kp2": (8.0, "N.m/rad"), "kd2": (0.1, "N.m.s/rad")}


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
        self.register_variable(Real("tau1", causality=Fmi2Causality.output, getter=lambda: self.torque(1)))
        self.register_variable(Real("tau2", causality=Fmi2Causality.output, getter=lambda: self.torque(2)))

    def torque(self, i):
        """Torque of joint i (1 or 2), N.m, from the inputs present now."""
        g = getattr
        tau = (g(self, f"kp{i}") * (g(self, f"q{i}_ref") - g(self, f"q{i}_m"))
               + g(self, f"kd{i}") * (g(self, f"qd{i}_ref") - g(self, f"qd{i}_m")))
        if self.use_feedforward:
            tau += g(self, f"tau{i}_ff")
        limit = g(self, f"tau{i}_max")
        return min(max(tau, -limit), limit)

    def do_step(self, current_time, step_size):
        return True  # stateless: the torques are a function of the inputs
