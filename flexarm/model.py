"""The paper's 11-element finite-element arm (eq. 1, 4-8) as plain functions.

State convention: z = (θ_1..θ_11, θ̇_1..θ̇_11), absolute angles in the
horizontal plane (rad, rad/s); torques τ = (τ_1, τ_2) in N·m.

Equation of motion (eq. 1)::

    M(θ) θ̈ + C(θ) θ̇² + K(θ) 1 = B̄ τ
    M = [M_jk cos(θ_j − θ_k)],  C = [M_jk sin(θ_j − θ_k)],  K(θ) = [−K_jk sin(θ_j − θ_k)]

with B̄ = [e_1, e_7 − e_6] (joint-2 torque acts on element 7 with its
reaction on element 6).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .parameters import (
    JOINT2_PAIR,
    LINK1_TIP_ELEMENT,
    LINK2_TIP_ELEMENT,
    N_ELEMENTS,
    STRAIN_GAUGE_ELEMENTS,
    ArmParameters,
    load_parameters,
)
from .signals import names as signal_names


class _Kernels:
    """:mod:`flexarm._kernels`, imported on first use: importing it loads (and may compile with) Numba, which
    a process that only reads parameters, trajectories or gains (a run of the native FMUs) never needs."""

    def __getattr__(self, name):
        from . import _kernels

        globals()["kern"] = _kernels
        return getattr(_kernels, name)


def numpy_kernels():
    """A private copy of :mod:`flexarm._kernels` on its NumPy path: the same mathematics, no Numba.

    For a few evaluations in a process that has not loaded Numba (the start-up check of a run's sampled loop,
    :mod:`scenarios.analysis.stability`, costs a third of a second more with it), and for symbolic arrays (CasADi,
    :mod:`fmu_build.native_codegen`). Loaded once per process.
    """
    global _NUMPY_KERNELS
    if _NUMPY_KERNELS is None:
        import importlib.util
        import os
        import sys

        saved = os.environ.get("FLEXARM_NO_NUMBA")
        os.environ["FLEXARM_NO_NUMBA"] = "1"
        try:
            # A package of its own, searched in this folder: the copy's relative imports (the dynamics and
            # integrator kernels that _kernels gathers) load NumPy copies under it, not the Numba modules.
            name = f"{__name__.rpartition('.')[0]}._kernels_numpy"
            spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("_kernels.py"),
                                                          submodule_search_locations=[str(Path(__file__).parent)])
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            spec.loader.exec_module(module)
        finally:
            if saved is None:
                del os.environ["FLEXARM_NO_NUMBA"]
            else:
                os.environ["FLEXARM_NO_NUMBA"] = saved
        _NUMPY_KERNELS = module
    return _NUMPY_KERNELS


_NUMPY_KERNELS = None
kern = _Kernels()
N = N_ELEMENTS
N_STATE = 2 * N_ELEMENTS
#: The accelerometer-carrying link ends, in ascending order (chain_kinematics needs that).
_LINK_TIPS = np.array([LINK1_TIP_ELEMENT, LINK2_TIP_ELEMENT], dtype=np.int64)

#: What :meth:`ArmModel.observables` returns, in order: the plant FMU's outputs in the signal catalogue.
OBSERVABLE_NAMES = signal_names("plant", "output", indices=False)  # the sample indices are the FMU's, not physics


class ArmModel:
    """Dynamics and kinematics of one parameter set.

    Parameters
    ----------
    params : ArmParameters, optional
        Defaults to the committed Sandia arm (no payload).
    damping_ratio : float
        Modal structural damping ratio ζ ≥ 0 of every flexible mode (default 0: the paper's
        undamped model); see :func:`modal_damping_matrix`.
    kernels : module, optional
        The numerical kernels: default :mod:`flexarm._kernels` (Numba when installed); :func:`numpy_kernels`
        for a few evaluations without loading Numba.

    Notes
    -----
    The constant coefficients M_jk and K_jk are computed once here
    ("it only requires one evaluation of the mass and stiffness elements").
    """

    def __init__(self, params: ArmParameters | None = None, damping_ratio: float = 0.0, kernels=None):
        self._kernels = kernels
        self.params = params if params is not None else load_parameters()
        self.mass_coefficients = self.params.mass_coefficients()
        self.stiffness = self.params.stiffness_matrix()
        self.length = self.params.length.copy()
        self.j2p, self.j2d = JOINT2_PAIR
        ratio = float(damping_ratio)
        if not (ratio >= 0.0 and np.isfinite(ratio)):
            raise ValueError(f"damping_ratio: must be a finite modal damping ratio >= 0, got {damping_ratio!r}")
        self.damping_ratio = ratio
        self.damping = np.zeros((N, N))
        if ratio > 0.0:
            self.damping = modal_damping_matrix(self, ratio)

    # -- dynamics ------------------------------------------------------------

    @property
    def _kern(self):
        return self._kernels if self._kernels is not None else kern
    def mass_matrix(self, theta) -> np.ndarray:
        """M(θ) = [M_jk cos(θ_j − θ_k)], kg·m², shape (11, 11)."""
        cosd, _ = self._kern.trig_differences(np.asarray(theta, dtype=float))
        return self.mass_coefficients * cosd

    def centrifugal_matrix(self, theta) -> np.ndarray:
        """C(θ) = [M_jk sin(θ_j − θ_k)], kg·m², shape (11, 11)."""
        _, sind = self._kern.trig_differences(np.asarray(theta, dtype=float))
        return self.mass_coefficients * sind

    def spring_torques(self, theta) -> np.ndarray:
        """K(θ)·1: generalised spring forces ∂V/∂θ, N·m, shape (11,)."""
        _, sind = self._kern.trig_differences(np.asarray(theta, dtype=float))
        return -(self.stiffness * sind).sum(axis=1)

    def input_matrix(self) -> np.ndarray:
        """B̄ = [e_1, e_7 − e_6], shape (11, 2)."""
        b = np.zeros((N, 2))
        b[0, 0] = 1.0
        b[self.j2d, 1] = 1.0
        b[self.j2p, 1] = -1.0
        return b

    def acceleration(self, theta, omega, tau) -> np.ndarray:
        """θ̈ (rad/s²), shape (11,), eq. 5."""
        return self._kern.acceleration(_f(theta), _f(omega), _f(tau), self.mass_coefficients, self.stiffness,
                                       self.j2p, self.j2d, self.damping)

    def state_derivative(self, z, tau) -> np.ndarray:
        """ż = f(z) + g(z)τ, shape (22,), eq. 7."""
        return self._kern.state_derivative(_f(z), _f(tau), self.mass_coefficients, self.stiffness, self.j2p,
                                           self.j2d, self.damping)

    def drift_and_input(self, z) -> tuple[np.ndarray, np.ndarray]:
        """f(z), shape (22,), and g(z), shape (22, 2), of eq. 7."""
        z = _f(z)
        f = self.state_derivative(z, np.zeros(2))
        g = np.zeros((N_STATE, 2))
        g[N:] = np.linalg.solve(self.mass_matrix(z[:N]), self.input_matrix())
        return f, g

    def jacobian(self, z, tau=(0.0, 0.0)) -> np.ndarray:
        """Exact ∂ż/∂z at (z, τ), shape (22, 22)."""
        z = _f(z)
        a_th, a_om, _ = self._kern.acceleration_jacobian(z[:N], z[N:], _f(tau), self.mass_coefficients,
                                                         self.stiffness, self.j2p, self.j2d, self.damping)
        jac = np.zeros((N_STATE, N_STATE))
        jac[:N, N:] = np.eye(N)
        jac[N:, :N] = a_th
        jac[N:, N:] = a_om
        return jac

    def linearize(self, z_bar, tau_bar=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """A = ∂(f + gτ̄)/∂z and B = g(z̄) at an operating point (eqs. 11-14).

        Parameters
        ----------
        z_bar : array_like, shape (22,)
            Operating point.
        tau_bar : array_like, shape (2,)
            Torque at the operating point. The paper linearises f only
            (τ̄ = 0, the default); passing the feedforward torque adds the
            term ∂(g(z)τ̄)/∂z, the exact linearisation about a moving point.

        Returns
        -------
        A : ndarray, shape (22, 22)
        B : ndarray, shape (22, 2)
        """
        _, g = self.drift_and_input(z_bar)
        return self.jacobian(z_bar, tau_bar), g

    # -- energies --------------------------------------------------------------
    def kinetic_energy(self, z) -> float:
        """T = ½ θ̇ᵀ M(θ) θ̇, J."""
        z = _f(z)
        om = z[N:]
        return 0.5 * float(om @ self.mass_matrix(z[:N]) @ om)

    def strain_energy(self, theta) -> float:
        """V = Σ_springs k (1 − cos(θ_i − θ_j)), J."""
        cosd, _ = self._kern.trig_differences(_f(theta))
        return 0.5 * float(np.sum(-self.stiffness * (1.0 - cosd)))

    def total_energy(self, z) -> float:
        """T + V, J."""
        z = _f(z)
        return self.kinetic_energy(z) + self.strain_energy(z[:N])

    def input_power(self, z, tau) -> float:
        """Power delivered by the motors, τ_1 q̇_1 + τ_2 q̇_2, W."""
        z = _f(z)
        return float(np.dot(_f(tau), joint_velocities(z[N:])))

    # -- kinematics ------------------------------------------------------------
    def hinge_positions(self, theta) -> np.ndarray:
        """Positions of the origin and every element's distal hinge, m, shape (12, 2)."""
        theta = _f(theta)
        pts = np.zeros((N + 1, 2))
        pts[1:, 0] = np.cumsum(self.length * np.cos(theta))
        pts[1:, 1] = np.cumsum(self.length * np.sin(theta))
        return pts

    def point_position(self, theta, element: int) -> np.ndarray:
        """Position of element `element`'s (0-based) distal end, m, shape (2,)."""
        theta = _f(theta)
        if not 0 <= element < N:
            raise ValueError(f"element: a 0-based element index in [0, {N - 1}], got {element!r}")
        # The same summation as link_tip_kinematics, so both give the same bits.
        zeros = np.zeros(N)
        ends = np.array([element], dtype=np.int64)
        return self._kern.chain_kinematics(theta, zeros, zeros, self.length, ends)[0, :2]

    def tip_position(self, theta) -> np.ndarray:
        """Tip of link 2 (x, y), m."""
        return self.point_position(theta, LINK2_TIP_ELEMENT)

    def tip_jacobian(self, theta) -> np.ndarray:
        """∂(tip x, y)/∂θ at the element angles `theta`, shape (2, 11), m/rad: the map :meth:`tip_velocity`
        applies to the element rates (elements past the link-2 tip do not move it)."""
        th = _f(theta)[:N]
        ell = np.where(np.arange(N) <= LINK2_TIP_ELEMENT, self.length[:N], 0.0)
        return np.vstack([-ell * np.sin(th), ell * np.cos(th)])

    def link1_tip_position(self, theta) -> np.ndarray:
        """Tip of link 1 (x, y), m (the link-1 accelerometer)."""
        return self.point_position(theta, LINK1_TIP_ELEMENT)

    def point_velocity(self, theta, omega, element: int) -> np.ndarray:
        """Velocity of element `element`'s distal end, m/s, shape (2,)."""
        l = self.length[: element + 1]
        th, om = _f(theta)[: element + 1], _f(omega)[: element + 1]
        return np.array([-np.sum(l * np.sin(th) * om), np.sum(l * np.cos(th) * om)])

    def tip_velocity(self, theta, omega) -> np.ndarray:
        """Velocity of the link-2 tip, m/s."""
        return self.point_velocity(theta, omega, LINK2_TIP_ELEMENT)

    def point_acceleration(self, theta, omega, alpha, element: int) -> np.ndarray:
        """Acceleration of element `element`'s distal end, m/s², shape (2,)."""
        l = self.length[: element + 1]
        th, om, al = _f(theta)[: element + 1], _f(omega)[: element + 1], _f(alpha)[: element + 1]
        c, s = np.cos(th), np.sin(th)
        return np.array([np.sum(l * (-s * al - c * om**2)), np.sum(l * (c * al - s * om**2))])

    def link_tip_accelerations(self, theta, omega, tau) -> np.ndarray:
        """Accelerations of the link-1 and link-2 tips, m/s², shape (2, 2) rows (x, y)."""
        return self.link_tip_kinematics(theta, omega, tau)[:, 2:4]

    def link_tip_kinematics(self, theta, omega, tau) -> np.ndarray:
        """Link-1 and link-2 tips: shape (2, 5) rows (x, y, ẍ, ÿ, a_n), m and m/s² (a_n: the accelerometer).

        One compiled pass over the chain (the plant FMU needs these every 1 ms step).
        """
        theta, omega = _f(theta), _f(omega)
        alpha = self.acceleration(theta, omega, tau)
        return self._kern.chain_kinematics(theta, omega, alpha, self.length, _LINK_TIPS)

    def observables(self, z, tau) -> np.ndarray:
        """Everything a sensor or the plant FMU reads off state z with held torque tau, shape (40,).

        In :data:`OBSERVABLE_NAMES` order: θ (rad), θ̇ (rad/s), encoder angles q (rad),
        tachometer rates q̇ (rad/s), strain-gauge angles ε (rad), link-2 tip (m),
        link-1 and link-2 tip accelerations (m/s²), accelerometer signals (m/s²).
        Equal to the separate functions (:func:`joint_angles`, ..., :meth:`accelerometer_signals`).
        """
        z = _f(z)
        tips = self.link_tip_kinematics(z[:N], z[N:], tau)
        out = np.empty(len(OBSERVABLE_NAMES))
        out[: 2 * N] = z
        out[2 * N: 2 * N + 10] = _SENSOR_MAP @ z  # q, q̇, ε are differences of angles and rates
        out[2 * N + 10: 2 * N + 12] = tips[1, :2]
        out[2 * N + 12: 2 * N + 16] = tips[:, 2:4].ravel()
        out[2 * N + 16:] = tips[:, 4]
        return out

    def accelerometer_signals(self, theta, omega, tau, tip_accelerations=None) -> np.ndarray:
        """Tip accelerations normal to the link (the accelerometers' axis), m/s², shape (2,).

        The normal of link k is (−sin θ_p, cos θ_p) with p its last segment.
        Pass `tip_accelerations` (from :meth:`link_tip_accelerations`) when
        already computed, to avoid solving the dynamics twice.
        """
        if tip_accelerations is None:
            return self.link_tip_kinematics(theta, omega, tau)[:, 4].copy()
        acc = tip_accelerations
        theta = _f(theta)
        out = np.empty(2)
        for row, p in enumerate((LINK1_TIP_ELEMENT, LINK2_TIP_ELEMENT)):
            out[row] = -np.sin(theta[p]) * acc[row, 0] + np.cos(theta[p]) * acc[row, 1]
        return out


