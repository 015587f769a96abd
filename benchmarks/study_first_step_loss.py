"""fmpy's ``simulate_ssp`` and the first millisecond: what a controller can still repair (issue 31), a study.

``simulate_ssp`` sets every connected input to 0 over the first communication step, so the plant holds no
torque from t = 0 to 1 ms, whatever the controller computed; from the second step on it steps Jacobi (loop
delay 2). The plant says so (``tau_lag``), and the LQG filter takes the torque the arm really got, but the
missing 1 ms of feedforward is a real impulse: it rings the bracket modes and leaves the arm behind. This
study runs the library plant (no FMI) under ``controller_lqg``'s law (gamma = 0.1, 200 ms schedule, Kalman
filter, delay 2) for Table 2's no-payload slew and prints the tracking errors of

* ``Gauss-Seidel``: no delay, torque delivered (the figure every master must give, issue 31's acceptance);
* ``Jacobi``: delay 2, torque delivered (our Jacobi master, libcosim, Ecos);
* ``first torque lost``: delay 2, the plant holds 0 over sample 0 and the filter is told (``simulate_ssp``);
* ``lost, catch-up N``: the same, plus a correction planned when the controller learns of the loss (its output
  of sample 2, the first that can act): the torques c_2 .. c_{N+1} that minimise the deviation from the
  undisturbed run over the next N samples (the 11 element rates in deg/s, the angles weighted 100x) with
  the deviation forced to 0 at the end (the linearised closed loop at the first schedule point, least
  squares); the feedback does not react to the planned deviation;
* ``samples 1-2 alone``: the Jacobi run's mean square plus what the deviation of samples 1 and 2 (which no
  correction can reach: sample 1's torque is computed before the loss is known) adds: what a perfect
  repair from sample 3 on would give, were the cross terms zero.

    python benchmarks/study_first_step_loss.py [--catch-up 40 80]

The acceptance asks for the Gauss-Seidel figures within 5 % or 0.005 deg (0.05 deg/s), whichever is larger;
the study prints that band. Not adopted: the controllers start the slew one sample later instead when their first
step finds the master's placeholder, so no torque is lost (docs/control.md, "The slew starts when the loop is
live"); this study stays as the measure of what a repair after the loss could do.
"""

from __future__ import annotations

import argparse

import numpy as np

from flexarm import ArmModel
from flexarm.integrator import PlantSimulator
from flexarm.lqg import lqg_controller
from flexarm.parameters import load_parameters
from scenarios.metrics import table_metrics

#: Weight of the angles' deviation (deg) against the rates' (deg/s) in the catch-up's least squares: the
#: table's position errors are about 100-1000x smaller than its velocity errors.
ANGLE_WEIGHT = 100.0
#: Weight of the end condition (deviation 0 after the catch-up) against the running cost.
END_WEIGHT = 1e3
#: Weight of the correction's size (N·m) in the least squares: a tie-breaker only.
TORQUE_WEIGHT = 1e-3


