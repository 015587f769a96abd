"""Geometry of the slew: inverse kinematics of the undeformed arm, distance from the line."""

from __future__ import annotations

import math

import numpy as np

from ..parameters import JOINT2_PAIR, ArmParameters
from .io import TrajectoryError


def inverse_kinematics(params: ArmParameters, point, elbow: int = 1) -> tuple[float, float]:
    """Joint angles (rad) of the undeformed arm with its tip at `point` (m).

    Parameters
    ----------
    params : ArmParameters
    point : array_like, shape (2,)
        Tip position, m.
    elbow : {1, -1}
        Sign of the elbow angle q2.

    Returns
    -------
    q1, q2 : float
        Shoulder angle and elbow angle (θ_7 − θ_6), rad.
    """
    l1 = params.length[: JOINT2_PAIR[1]].sum()
    l2 = params.length[JOINT2_PAIR[1]:].sum()
    x, y = float(point[0]), float(point[1])
    c2 = (x * x + y * y - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    if not -1.0 < c2 < 1.0:
        raise TrajectoryError(f"point {point} is outside the arm's reach ({abs(l1 - l2):.3f} to {l1 + l2:.3f} m)")
    q2 = elbow * math.acos(c2)
    q1 = math.atan2(y, x) - math.atan2(l2 * math.sin(q2), l1 + l2 * math.cos(q2))
    return q1, q2


def line_distance(params: ArmParameters, tip) -> np.ndarray:
    """Signed distance (m) of tip positions, shape (..., 2), from the straight line."""
    p0, p1 = params.line_start, params.line_end
    d = (p1 - p0) / np.linalg.norm(p1 - p0)
    normal = np.array([-d[1], d[0]])
    return (np.asarray(tip) - p0) @ normal

