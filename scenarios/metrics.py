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


#: A run ends with a warning when a joint's torque is at or beyond its motor's peak torque (the plant's
#: ``motors.peak_torque_Nm``) on more than this fraction of its samples. The minimum-time feedforward rides
#: ``torque_limit_fraction`` (80 %) of the peak, so a run tracking it never reaches the peak; a controller
#: that clips (the LQG) or asks for more (the LQR, which does not clip) does.
SATURATION_WARN_FRACTION = 0.02


def saturation_warnings(tau, limits, fraction: float = SATURATION_WARN_FRACTION) -> list[str]:
    """Warnings for joints whose torque is at or beyond its limit on more than `fraction` of the samples.

    Parameters
    ----------
    tau : ndarray, shape (n, 2)
        The torques applied to the plant, N·m.
    limits : sequence of 2 floats
        Each motor's peak torque, N·m.
    fraction : float
        The share of samples (0..1) above which a joint warns.

    Returns
    -------
    list of str
        One sentence per joint that saturates that often (empty: none).
    """
    tau = np.abs(np.asarray(tau, dtype=float))
    limits = np.asarray(limits, dtype=float)
    n = len(tau)
    out = []
    for j in range(tau.shape[1] if tau.ndim == 2 else 0):
        k = int(np.count_nonzero(tau[:, j] >= limits[j] * (1.0 - 1e-9)))
        if n and k / n > fraction:
            out.append(f"torque saturation: tau{j + 1} at or beyond its motor's limit ({limits[j]:g} N·m) on {k} "
                       f"of {n} samples ({100.0 * k / n:.1f} % > {100.0 * fraction:g} %): figures of a saturated loop")
    return out


def velocity_errors(result, traj) -> np.ndarray:
    """The 11 element rates' errors of a run against the trajectory, deg/s, shape (n, 11).

    Parameters
    ----------
    result : CaseResult
        A run that recorded ``plant.omega1`` .. ``plant.omega11`` (rad/s) at 1 ms samples from t = 0.
    traj : Trajectory
        The desired slew; past its end the desired rates are zero (the arm holds the end point).
    """
    s = result.series
    omega = np.column_stack([s[f"plant.omega{i}"] for i in range(1, 12)])
    n = len(omega)
    idx = np.minimum(np.arange(n), traj.n_samples)
    desired = traj.omega[idx] * (np.arange(n) < traj.n_samples + 1)[:, None]
    return np.degrees(omega - desired)
