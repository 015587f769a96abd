"""The reference signals a controller tracks, sampled as the project's controllers sample them (no FMI).

What the reference FMU (``fmus/reference/``, native ``fmus/native/reference/``) outputs: at sample
k = round(t / dt) (:meth:`flexarm.control.TrackingController.sample_index`, dt = 1 ms, the
trajectory's sample time) the desired state z_d[k] (:meth:`~flexarm.control.TrackingController.desired_state`:
the final state for k ≥ n), the joint references q_d = (θ1, θ7 − θ6) and q̇_d of it
(:func:`flexarm.model.joint_angles`, the encoders' map), the feedforward torque of the sample
(:meth:`~flexarm.control.TrackingController.feedforward`: τ[k] for k < n, 0 after), the desired tip and
the progress k / n (1 from t_f on). n = t_f / dt is the number of torque steps of the slew.

**Lead** (the FMU's ``lead_samples`` parameter, L ≥ 0 samples, default 0): at time t the outputs are
those of sample round(t / dt) + L, the same rows shifted. A master whose stepping delays the reference
on its way to the plant (Jacobi: one communication step through the controller, :func:`lead_samples_for`)
sets L to that delay, so that the feedforward torque of sample k acts over sample k, as in a
Gauss-Seidel master with L = 0.

Column names and order: the catalogue's ``reference`` outputs (``flexarm/data/signals.toml``).
"""

from __future__ import annotations

import numpy as np

from .control import TrackingController
from .model import JOINT2_PAIR, N
from .signals import names

#: The reference FMU's outputs, in order (signal catalogue, fmu "reference").
REFERENCE_OUTPUTS = names("reference", "output")
#: Largest lead the reference FMU accepts, samples (1 s of 1 ms samples).
MAX_LEAD_SAMPLES = 1000
#: Steppings whose masters read every output before setting any input (one step of delay per
#: direct-feedthrough FMU a signal crosses): libcosim, fmpy's ``simulate_ssp`` (scenarios.master.cosim's "fmpy-ssp").
JACOBI_STEPPINGS = ("jacobi", "fmpy-ssp")


def lead_samples_for(stepping: str, samples_per_step: int = 1) -> int:
    """The reference FMU's ``lead_samples`` for a master's stepping: the reference's delay on its way to the plant.

    Parameters
    ----------
    stepping : {"gauss-seidel", "jacobi", "fmpy-ssp"}
        Gauss-Seidel (the controller reads the reference's outputs of the same communication point and the
        plant its torques before stepping): no delay, 0. Jacobi ("fmpy-ssp" steps the same way): the
        controller's torques computed from the reference of t_k reach the plant at t_k+1, one communication
        step later (the controller is the one direct-feedthrough FMU between them).
    samples_per_step : int
        The communication step in samples of 1 ms (≥ 1).

    Returns
    -------
    int
        Samples, 0 or `samples_per_step` (≤ :data:`MAX_LEAD_SAMPLES`).

    Raises
    ------
    ValueError
        Naming ``stepping`` or ``samples_per_step``.
    """
    if stepping not in ("gauss-seidel", *JACOBI_STEPPINGS):
        raise ValueError(f"stepping: one of gauss-seidel, {', '.join(JACOBI_STEPPINGS)}, got {stepping!r}")
    if isinstance(samples_per_step, bool) or not isinstance(samples_per_step, int) \
            or not 1 <= samples_per_step <= MAX_LEAD_SAMPLES:
        raise ValueError(f"samples_per_step: an integer in 1..{MAX_LEAD_SAMPLES} (the communication step in 1 ms "
                         f"samples), got {samples_per_step!r}")
    return samples_per_step if stepping in JACOBI_STEPPINGS else 0


class ReferenceSignals:
    """The reference outputs of every sample of a trajectory (computed once), looked up by time.

    Parameters
    ----------
    trajectory : TrajectoryResult or path-like
        The minimum-time slew (a path is read through :func:`flexarm.trajectory.load_trajectory`, which checks
        the SHA-256 of the parameter file it records).

    Attributes
    ----------
    table : ndarray, shape (n + 1, len(REFERENCE_OUTPUTS))
        Row k: the outputs of sample k; row n (t = t_f) is held for every later sample.
    dt : float
        Sample time, s.
    n_steps : int
        n, the torque steps of the slew.
    """

    def __init__(self, trajectory):
        law = TrackingController(trajectory, None, mode="ff", saturation=None)  # the controllers' sampling
        self.dt, self.n_steps = law.dt, law.n_steps
        self._law = law
        n = self.n_steps
        z = np.array([law.desired_state(k) for k in range(n + 1)])
        theta, omega = z[:, :N], z[:, N:]
        # the motor angles and rates of every row at once (joint_angles is a difference of two elements)
        q, qd = (np.column_stack([x[:, 0], x[:, JOINT2_PAIR[1]] - x[:, JOINT2_PAIR[0]]]) for x in (theta, omega))
        tau = np.array([law.feedforward(k) for k in range(n + 1)])
        tip = np.asarray(law.trajectory.tip, dtype=float)[: n + 1]
        columns = {**{f"theta_ref{i + 1}": theta[:, i] for i in range(N)},
                   **{f"omega_ref{i + 1}": omega[:, i] for i in range(N)},
                   "q1_ref": q[:, 0], "q2_ref": q[:, 1], "qd1_ref": qd[:, 0], "qd2_ref": qd[:, 1],
                   "tau1_ff": tau[:, 0], "tau2_ff": tau[:, 1], "tip_x_ref": tip[:, 0], "tip_y_ref": tip[:, 1],
                   "progress": np.arange(n + 1) / n}
        rows = np.column_stack([columns[name] for name in REFERENCE_OUTPUTS])
        self.table = np.array(rows, dtype=float)
        self.table.setflags(write=False)

    def sample_index(self, t: float) -> int:
        """Sample k of time t, s (the nearest multiple of dt; as the controllers)."""
        return self._law.sample_index(t)

    def at(self, k: int) -> np.ndarray:
        """The outputs of sample k ≥ 0, shape (len(REFERENCE_OUTPUTS),): row min(k, n) of :attr:`table`."""
        if k < 0:
            raise ValueError(f"k: sample index must be >= 0, got {k}")
        return self.table[min(int(k), self.n_steps)]

    def at_time(self, t: float, lead_samples: int = 0) -> np.ndarray:
        """The outputs at time t, s, led by `lead_samples` ≥ 0: :meth:`at` of :meth:`sample_index` + lead."""
        if isinstance(lead_samples, bool) or not isinstance(lead_samples, (int, np.integer)) \
                or not 0 <= lead_samples <= MAX_LEAD_SAMPLES:
            raise ValueError(f"lead_samples: an integer in 0..{MAX_LEAD_SAMPLES}, got {lead_samples!r}")
        return self.at(self.sample_index(t) + int(lead_samples))
