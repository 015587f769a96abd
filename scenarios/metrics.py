"""The paper's table metrics (section 5): peak torques and tracking errors over all 11 elements."""

from __future__ import annotations

import numpy as np

METRICS = ("peak_tau1", "peak_tau2", "peak_position_error", "peak_velocity_error",
           "rms_position_error", "rms_velocity_error")
UNITS = {"peak_tau1": "N·m", "peak_tau2": "N·m", "peak_position_error": "deg",
         "peak_velocity_error": "deg/s", "rms_position_error": "deg", "rms_velocity_error": "deg/s"}
LABELS = {"peak_tau1": "peak torque (1st joint), N-m", "peak_tau2": "peak torque (2nd joint), N-m",
          "peak_position_error": "peak position error, deg", "peak_velocity_error": "peak velocity error, deg/sec",
          "rms_position_error": "rms position error, deg", "rms_velocity_error": "rms velocity error, deg/sec"}


def table_metrics(tau, theta, omega, theta_desired, omega_desired) -> dict[str, float]:
    """Peak torques and peak/rms position and velocity errors.

    Parameters
    ----------
    tau : ndarray, shape (n, 2)
        Applied torques, N·m.
    theta, omega : ndarray, shape (n, 11)
        True simulated element angles (rad) and rates (rad/s).
    theta_desired, omega_desired : ndarray, shape (n, 11)
        The optimiser's desired states at the same samples.

    Returns
    -------
    dict
        Peaks are over all 11 elements and all samples; rms is the root mean
        square over all 11 elements and all samples (degrees, deg/s).
    """
    pos = np.degrees(np.asarray(theta) - np.asarray(theta_desired))
    vel = np.degrees(np.asarray(omega) - np.asarray(omega_desired))
    tau = np.asarray(tau)
    return {
        "peak_tau1": float(np.max(np.abs(tau[:, 0]))),
        "peak_tau2": float(np.max(np.abs(tau[:, 1]))),
        "peak_position_error": float(np.max(np.abs(pos))),
        "peak_velocity_error": float(np.max(np.abs(vel))),
        "rms_position_error": float(np.sqrt(np.mean(pos**2))),
        "rms_velocity_error": float(np.sqrt(np.mean(vel**2))),
    }
