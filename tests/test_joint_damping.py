"""Viscous joint damping and the slowest pole of the hold after the slew (flexarm.joint_damping)."""

from __future__ import annotations

import numpy as np
import pytest

from flexarm.joint_damping import best_joint_damping, damped_closed_loop, hold_loop, joint_damping_matrix


def _servo_toy(J=2.6, kp=2.0, kd=0.5):
    """Seven elements: element 1 a servo (inertia J, position gain kp, rate gain kd, no spring); elements 2-7 stiff,
    well-damped springs (1000 rad/s, ζ = 0.5), so the servo pair is the slowest."""
    n = 7
    mass = np.diag([J] + [1.0] * 6)
    stiff = np.diag([0.0] + [1e6] * 6)
    own = np.diag([0.0] + [1e3] * 6)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(mass, stiff), -np.linalg.solve(mass, own)]])
    B = np.zeros((2 * n, 1))
    B[n, 0] = 1.0 / J
    G = np.zeros((1, 2 * n))
    G[0, 0], G[0, n] = kp, kd
    return A, B, G, mass


def test_the_best_damping_of_a_servo_mode_is_critical_and_its_rate_the_natural_frequency():
    """J s^2 + (kd + c) s + kp: the slowest root decays fastest at critical damping, c = 2 sqrt(kp J) - kd, where
    its rate is sqrt(kp / J); the roots' product kp / J does not depend on c."""
    J, kp, kd = 2.6, 2.0, 0.5
    A, B, G, mass = _servo_toy(J, kp, kd)
    best = best_joint_damping(A, B, G, mass, c_max=20.0)
    assert best["c"] == pytest.approx(2 * np.sqrt(kp * J) - kd, rel=2e-3)  # the refine's tolerance on c: 1e-4
    assert best["rate"] == pytest.approx(np.sqrt(kp / J), rel=1e-4)  # flat at the optimum: rate error ~ (dc)^2
    assert best["rate_undamped"] == pytest.approx(kd / (2 * J), rel=1e-9)
    roots = np.linalg.eigvals(damped_closed_loop(A, B, G, mass, joint_damping_matrix(7, 7.0)))
    slow = roots[np.argsort(-roots.real)][:2]  # the servo pair, overdamped at c = 7
    assert np.prod(slow).real == pytest.approx(kp / J, rel=1e-9)


def test_no_joint_damping_settles_the_paper_arm_in_two_seconds():
    """The hold after the slew (gamma = 0.1 and eq. 32, no payload and 0.275 kg): the slowest pole without joint
    damping is the lightly damped joint-1 servo pair (gamma = 0.1: about -0.10 +- 0.85j 1/s), and no viscous joint
    damping makes the slowest pole decay faster than 1 1/s, half the 2 1/s that e^-4 in 2 s needs."""
    from flexarm.gain_schedule import GainSchedule, desired_states
    from flexarm.model import ArmModel
    from flexarm.parameters import load_parameters
    from flexarm.trajectory import load_trajectory

    end = desired_states(load_trajectory())[-1]
    for payload in (0.0, 0.275):
        model = ArmModel(load_parameters(payload_mass=payload))
        for gain_set in ("gamma0.1", "eq32"):
            best = best_joint_damping(*hold_loop(model, GainSchedule.load(gain_set, "200ms").gains[-1], end))
            pole = best["pole_undamped"]
            assert abs(pole.imag) > 0.5 and -pole.real < 0.7, (payload, gain_set, pole)  # a lightly damped pair
            if gain_set == "gamma0.1":
                assert pole.real == pytest.approx(-0.10, abs=0.02) and abs(pole.imag) == pytest.approx(0.85, abs=0.03)
            assert best["rate"] > best["rate_undamped"] and best["rate"] < 1.0, (payload, gain_set, best)
