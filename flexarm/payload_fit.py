"""The tip payload identified from one trial's measurements: output-error least squares on the joint encoders, no FMI.

A robot that does not know what it carries runs its slew once and measures. The torques it applied are known exactly
(they are its own outputs), and the plant starts at rest, so the model of the arm with payload m, driven open loop by
those torques, reproduces the measured joint angles when m is right (up to the encoders' noise, ±0.1° uniform, and
whatever else the model gets wrong). :func:`identify_payload` finds the m that minimises the rms difference::

    J(m) = sqrt( mean_k |q_model(m, k) − q_measured(k)|² ),   k = 0 .. N

over [0, 2] kg by bounded Brent search (scipy.optimize.minimize_scalar; about 25 replays of 0.17 CPU-s each for a
3 s trial). The joints respond to the payload through the inertia they move (the rigid-body modes are free:
an error in m grows in the joint angles as the slew goes on), so J has one minimum on that range. The payload-bank
estimator of controller_lqg identifies on line from the same sensors (:mod:`flexarm.lqg_bank`); this is its offline
counterpart, between trials.

The measurement of sample k is taken as that of the state at t_k (a Gauss-Seidel master: the sensors read the plant
after its step); the caller checks the stepping.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The payloads searched, kg (the motors' limits are reached above about 0.35 kg; 2 kg is far beyond).
PAYLOAD_BOUNDS = (0.0, 2.0)
#: Brent's tolerance on the payload, kg (0.1 g: far below what the encoders resolve).
PAYLOAD_TOLERANCE = 1e-4


class IdentificationError(ValueError):
    """Measurements that cannot identify a payload (shapes, non-finite values) or a search that ends at a bound."""


@dataclass(frozen=True)
class PayloadEstimate:
    """The identified payload.

    Attributes
    ----------
    mass : float
        kg.
    rms_residual_deg : float
        J at the estimate, deg (the encoders' noise alone gives about 0.058°, ±0.1° uniform).
    evaluations : int
        Open-loop replays the search took.
    """

    mass: float
    rms_residual_deg: float
    evaluations: int

    def as_dict(self) -> dict:
        return {"payload_mass_kg": self.mass, "rms_residual_deg": self.rms_residual_deg,
                "replays": self.evaluations, "method": "output-error least squares on the joint encoders, "
                "bounded Brent search (flexarm.payload_fit)"}


def replayed_joint_angles(payload_mass: float, z0, torques, params=None) -> np.ndarray:
    """Joint angles (rad, shape (N + 1, 2)) of the arm with `payload_mass` (kg) from state `z0` (shape (22,)) under
    `torques` (N·m, shape (N, 2), each held over one 1 ms sample), open loop."""
    from .integrator import simulate
    from .model import ArmModel, joint_angles
    from .parameters import load_parameters

    model = ArmModel(load_parameters(payload_mass=payload_mass) if params is None
                     else params.with_payload(payload_mass))
    z = simulate(model, z0, torques)
    return np.array([joint_angles(x) for x in z[:, : z.shape[1] // 2]])


def identify_payload(measured_q, torques, z0, bounds=PAYLOAD_BOUNDS, params=None) -> PayloadEstimate:
    """The payload whose open-loop replay of `torques` best matches the measured joint angles.

    Parameters
    ----------
    measured_q : array_like, shape (N + 1, 2)
        Encoder angles q1, q2 at samples 0 .. N, rad.
    torques : array_like, shape (N, 2)
        The torques applied over samples 0 .. N − 1, N·m.
    z0 : array_like, shape (22,)
        The state at sample 0 (the run's start: at rest).
    bounds : (float, float)
        Payloads searched, kg.
    params : ArmParameters, optional
        The model's arm (default the committed one); its payload is what is searched.

    Raises
    ------
    IdentificationError
        Inconsistent shapes, non-finite values, or a minimum at a bound of the search (not identified).
    """
    from scipy.optimize import minimize_scalar

    q = np.asarray(measured_q, dtype=float)
    tau = np.asarray(torques, dtype=float)
    if q.ndim != 2 or q.shape[1] != 2 or tau.shape != (len(q) - 1, 2) or len(tau) < 1:
        raise IdentificationError(f"measured_q (N + 1, 2) and torques (N, 2), got {q.shape} and {tau.shape}")
    if not (np.isfinite(q).all() and np.isfinite(tau).all()):
        raise IdentificationError("measured_q and torques must be finite")
    count = [0]

    def cost(m: float) -> float:
        count[0] += 1
        return float(np.sqrt(np.mean((replayed_joint_angles(m, z0, tau, params) - q) ** 2)))

    lo, hi = map(float, bounds)
    res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": PAYLOAD_TOLERANCE})
    mass = float(res.x)
    if min(mass - lo, hi - mass) < 10 * PAYLOAD_TOLERANCE:
        raise IdentificationError(f"payload: the best fit is at the bound of [{lo:g}, {hi:g}] kg ({mass:.4f} kg, rms "
                                  f"residual {np.degrees(res.fun):.3f}°): the trial does not identify it")
    return PayloadEstimate(mass, float(np.degrees(res.fun)), count[0])
