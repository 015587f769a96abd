"""Modal analysis of the arm about a configuration, with free (torque-controlled) joints."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from .model import ArmModel, N, rigid_configuration
from .parameters import JOINT2_PAIR

# Springs (0-based element pairs) that belong to each link's flexible part.
_LINK1_SPRINGS = {(1, 2), (2, 3), (3, 4)}
_LINK2_SPRINGS = {(7, 8), (8, 9), (9, 10)}


@dataclass
class Modes:
    """Result of :func:`modal_analysis`.

    Attributes
    ----------
    frequencies_hz : ndarray, shape (9,)
        Flexible natural frequencies, ascending (the two rigid-body modes of
        the free joints are dropped).
    shapes : ndarray, shape (11, 9)
        Mass-normalised mode shapes (columns), rad.
    link1_energy_fraction : ndarray, shape (9,)
        Share of each mode's strain energy stored in link 1's springs
        (the rest is link 2 and the brackets).
    link2_energy_fraction : ndarray, shape (9,)
    """

    frequencies_hz: np.ndarray
    shapes: np.ndarray
    link1_energy_fraction: np.ndarray
    link2_energy_fraction: np.ndarray

    def link_mode(self, link: int) -> int:
        """Index of the lowest mode whose strain energy sits mostly in `link` (1 or 2)."""
        frac = self.link1_energy_fraction if link == 1 else self.link2_energy_fraction
        candidates = np.flatnonzero(frac > 0.5)
        if candidates.size == 0:
            raise ValueError(f"no mode is dominated by link {link}")
        return int(candidates[0])

    def link_frequency(self, link: int) -> float:
        """Natural frequency (Hz) of the first mode dominated by `link`."""
        return float(self.frequencies_hz[self.link_mode(link)])


def modal_analysis(model: ArmModel, theta=None, q=(0.0, np.pi / 2)) -> Modes:
    """Natural frequencies and mode shapes about a configuration at rest.

    Parameters
    ----------
    model : ArmModel
    theta : array_like, shape (11,), optional
        Element angles, rad. Default: the undeformed arm at joint angles `q`.
    q : (float, float)
        Joint angles (rad) used when `theta` is not given.

    Notes
    -----
    Linearising eq. 1 at rest gives M(θ) ẍ + K_t x = 0 with the tangent
    stiffness K_t = −∂S/∂θ; both joints are free (no torque feedback), so two
    eigenvalues are zero and are dropped.
    """
    theta = rigid_configuration(*q) if theta is None else np.asarray(theta, dtype=float)
    z = np.concatenate([theta, np.zeros(N)])
    mass = model.mass_matrix(theta)
    a_th = model.jacobian(z)[N:, :N]
    k_t = -mass @ a_th
    k_t = 0.5 * (k_t + k_t.T)
    eigval, vec = scipy.linalg.eigh(k_t, mass)
    order = np.argsort(eigval)
    eigval, vec = eigval[order][2:], vec[:, order][:, 2:]
    freqs = np.sqrt(np.maximum(eigval, 0.0)) / (2 * np.pi)
    frac1 = np.zeros(len(freqs))
    frac2 = np.zeros(len(freqs))
    for m in range(len(freqs)):
        x = vec[:, m]
        energy = {}
        for (i, j), k in zip(model.params.spring_pairs, model.params.spring_stiffness):
            energy[(int(i), int(j))] = 0.5 * k * (x[i] - x[j]) ** 2
        total = sum(energy.values())
        frac1[m] = sum(e for p, e in energy.items() if p in _LINK1_SPRINGS) / total
        frac2[m] = sum(e for p, e in energy.items() if p in _LINK2_SPRINGS) / total
    return Modes(freqs, vec, frac1, frac2)


def rigid_joint_accelerations(model: ArmModel, q=(0.0, np.pi / 2)) -> np.ndarray:
    """Angular accelerations (rad/s²) at peak torque of the rigid arm at rest.

    Joint 1 with the elbow locked (the whole arm one rigid body about the
    shoulder), joint 2 with the shoulder locked (link 2 about the elbow).
    Returns shape (2,).
    """
    theta = rigid_configuration(*q)
    mass = model.mass_matrix(theta)
    whole = np.ones(N)
    distal = np.zeros(N)
    distal[JOINT2_PAIR[1]:] = 1.0
    inertia = np.array([whole @ mass @ whole, distal @ mass @ distal])
    return model.params.peak_torque / inertia
