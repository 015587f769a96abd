"""One trial of the learning: the tracking errors it measures and the library loop (no FMI) that runs it.

The errors are formed as the controller forms its own, from the encoders and strain gauges (eqs. 21-31),
never from the true states; :func:`simulate_trial` runs one slew of the arm, its sensors and a
controller with a feedforward correction, for the tests and quick studies; :class:`Safeguard` keeps the learning
from making the measured error worse on a plant its model mispredicts. The learning law itself is in
:mod:`flexarm.ilc`, which re-exports these names.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gain_schedule import as_trajectory, desired_states
from .learned_feedforward import IlcError
from .lqr_design import measurement_map
from .model import N


# -- measurements -------------------------------------------------------------------
def measured_angles(q, strain) -> np.ndarray:
    """The 11 reconstructed angles (eqs. 21-31), shape (n, 11), from encoder angles (n, 2) and gauge angles (n, 6)."""
    from .model import reconstruct_angles

    q, strain = np.asarray(q, dtype=float), np.asarray(strain, dtype=float)
    basis = np.array([reconstruct_angles(e[:2], e[2:]) for e in np.eye(8)])  # linear map, (8, 11)
    return np.hstack([q, strain]) @ basis


def desired_angles(trajectory, n_samples: int) -> np.ndarray:
    """The reconstruction of the desired state at samples 0..n_samples, shape (n_samples + 1, 11): the final state
    after the slew (as the controller compares)."""
    traj = as_trajectory(trajectory)
    z = desired_states(traj)
    idx = np.minimum(np.arange(n_samples + 1), traj.n_samples)
    return z[idx] @ measurement_map()[:N].T


def measured_errors(q, strain, trajectory) -> np.ndarray:
    """The learning's error e = desired − measured reconstructed angles at samples 1..N, shape (N, 11), rad.

    Parameters
    ----------
    q : array_like, shape (N + 1, 2)
        Encoder angles q1, q2 at samples 0..N (the sensors' ``q1_m``, ``q2_m``), rad.
    strain : array_like, shape (N + 1, 6)
        Strain-gauge angles (``eps1_m`` .. ``eps6_m``), rad.
    trajectory : TrajectoryResult or path-like
    """
    y = measured_angles(q, strain)
    if not np.isfinite(y).all():
        raise IlcError("measurements: contain non-finite values (an unbounded or failed trial teaches nothing)")
    return (desired_angles(trajectory, len(y) - 1) - y)[1:]


def feedforward_over(trajectory, n_samples: int) -> np.ndarray:
    """The trajectory's feedforward over n_samples samples (zero after the slew), shape (n_samples, 2), N·m."""
    traj = as_trajectory(trajectory)
    out = np.zeros((n_samples, 2))
    m = min(n_samples, traj.n_samples)
    out[:m] = traj.tau[:m]
    return out


# -- the library loop (no FMI): for the tests and quick studies ------------------------
def simulate_trial(controller, n_steps: int, payload_mass: float = 0.275, noise: bool = True, seed: int = 1,
                   substeps: int | None = None) -> dict:
    """One trial of the library plant and sensors under `controller`, started at rest on the trajectory.

    Parameters
    ----------
    controller : flexarm.control.TrackingController
        With its ``feedforward_correction`` (the trial's u_j).
    n_steps : int
        1 ms samples to run.
    payload_mass : float
        Tip payload of the plant, kg (the controller does not know it).
    noise : bool
        Sensor noise (the paper's uniform noise), seeded with `seed`.

    Returns
    -------
    dict
        ``q`` (n + 1, 2) and ``strain`` (n + 1, 6): the measured encoder and gauge angles, rad (what the
        learning sees); ``states`` (n + 1, 22) the true states and ``torques`` (n, 2) N·m (for the metrics).
    """
    from .integrator import DEFAULT_SUBSTEPS, PlantSimulator
    from .model import ArmModel
    from .parameters import load_parameters
    from .sensors import ENCODERS, STRAIN_GAUGES, SensorBank, SensorSettings, true_signals_from_state

    model = ArmModel(load_parameters(payload_mass=payload_mass))
    settings = SensorSettings.from_toml().replace(noise_enabled=bool(noise), noise_seed=int(seed))
    bank = SensorBank(settings, model.params, controller.dt)
    plant = PlantSimulator(model, controller.z[0], substeps=substeps or DEFAULT_SUBSTEPS)
    meas, states, torques = [], [plant.z.copy()], []
    for k in range(int(n_steps) + 1):
        z = plant.z
        m = bank.measure(true_signals_from_state(model, z, np.zeros(2)))
        meas.append(m)
        if k == n_steps:
            break
        tau = controller.torque_from_measurements(k, m[:10])
        plant.step(tau, controller.dt)
        torques.append(tau)
        states.append(plant.z.copy())
    meas = np.array(meas)
    return {"q": meas[:, ENCODERS], "strain": meas[:, STRAIN_GAUGES], "states": np.array(states),
            "torques": np.array(torques)}


# -- the safeguard --------------------------------------------------------------------
@dataclass(frozen=True)
class Safeguard:
    """A trial-wise safeguard on the learning: it keeps only what lowers the measured error.

    The norm-optimal update falls monotonically on its model; on a plant the model mispredicts (a model error it
    cannot see) its step may raise the error instead, and the iteration then settles at a worse point than no
    correction. With the safeguard, the next update always starts from the trial with the lowest measured error
    norm ‖e‖₂ so far (its correction and its errors), and after each trial:

    * a new lowest: that trial becomes the start, and the step grows back (doubles, up to 1);
    * anything else: the start stays, and the step halves.

    The next correction is ``u_base + step · (update(u_base, e_base) − u_base)``, a convex combination of two
    corrections within the torque limits, so within them too. Where the learning keeps helping every trial is a new
    lowest and the law runs unchanged; where it does not, the corrections shrink back to the best one measured.
    The price: at the noise floor the step shrinks too (the learning stops learning noise, and stops).

    Attributes
    ----------
    base_trial : int
        The trial with the lowest measured error norm: the next update's start.
    lowest_norm : float
        Its norm, rad.
    step : float
        The fraction of the update taken, in (0, 1].
    """

    base_trial: int
    lowest_norm: float
    step: float = 1.0

    def after(self, trial: int, norm: float) -> tuple[Safeguard, bool]:
        """The state after `trial` measured error norm `norm` (rad), and whether it is the new lowest."""
        if norm < self.lowest_norm:
            return Safeguard(trial, norm, min(1.0, 2.0 * self.step)), True
        return Safeguard(self.base_trial, self.lowest_norm, 0.5 * self.step), False

    def next_correction(self, base_correction, proposal) -> np.ndarray:
        """``base + step · (proposal − base)``, shape (N, 2), N·m."""
        base = np.asarray(base_correction, dtype=float)
        return base + self.step * (np.asarray(proposal, dtype=float) - base)

    def as_dict(self) -> dict:
        return {"base_trial": self.base_trial, "lowest_norm_rad": self.lowest_norm, "step": self.step}
