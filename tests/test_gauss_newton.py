"""The Gauss-Legendre stage equations are solved to round-off (issue 24): the scheme's error is its own.

The kernel's simplified Newton iteration stops at GAUSS_TOL or where the corrections stop contracting; a loose
stop would leave an error floor that does not fall with the substep. Here the kernel's step is compared with the
same collocation equations iterated 200 times with no stopping test (NumPy, the exact same residual), on the
free arm with all nine flexible modes excited, at 32 and 256 substeps per ms.
"""

import numpy as np
import pytest

import flexarm._kernels as kern
from flexarm import ArmModel
from scenarios.reports.scheme_accuracy_parts import free_arm_state


def _fully_iterated_step(model, z, tau, h, iterations=200):
    """One 2-stage Gauss step: the collocation equations by simplified Newton, `iterations` times, no stop."""
    mc, kl, j2p, j2d, dmp = model.mass_coefficients, model.stiffness, model.j2p, model.j2d, model.damping
    a, a2, c = kern.GAUSS_A, kern.GAUSS_A2, kern.GAUSS_C
    n = z.size // 2
    theta, omega = z[:n], z[n:]
    mass, rhs, cosd, sind = kern.assemble(theta, omega, mc, kl)
    u = kern.input_forces(np.asarray(tau, float), n, j2p, j2d)
    acc = np.linalg.solve(mass, rhs + u - dmp @ omega)
    q, v = kern.tangent_matrices(mc, kl, cosd, sind, omega, acc)
    v = v - dmp
    w = np.block([[(mass if i == j else 0) - h * h * a2[i, j] * q - h * a[i, j] * v for j in range(2)]
                  for i in range(2)])
    k = np.concatenate([acc, acc])
    g = np.empty(2 * n)
    for _ in range(iterations):
        for i in range(2):
            th = theta + h * c[i] * omega + h * h * (a2[i, 0] * k[:n] + a2[i, 1] * k[n:])
            om = omega + h * (a[i, 0] * k[:n] + a[i, 1] * k[n:])
            m_i, s_i, _, _ = kern.assemble(th, om, mc, kl)
            g[i * n:(i + 1) * n] = m_i @ k[i * n:(i + 1) * n] - (s_i - dmp @ om + u)
        k = k - np.linalg.solve(w, g)
    b1, b2 = 0.5 * (1 - c[0]), 0.5 * (1 - c[1])
    return np.concatenate([theta + h * omega + h * h * (b1 * k[:n] + b2 * k[n:]), omega + 0.5 * h * (k[:n] + k[n:])])


@pytest.mark.parametrize("substeps", [32, 256])
def test_gauss_stage_equations_are_solved_to_round_off(substeps):
    model = ArmModel()
    z = free_arm_state(model)
    h = 1e-3 / substeps
    tau = (0.5, 0.2)
    for _ in range(8):
        z_kernel, iterations = kern.gauss_step(z, np.asarray(tau), h, model.mass_coefficients, model.stiffness,
                                               model.j2p, model.j2d, model.damping, kern.GAUSS_A, kern.GAUSS_A2,
                                               kern.GAUSS_C)
        z_full = _fully_iterated_step(model, z, tau, h)
        assert iterations < kern.GAUSS_MAX_ITER
        # the bracket elements' rates are of order 1 rad/s: 1e-8 rad/s is far below any scheme error
        assert np.abs(z_kernel - z_full).max() <= 1e-8
        z = z_kernel
    assert np.abs(z[11:]).max() > 0.1  # the modes are moving: the comparison is not between two rests