#: Joint angles (rad) at which the modal damping matrix is built: the calibration configuration.
DAMPING_CONFIGURATION = (0.0, np.pi / 2)


def modal_damping_matrix(model: ArmModel, ratio: float, q=DAMPING_CONFIGURATION) -> np.ndarray:
    """Damping matrix C_d (N·m·s/rad, shape (11, 11)) giving every flexible mode the ratio ζ.

    Built once at the undeformed configuration with joint angles `q` (rad):
    C_d = M Φ diag(2ζω_k) Φᵀ M over the nine flexible modes (Φ mass-normalised, ω_k rad/s), so
    mode k decays as exp(−ζω_k t) there. C_d θ̇ vanishes for the two rigid-body motions (all
    elements turning together; link 2 turning about the elbow), which are the same vectors at
    every configuration, so damping never resists the slew itself. The flexible modes barely
    depend on the configuration (paper; :mod:`flexarm.modes`), so ζ holds approximately elsewhere.
    """
    import scipy.linalg

    theta = rigid_configuration(*q)
    zero = np.zeros(N)
    mass = model.mass_matrix(theta)
    a_th, _, _ = kern.acceleration_jacobian(theta, zero, np.zeros(2), model.mass_coefficients, model.stiffness,
                                            model.j2p, model.j2d, np.zeros((N, N)))
    k_t = -mass @ a_th
    eigval, vec = scipy.linalg.eigh(0.5 * (k_t + k_t.T), mass)
    order = np.argsort(eigval)[2:]  # drop the two rigid-body modes (free joints)
    omega = np.sqrt(np.maximum(eigval[order], 0.0))
    mphi = mass @ vec[:, order]
    damping = mphi @ np.diag(2.0 * ratio * omega) @ mphi.T
    return 0.5 * (damping + damping.T)


