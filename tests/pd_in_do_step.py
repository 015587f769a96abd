"""A plain joint PD plus feedforward whose torques are computed in ``do_step`` (one sample late), as a user might
first write it: with the rate gain ``kd1`` = 6 N·m·s/rad the loop is unstable on table2 (issue 35, item 1), with
the default ``kd1`` = 0.25 it tracks. Built by tests (tests/pd_fmus.py) with ``pythonfmu build``.
"""

import ctypes

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

# pythonfmu 0.7.0 drops one reference to this module's namespace per fmi2Instantiate (see examples/own_controller).
ctypes.pythonapi.Py_IncRef(ctypes.py_object(globals()))

INPUTS = ("q1_m", "q2_m", "qd1_m", "qd2_m", "q1_ref", "q2_ref", "qd1_ref", "qd2_ref", "tau1_ff", "tau2_ff")
GAINS = {"kp1": 80.0, "kd1": 0.25, "kp2": 2.0, "kd2": 0.01}
LIMITS = (7.0, 2.25)  # the motors' peak torques, N.m


class PDInDoStep(Fmi2Slave):
    """tau_i = sat(tau_i_ff + kp_i (q_i_ref - q_i_m) + kd_i (qd_i_ref - qd_i_m)), updated in do_step."""

    author = "a flexarm-fmi test"
    description = "Joint PD plus feedforward, torques computed in do_step"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        for name in INPUTS:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input))
        for name, value in GAINS.items():
            setattr(self, name, value)
            self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.tunable))
        self.use_feedforward = True
        self.register_variable(Boolean("use_feedforward", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.tunable))
        self.tau1, self.tau2 = 0.0, 0.0
        self.register_variable(Real("tau1", causality=Fmi2Causality.output))
        self.register_variable(Real("tau2", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        for i, limit in ((1, LIMITS[0]), (2, LIMITS[1])):
            g = getattr
            tau = (g(self, f"kp{i}") * (g(self, f"q{i}_ref") - g(self, f"q{i}_m"))
                   + g(self, f"kd{i}") * (g(self, f"qd{i}_ref") - g(self, f"qd{i}_m")))
            if self.use_feedforward:
                tau += g(self, f"tau{i}_ff")
            setattr(self, f"tau{i}", min(max(tau, -limit), limit))
        return True
