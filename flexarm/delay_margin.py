"""Delay margins of the sampled-data loops (issue 14): how many whole 1 ms samples of loop delay each gain set takes.

For a gain set at a schedule point t_k the loop is linearised about the
desired state z_d(t_k) and the feedforward torque τ_ff(t_k) (the exact
linearisation of the tracking-error dynamics), sampled with a 1 ms
zero-order hold, and closed with the controller *as it runs*
(:class:`flexarm.control.TrackingController`): angles reconstructed from
the encoders and gauges with rigid brackets (eqs. 21-31), the two
tachometer velocities, the other nine velocities not fed back, i.e. the gain
reduce_gain(K)·C of :func:`flexarm.lqr_design.effective_gain`. A loop delay
of d samples means the torque held over [t_j, t_j+1) was computed from the
state at t_(j−d):

    x_(j+1) = Φ x_j + Γ v_(j−d),   v_j = −K_eff x_j,

whose companion matrix (state x_j and the d torques in flight) must have
spectral radius < 1. The margin is the largest d such that every delay
0..d is stable (−1: unstable even without delay).

Bracket modes. The three bracket modes (5.6, 13 and 21 kHz) lie above the
1 kHz sampling rate; undamped in the model, their aliases sit on the unit
circle and the reconstruction (which takes brackets as rigid) feeds them a
micro-radian signal, which makes even the delay-free loop grow at ≤ 2 s⁻¹
(:mod:`flexarm.lqr_design`). The plant's L-stable integrator, like the
hardware's structural damping, removes them. The margin is therefore
computed on the modal model truncated above :data:`MODE_CUTOFF_HZ` (rigid
modes and the link modes at 8-190 Hz, 16 states); the simulation test checks
one entry against the full nonlinear plant.

Besides the schedule points, the column ``hold`` is the loop after the slew:
the final (resting) state, zero feedforward and the last gain set.

Run ``python -m flexarm.delay_margin`` for the table.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from .gain_schedule import GainSchedule, as_trajectory, default_trajectory_path, desired_states, sample_time
from .gain_sets import GAIN_SET_NAMES
from .lqr_design import DEFAULT_DT, effective_gain, scaling_transform, zoh
from .model import ArmModel, N

#: Modes above this frequency (the sampling rate) are truncated: the bracket modes, Hz.
MODE_CUTOFF_HZ = 1000.0
#: Largest delay examined, samples.
MAX_DELAY = 30


def truncated_model(model: ArmModel, z_bar, tau_bar, dt: float = DEFAULT_DT, cutoff_hz: float = MODE_CUTOFF_HZ):
    """ZOH model of the linearisation with the modes above ``cutoff_hz`` truncated.

    Returns
    -------
    Phi : ndarray, shape (r, r)
    Gamma : ndarray, shape (r, 2)
    T_r : ndarray, shape (22, r)
        Maps the reduced (modal, scaled) state to the 22 physical states.
    """
    A, B = model.linearize(z_bar, tau_bar)
    T = scaling_transform(model, z_bar)
    Ti = np.linalg.inv(T)
    theta = np.asarray(z_bar, dtype=float)[:N]
    mass = model.mass_matrix(theta)
    k_t = -mass @ model.jacobian(np.r_[theta, np.zeros(N)])[N:, :N]
    import scipy.linalg

    w2 = scipy.linalg.eigh(0.5 * (k_t + k_t.T), mass, eigvals_only=True)
    keep_modes = np.flatnonzero(np.sqrt(np.maximum(w2, 0.0)) < 2 * np.pi * cutoff_hz)
    keep = np.r_[keep_modes, N + keep_modes]
    At, Bt = (Ti @ A @ T)[np.ix_(keep, keep)], (Ti @ B)[keep]
    Phi, Gamma = zoh(At, Bt, dt)
    return Phi, Gamma, T[:, keep]


def closed_loop_matrix(Phi, Gamma, G, delay: int) -> np.ndarray:
    """Companion matrix of x_(j+1) = Φx_j + Γv_(j−d), v_j = −G x_j; state (x_j, v_(j−1), ..., v_(j−d))."""
    n, m = Gamma.shape
    if delay == 0:
        return Phi - Gamma @ G
    size = n + m * delay
    F = np.zeros((size, size))
    F[:n, :n] = Phi
    F[:n, n + m * (delay - 1):] = Gamma  # the oldest torque in flight acts now
    F[n:n + m, :n] = -G
    F[n + m:, n:n + m * (delay - 1)] = np.eye(m * (delay - 1))
    return F


def spectral_radii(Phi, Gamma, G, max_delay: int = MAX_DELAY) -> np.ndarray:
    """ρ of the closed loop for delays 0..max_delay, shape (max_delay + 1,)."""
    return np.array([np.abs(np.linalg.eigvals(closed_loop_matrix(Phi, Gamma, G, d))).max()
                     for d in range(max_delay + 1)])


def margin_from_radii(rho) -> int:
    """Largest d with ρ(0..d) < 1; −1 if ρ(0) ≥ 1."""
    unstable = np.flatnonzero(np.asarray(rho) >= 1.0)
    return int(unstable[0]) - 1 if len(unstable) else len(rho) - 1


def delay_margins(model: ArmModel, schedule: GainSchedule, trajectory, max_delay: int = MAX_DELAY,
                  omega7: str = "tachometer") -> dict:
    """Delay margin at every point of a gain schedule and in the hold after the slew.

    Parameters
    ----------
    model : ArmModel
        The plant (no payload).
    schedule : GainSchedule
    trajectory : TrajectoryResult or path-like
    max_delay : int
        Largest delay examined (a margin equal to it means "at least").
    omega7 : str
        The controller's θ̇7 estimate (:data:`flexarm.lqr_design.OMEGA7_CHOICES`).

    Returns
    -------
    dict
        ``times`` (s, the schedule points), ``margins`` (int per point), ``rho`` (n_points, max_delay + 1),
        ``hold_margin``, ``hold_rho``.
    """
    traj = as_trajectory(trajectory)
    z, dt = desired_states(traj), sample_time(traj)
    margins, radii = [], []
    for t_k, K in zip(schedule.times, schedule.gains):
        k = int(round(t_k / dt))
        tau_bar = traj.tau[k] if k < traj.n_samples else np.zeros(2)
        Phi, Gamma, T_r = truncated_model(model, z[k], tau_bar, dt)
        rho = spectral_radii(Phi, Gamma, effective_gain(K, omega7) @ T_r, max_delay)
        radii.append(rho)
        margins.append(margin_from_radii(rho))
    Phi, Gamma, T_r = truncated_model(model, z[-1], np.zeros(2), dt)
    hold_rho = spectral_radii(Phi, Gamma, effective_gain(schedule.gains[-1], omega7) @ T_r, max_delay)
    return {"times": np.asarray(schedule.times), "margins": np.array(margins), "rho": np.array(radii),
            "hold_margin": margin_from_radii(hold_rho), "hold_rho": hold_rho}


def format_table(results: dict[str, dict], max_delay: int = MAX_DELAY) -> str:
    """One row per gain set: the margin at each schedule point, the minimum and the hold."""
    first = next(iter(results.values()))
    cells = lambda v: ">=" + str(max_delay) if v >= max_delay else ("unst." if v < 0 else str(v))  # noqa: E731
    head = f"{'gain set':<15}" + "".join(f"{t:>6.1f}" for t in first["times"]) + f"{'min':>6}{'hold':>6}"
    lines = ["loop delay margin, whole 1 ms samples, at each gain-schedule time t_k (s)", head, "-" * len(head)]
    for name, r in results.items():
        lines.append(f"{name:<15}" + "".join(f"{cells(m):>6}" for m in r["margins"])
                     + f"{cells(int(r['margins'].min())):>6}{cells(r['hold_margin']):>6}")
    return "\n".join(lines)


def main(argv=None) -> int:
    """Print the delay-margin table of the committed gain schedules."""
    ap = argparse.ArgumentParser(prog="python -m flexarm.delay_margin", description=__doc__.split("\n")[0])
    ap.add_argument("--sets", nargs="+", default=list(GAIN_SET_NAMES), help="gain-set names")
    ap.add_argument("--schedule", default="200ms", choices=("200ms", "20ms", "single"))
    ap.add_argument("--max-delay", type=int, default=MAX_DELAY)
    ap.add_argument("--omega7", default="tachometer", choices=("tachometer", "rigid"))
    args = ap.parse_args(argv)
    if not 0 <= args.max_delay <= 200:
        print(f"error: --max-delay must be in 0..200, got {args.max_delay}", file=sys.stderr)
        return 2
    model = ArmModel()
    traj = as_trajectory(default_trajectory_path())
    results = {name: delay_margins(model, GainSchedule.load(name, args.schedule), traj, args.max_delay, args.omega7)
               for name in args.sets}
    print(format_table(results, args.max_delay))
    print(f"\nModel: linearised about (z_d(t_k), tau_ff(t_k)), 1 ms ZOH, modes above {MODE_CUTOFF_HZ:g} Hz "
          "(brackets) truncated; controller as implemented (reconstructed angles, two tachometers). "
          "'hold': after the slew (final state, last gain set).")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