# -- functions of the angles alone --------------------------------------------
def joint_angles(theta) -> np.ndarray:
    """Motor (encoder) angles q_1 = θ_1, q_2 = θ_7 − θ_6, rad, shape (2,)."""
    theta = _f(theta)
    return np.array([theta[0], theta[JOINT2_PAIR[1]] - theta[JOINT2_PAIR[0]]])


def joint_velocities(omega) -> np.ndarray:
    """Motor (tachometer) rates q̇_1, q̇_2, rad/s, shape (2,)."""
    return joint_angles(omega)


def strain_gauge_angles(theta) -> np.ndarray:
    """Each link segment's angle relative to its proximal neighbour (eqs. 23-31), rad, shape (6,).

    Order: ε_1,1 ε_1,2 ε_1,3 ε_2,1 ε_2,2 ε_2,3 (θ_3−θ_2, θ_4−θ_3, θ_5−θ_4, θ_9−θ_8, θ_10−θ_9, θ_11−θ_10).
    """
    theta = _f(theta)
    idx = np.array(STRAIN_GAUGE_ELEMENTS)
    return theta[idx] - theta[idx - 1]


def reconstruct_angles(q, strain) -> np.ndarray:
    """The 11 element angles from encoders and strain-gauge angles (eqs. 21-31), rad, shape (11,).

    The brackets are taken as rigid (θ_2 = θ_1, θ_6 = θ_5, θ_8 = θ_7).
    """
    q, e = _f(q), _f(strain)
    th = np.empty(N)
    th[0] = q[0]
    th[1] = th[0]
    th[2] = th[1] + e[0]
    th[3] = th[2] + e[1]
    th[4] = th[3] + e[2]
    th[5] = th[4]
    th[6] = th[5] + q[1]
    th[7] = th[6]
    th[8] = th[7] + e[3]
    th[9] = th[8] + e[4]
    th[10] = th[9] + e[5]
    return th


def rigid_configuration(q1: float, q2: float) -> np.ndarray:
    """Undeformed element angles for joint angles q1, q2 (rad), shape (11,)."""
    th = np.full(N, float(q1))
    th[JOINT2_PAIR[1]:] += float(q2)
    return th


def _f(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float)


def _sensor_map() -> np.ndarray:
    """The (10, 22) matrix taking z to (q1, q2, q̇1, q̇2, ε1..ε6) (differences: exact in floating point)."""
    m = np.zeros((10, 2 * N))
    m[0, 0] = 1.0
    m[1, JOINT2_PAIR[1]], m[1, JOINT2_PAIR[0]] = 1.0, -1.0
    m[2, N] = 1.0
    m[3, N + JOINT2_PAIR[1]], m[3, N + JOINT2_PAIR[0]] = 1.0, -1.0
    for row, e in enumerate(STRAIN_GAUGE_ELEMENTS):
        m[4 + row, e], m[4 + row, e - 1] = 1.0, -1.0
    return m


_SENSOR_MAP = _sensor_map()
