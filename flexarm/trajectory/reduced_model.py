"""The reduced chain models and the Radau collocation scheme the minimum-time NLP is built from.

:class:`ReducedModel` groups the 11 element angles into fewer (the rigid two-link model, or the flexible model with
the stiff brackets merged), :func:`_residual_function` is its equations of motion as a CasADi function of the
coefficients (so payload and constants are NLP parameters), and :func:`_radau` / :func:`_lagrange_basis` are the
collocation points, derivative matrix and interpolation basis (:mod:`flexarm.trajectory.problem` uses all of them).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..model import ArmModel
from ..parameters import JOINT2_PAIR, N_ELEMENTS, ArmParameters

#: Element groups (0-based element -> reduced angle) of the two optimiser models.
RIGID_GROUPS = (0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1)
FLEX_GROUPS = (0, 0, 1, 2, 3, 3, 4, 4, 5, 6, 7)  # brackets merged: θ2=θ1, θ6=θ5, θ8=θ7


# -- reduced models -------------------------------------------------------------
@dataclass(frozen=True)
class ReducedModel:
    """Eq. 1 for the elements merged into groups (θ = Tθ_r).

    Attributes
    ----------
    groups : tuple of int, length 11
        Reduced angle of each element.
    T : ndarray, shape (11, n)
        0/1 grouping matrix.
    mass_coefficients : ndarray, shape (n, n)
        TᵀM_jk T, kg·m².
    stiffness : ndarray, shape (n, n)
        TᵀK T, N·m/rad (springs inside a group drop out).
    input_matrix : ndarray, shape (n, 2)
        TᵀB̄.
    """

    groups: tuple
    T: np.ndarray
    mass_coefficients: np.ndarray
    stiffness: np.ndarray
    input_matrix: np.ndarray
    length: np.ndarray
    joint_rows: np.ndarray = field(default_factory=lambda: np.zeros((2, 1)))

    @classmethod
    def build(cls, params: ArmParameters, groups) -> ReducedModel:
        groups = tuple(int(g) for g in groups)
        n = max(groups) + 1
        T = np.zeros((N_ELEMENTS, n))
        T[np.arange(N_ELEMENTS), groups] = 1.0
        full = ArmModel(params)
        sel = np.zeros((2, N_ELEMENTS))  # joint angles q = S θ
        sel[0, 0] = 1.0
        sel[1, JOINT2_PAIR[1]], sel[1, JOINT2_PAIR[0]] = 1.0, -1.0
        return cls(groups, T, T.T @ full.mass_coefficients @ T, T.T @ full.stiffness @ T,
                   T.T @ full.input_matrix(), params.length.copy(), sel @ T)

    @property
    def n(self) -> int:
        return self.T.shape[1]

    def reduce(self, theta_full) -> np.ndarray:
        """Reduced angles (the first element of each group), shape (..., n)."""
        first = [self.groups.index(g) for g in range(self.n)]
        return np.asarray(theta_full)[..., first]

    def coefficient_vector(self) -> np.ndarray:
        """Model constants in the order of :func:`_residual_function`'s `coeff` input."""
        pattern = self.stiffness_pattern()
        return np.concatenate([self.mass_coefficients.ravel(), self.stiffness[pattern], self.input_matrix.ravel()])

    def stiffness_pattern(self) -> np.ndarray:
        """Off-diagonal entries of TᵀKT that are springs (structure of the problem)."""
        pattern = self.stiffness != 0.0
        np.fill_diagonal(pattern, False)
        return pattern


def _residual_function(n: int, pattern: np.ndarray) -> ca.Function:
    """CasADi f(θ, ω, a, τ, coeff) = M(θ)a + C(θ)ω² + K(θ)1 − B̄τ, N·m (SX).

    The constants (M_jk, spring stiffnesses, B̄) are an input so one NLP serves
    every parameter set with the same structure (payload changes, sensitivity).
    """
    th, om, a = ca.SX.sym("th", n), ca.SX.sym("om", n), ca.SX.sym("a", n)
    tau = ca.SX.sym("tau", 2)
    n_k = int(pattern.sum())
    coeff = ca.SX.sym("coeff", n * n + n_k + 2 * n)
    Mc = ca.reshape(coeff[: n * n], n, n).T  # row-major as numpy's ravel
    kvals = {}
    for idx, (i, j) in enumerate(zip(*np.nonzero(pattern))):
        kvals[(int(i), int(j))] = coeff[n * n + idx]
    B = ca.reshape(coeff[n * n + n_k:], 2, n).T
    terms = []
    for i in range(n):
        t = -(B[i, 0] * tau[0] + B[i, 1] * tau[1]) + Mc[i, i] * a[i]
        for j in range(n):
            if i == j:
                continue
            dth = th[i] - th[j]
            c, sn = ca.cos(dth), ca.sin(dth)
            t += Mc[i, j] * (c * a[j] + sn * om[j] ** 2)
            if (i, j) in kvals:
                t += -kvals[(i, j)] * sn
        terms.append(t)
    return ca.Function("dyn", [th, om, a, tau, coeff], [ca.vertcat(*terms)])


# -- collocation ----------------------------------------------------------------
def _radau(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Radau IIA points (with 0 first) and derivative matrix D[r, j] = L_r'(τ_j), j ≥ 1."""
    tau = np.array([0.0] + ca.collocation_points(degree, "radau"))
    D = np.zeros((degree + 1, degree))
    for r in range(degree + 1):
        coeff = np.poly1d([1.0])
        for m in range(degree + 1):
            if m != r:
                coeff *= np.poly1d([1.0, -tau[m]]) / (tau[r] - tau[m])
        der = np.polyder(coeff)
        D[r] = der(tau[1:])
    return tau, D


def collocation_times(n_intervals: int, degree: int) -> np.ndarray:
    """The grid's points in normalised time s ∈ [0, 1], shape (1 + n_intervals·degree,): 0, then each interval's
    Radau IIA points (k + τ_j)/N, j = 1..degree (the last of an interval is the next one's node)."""
    tau, _ = _radau(degree)
    n = int(n_intervals)
    return np.concatenate([[0.0], (np.repeat(np.arange(n), degree) + np.tile(tau[1:], n)) / n])


def _lagrange_basis(tau: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Lagrange basis on points tau evaluated at x: shape (len(x), len(tau))."""
    out = np.ones((len(x), len(tau)))
    for r in range(len(tau)):
        for m in range(len(tau)):
            if m != r:
                out[:, r] *= (x - tau[m]) / (tau[r] - tau[m])
    return out