def catch_up_plan(ctrl, lost: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Corrections c_2 .. c_{n+1} (shape (n, 2), N·m) for the torque `lost` over sample 0, and the planned
    deviation of the state from the undisturbed run at samples 2 .. n + 2 (shape (n + 1, 22))."""
    d = ctrl.design
    i0 = d.index_at(0.0)
    phi, gam = d.Phi[i0], d.Gamma[i0]
    x2 = phi @ (gam @ (-lost))  # the deviation at sample 2 (sample 1's torque was sent before the loss was known)
    w = np.diag(np.r_[np.full(11, ANGLE_WEIGHT), np.ones(11)]) * np.degrees(1.0)
    powers = [np.eye(22)]
    for _ in range(n + 1):
        powers.append(phi @ powers[-1])
    rows, rhs = [], []
    for m in range(1, n + 1):  # deviation at sample 2 + m
        block = np.zeros((22, 2 * n))
        for j in range(m):
            block[:, 2 * j:2 * j + 2] = powers[m - 1 - j] @ gam
        weight = w * (END_WEIGHT if m == n else 1.0)
        rows.append(weight @ block)
        rhs.append(-weight @ powers[m] @ x2)
    a = np.vstack([*rows, np.sqrt(TORQUE_WEIGHT) * np.eye(2 * n)])
    b = np.concatenate([*rhs, np.zeros(2 * n)])
    c = np.linalg.lstsq(a, b, rcond=None)[0].reshape(n, 2)
    plan = [x2]
    for k in range(n):
        plan.append(phi @ plan[-1] + gam @ c[k])
    return c, np.array(plan)


def run(delay: int, lose_first: bool, catch_up: int = 0) -> tuple[dict, np.ndarray]:
    """Table metrics of one library run and its states (shape (n + 1, 22))."""
    ctrl = lqg_controller(loop_delay_samples=delay)
    d = ctrl.design
    w = d.weight_index(ctrl.gain_set)
    plant = PlantSimulator(ArmModel(load_parameters()), ctrl.z[0])
    state = ctrl.initial_state()
    states, torques, measured = [plant.z.copy()], [], []
    correction, plan = np.zeros((0, 2)), np.zeros((0, 22))
    for k in range(ctrl.n_steps):
        measured.append(d.C @ plant.z)
        tau, state = ctrl.step(state, k, measured[max(k - delay, 0)])
        j = k - 2
        if 0 <= j < len(correction):  # the plan, and the feedback kept off the planned deviation
            tau = tau + correction[j] + d.K[d.index_at(k * ctrl.dt), w] @ plan[j]
            state.du[-1] = tau - ctrl.feedforward(k)
        applied = tau
        if lose_first and k == 0:
            applied = np.zeros(2)
            state.du[-1] = applied - ctrl.feedforward(0)  # the plant's report: the filter knows
        if lose_first and k == 1 and catch_up:
            correction, plan = catch_up_plan(ctrl, ctrl.feedforward(0), catch_up)
        plant.step(applied, ctrl.dt)
        torques.append(applied)
        states.append(plant.z.copy())
    s, z = np.array(states), ctrl.z[:len(states)]
    return table_metrics(np.array(torques), s[:, :11], s[:, 11:], z[:, :11], z[:, 11:]), s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--catch-up", type=int, nargs="*", default=[40, 80], help="catch-up lengths N, samples")
    args = ap.parse_args()
    gs, _ = run(0, False)
    jac, s_jac = run(2, False)
    lost, s_lost = run(2, True)
    rows = [("Gauss-Seidel", gs), ("Jacobi", jac), ("first torque lost", lost)]
    rows += [(f"lost, catch-up {n}", run(2, True, n)[0]) for n in args.catch_up]
    dv = np.degrees(s_lost[1:3, 11:] - s_jac[1:3, 11:])
    n = len(s_jac) - 1
    alone = np.sqrt(jac["rms_velocity_error"] ** 2 + np.sum(np.mean(dv**2, axis=1)) / n)
    print("controller_lqg's law (gamma = 0.1, 200 ms, Kalman filter), Table 2 no payload, library plant")
    print(f"{'':22} {'rms pos, deg':>13} {'rms vel, deg/s':>15} {'peak tau1, N·m':>15} {'peak tau2, N·m':>15}")
    for label, m in rows:
        print(f"{label:22} {m['rms_position_error']:13.5g} {m['rms_velocity_error']:15.5g} "
              f"{m['peak_tau1']:15.4g} {m['peak_tau2']:15.4g}")
    print(f"{'samples 1-2 alone':22} {'':>13} {alone:15.5g}")
    band = [(max(0.05 * v, tol)) for v, tol in ((gs["rms_position_error"], 0.005), (gs["rms_velocity_error"], 0.05))]
    print(f"acceptance band around Gauss-Seidel: position <= {gs['rms_position_error'] + band[0]:.5g} deg, "
          f"velocity <= {gs['rms_velocity_error'] + band[1]:.5g} deg/s")


if __name__ == "__main__":
    main()
