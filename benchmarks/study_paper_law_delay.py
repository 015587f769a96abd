"""What the paper's law needs to give its Gauss-Seidel answer in a Jacobi master (issue 31): a study.

Runs the library plant (no FMI) for Table 2's no-payload case under the paper's feedforward + scheduled LQR
(gamma = 0.1, 200 ms schedule) with the torque held over sample a computed from the measurement of sample
a - d (d = 2: a Jacobi master at 1 ms with separate sensors and controller FMUs), four ways, and prints the
tables' tracking errors beside the delay-free run:

* ``no delay``: the law as it runs in a Gauss-Seidel master (the reference);
* ``delayed``: the law on the measurement of a - d, with sample a's feedforward and desired values;
* ``model prediction``: the reconstructed error of a - d (eqs. 21-31, the nine unmeasured velocities taken as
  0) carried to a by the linearised model along the slew (the LQG design's Phi, Gamma) with the torques sent;
* ``Kalman predictor``: the LQG design's Kalman filter and predictor to a, fed to the paper's reduced gains K(t_a)
  (flexarm.lqg.PredictedTracking: what controller.fmu does in a Jacobi master).

    python benchmarks/study_paper_law_delay.py [--delay 2] [--payload 0.275]

The acceptance of issue 31 asks every master to give the Gauss-Seidel figures within 5 % or 0.005 deg
(0.05 deg/s).
"""

from __future__ import annotations

import argparse

import numpy as np

from flexarm.control import TrackingController, tracking_errors
from flexarm.gain_schedule import GainSchedule
from flexarm.integrator import PlantSimulator
from flexarm.lqg import PredictedTracking
from flexarm.lqg_design import LqgDesign
from flexarm.lqr import default_trajectory_path
from flexarm.model import ArmModel, joint_angles, joint_velocities, strain_gauge_angles
from flexarm.parameters import load_parameters


def measurements(z: np.ndarray) -> np.ndarray:
    th, om = z[:11], z[11:]
    return np.concatenate([joint_angles(th), joint_velocities(om), strain_gauge_angles(th)])


def run(law: TrackingController, design: LqgDesign, model: ArmModel, how: str, d: int) -> dict[str, float]:
    n = law.n_steps
    plant = PlantSimulator(model, law.z[0])
    predictor = PredictedTracking(law, design, d) if how == "Kalman predictor" else None
    state = None if predictor is None else predictor.initial_state()
    measured, states, held = [], [plant.z.copy()], {}
    for a in range(n):
        measured.append(measurements(plant.z))
        j = a - d
        if how == "no delay":
            tau = law.torque_from_measurements(a, measured[a])
        elif predictor is not None:  # what controller.fmu does in a Jacobi master
            tau, state = predictor.step(state, a, measured[j] if j >= 0 else predictor.desired_measurement(0))
        else:
            error = law._estimator @ measured[max(j, 0)] - law._x_hat_d[max(j, 0)]
            if how == "model prediction":
                for i in range(max(j, 0), a):
                    p = design.index_at(i * law.dt)
                    error = design.Phi[p] @ error + design.Gamma[p] @ (held[i] - law.feedforward(i))
            tau = np.clip(law.feedforward(a) - law.gain(a) @ error, -law.saturation, law.saturation)
        held[a] = tau
        plant.step(tau, law.dt)
        states.append(plant.z.copy())
    return tracking_errors(np.array(states), law.trajectory)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--delay", type=int, default=2, help="loop delay, samples (default 2)")
    ap.add_argument("--payload", type=float, default=0.0, help="tip payload the law does not know, kg")
    args = ap.parse_args()
    law = TrackingController(default_trajectory_path(), GainSchedule.load("gamma0.1", "200ms"))
    design = LqgDesign.load("200ms")
    model = ArmModel(load_parameters().with_payload(args.payload)) if args.payload else ArmModel(load_parameters())
    print(f"Table 2 law, gamma = 0.1, 200 ms schedule, payload {args.payload} kg, loop delay {args.delay} samples")
    print(f"{'':18} {'rms pos, deg':>13} {'rms vel, deg/s':>15} {'peak pos, deg':>14}")
    for how in ("no delay", "delayed", "model prediction", "Kalman predictor"):
        r = run(law, design, model, how, 0 if how == "no delay" else args.delay)
        print(f"{how:18} {r['pos_rms']:13.5g} {r['vel_rms']:15.5g} {r['pos_peak']:14.5g}", flush=True)


if __name__ == "__main__":
    main()
