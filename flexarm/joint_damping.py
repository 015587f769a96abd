"""How fast the arm can settle at the end of the slew with viscous joint damping (issue 32 item 4).

The paper's experiments reach "a vibrationless state" about 2 s after t_f. In the model the hold after the slew
(end point, zero feedforward, the last gain set) has a slow, lightly damped pole pair: the joint-1 servo mode,
a position gain of a few N·m/rad on the arm's inertia about joint 1. This module asks what viscous damping at the
joints (a torque −c·rate at each motor: θ̇1 at joint 1, the relative rate θ̇7 − θ̇6 at joint 2) would do to the
loop's slowest pole.

For a second-order mode J·s² + (k_d + c)·s + k_p the product of the two roots is k_p/J whatever c is, so
damping moves the pair onto the real axis and then splits it: the slowest root's decay rate is largest at
critical damping, where it equals the mode's natural frequency, and falls as 1/c beyond. The arm's loop behaves
the same way (:func:`best_joint_damping` searches c numerically on the full linearised loop). Decaying by e^-4
(to 1.8 %) takes 4/σ for a slowest decay rate σ (1/s); settling in 2 s needs σ ≥ 2 1/s.
"""

from __future__ import annotations

import numpy as np

#: Decay, in e-folds, that counts as settled (e^-4 = 1.8 % of the error left).
SETTLED_EFOLDS = 4.0


def joint_damping_matrix(n: int, c: float) -> np.ndarray:
    """Generalised damping (n × n) of a viscous torque −c·rate at both motors, N·m·s/rad.

    Joint 1 acts on θ̇1 (element 1's absolute rate), joint 2 on the relative rate θ̇7 − θ̇6 across the elbow.
    """
    D = np.zeros((n, n))
    D[0, 0] = c
    e = np.zeros(n)
    e[6], e[5] = 1.0, -1.0
    return D + c * np.outer(e, e)


def damped_closed_loop(A, B, G, mass, damping) -> np.ndarray:
    """The continuous closed loop Ȧ = (A − M⁻¹D on the rates) − B·G of a linearised arm.

    Parameters
    ----------
    A : ndarray, shape (2n, 2n)
        Linearised plant (angles, then rates).
    B : ndarray, shape (2n, m)
    G : ndarray, shape (m, 2n)
        State feedback u = −G x (the controller as it runs, e.g. :func:`flexarm.lqr_design.effective_gain`).
    mass : ndarray, shape (n, n)
        Mass matrix at the linearisation point, kg·m².
    damping : ndarray, shape (n, n)
        Generalised viscous damping added to the plant, N·m·s/rad.
    """
    n = mass.shape[0]
    Ad = np.array(A, dtype=float)
    Ad[n:, n:] -= np.linalg.solve(mass, damping)
    return Ad - np.asarray(B) @ np.asarray(G)


def slowest_decay_rate(a_cl) -> float:
    """The smallest −Re(λ) over the eigenvalues of a continuous closed loop, 1/s (negative: it grows)."""
    return float(-np.linalg.eigvals(a_cl).real.max())


def best_joint_damping(A, B, G, mass, c_max: float = 50.0, grid: int = 201) -> dict:
    """The viscous joint damping c in [0, c_max] that makes the loop's slowest pole decay fastest.

    A grid over c (N·m·s/rad at each joint), refined by a bounded scalar search around the grid's best.

    Returns
    -------
    dict
        ``c`` (N·m·s/rad), ``rate`` (the slowest decay rate there, 1/s), ``rate_undamped`` (at c = 0, 1/s) and
        ``pole_undamped`` (the slowest pole at c = 0, complex, 1/s).
    """
    from scipy.optimize import minimize_scalar

    n = mass.shape[0]

    def rate(c: float) -> float:
        return slowest_decay_rate(damped_closed_loop(A, B, G, mass, joint_damping_matrix(n, c)))

    cs = np.linspace(0.0, c_max, grid)
    rates = np.array([rate(c) for c in cs])
    i = int(np.argmax(rates))
    lo, hi = cs[max(i - 1, 0)], cs[min(i + 1, grid - 1)]
    if hi > lo:
        found = minimize_scalar(lambda c: -rate(c), bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
        c_best, r_best = (float(found.x), -float(found.fun)) if -found.fun >= rates[i] else (cs[i], rates[i])
    else:
        c_best, r_best = float(cs[i]), float(rates[i])
    ev = np.linalg.eigvals(damped_closed_loop(A, B, G, mass, np.zeros((n, n))))
    return {"c": float(c_best), "rate": float(r_best), "rate_undamped": float(-ev.real.max()),
            "pole_undamped": complex(ev[np.argmax(ev.real)])}


def hold_loop(model, gain, end_state):
    """(A, B, G, M) of the hold after the slew: the arm linearised at rest at `end_state` with zero torque, and the
    controller as it runs with gain `gain` (11 angles and the two tachometer rates fed back)."""
    from .lqr_design import effective_gain
    from .model import N

    z = np.asarray(end_state, dtype=float)
    A, B = model.linearize(np.r_[z[:N], np.zeros(N)], np.zeros(2))
    return A, B, effective_gain(gain), model.mass_matrix(z[:N])
