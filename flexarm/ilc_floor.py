"""The floor of the tracking error: what any torque history within the motors' peak torques can do (no FMI).

Used to tell what the learning (:mod:`flexarm.ilc`) could reach at best: :func:`minimum_tracking_error` searches
the torque histories themselves, open loop and noise-free, for the smallest rms error of the 11 element angles
along the slew (the tables' metric). Any controller's torques are one such history, so the error found is
(up to the search's resolution: torques held over blocks, a local search) a floor for every controller.
``python -m scenarios.ilc.floor`` writes it into docs/ilc.md.
"""

from __future__ import annotations

import numpy as np

from .gain_schedule import as_trajectory, desired_states, sample_time
from .ilc import LtvModel, NormOptimalIlc, simulate_trial, truncated_physical_model
from .model import N_STATE, N

#: Levenberg-Marquardt damping: first value (relative to the largest diagonal of RᵀR), factor on a failed step,
#: factor on a successful one.
DAMPING_START, DAMPING_UP, DAMPING_DOWN = 1e-6, 10.0, 0.3


def open_loop_model(arm, states, torques, dt: float, every: int = 20) -> LtvModel:
    """The arm's open-loop ZOH model linearised about a run, one model per sample (the same every `every` samples).

    Parameters
    ----------
    arm : flexarm.model.ArmModel
    states : array_like, shape (N + 1, 22)
        The run's states at samples 0..N.
    torques : array_like, shape (N, 2)
        Its torques, N·m (sample k held over [k·dt, (k+1)·dt)).
    dt : float
        Sample time, s.
    every : int
        Samples between linearisation points.

    Returns
    -------
    LtvModel
        δx_(k+1) = Φ_k δx_k + Γ_k δτ_k; output: the 11 element angles (rad) of the state deviation.
    """
    states, torques = np.asarray(states, dtype=float), np.asarray(torques, dtype=float)
    n = len(torques)
    points = [truncated_physical_model(arm, states[k], torques[k], dt) for k in range(0, n, every)]
    which = np.minimum(np.arange(n) // every, len(points) - 1)
    return LtvModel(A=np.array([points[i][0] for i in which]), B=np.array([points[i][1] for i in which]),
                    C=np.eye(N_STATE)[:N], dt=dt)


def lifted_blocks(model: LtvModel, block: int) -> np.ndarray:
    """The lifted model for inputs held over blocks of `block` samples: shape (N·11, 2·n_blocks), rows sample by
    sample (δy_1..δy_N), columns (block, joint)."""
    n = model.n_samples
    nb = -(-n // block)
    X = np.zeros((N_STATE, 2 * nb))
    G = np.empty((n, len(model.C), 2 * nb))
    for k in range(n):
        X = model.A[k] @ X
        b = k // block
        X[:, 2 * b:2 * b + 2] += model.B[k]
        G[k] = model.C @ X
    return G.reshape(n * len(model.C), 2 * nb)


def minimum_tracking_error(payload_mass: float = 0.275, block: int = 10, linearisations: int = 6,
                           trials: int = 30, trajectory=None, progress=None) -> dict:
    """The smallest rms element-angle error along the slew found with torques within the motors' peak torques.

    Noise-free and open loop. Starting from the torques of the unlearned γ = 0.1 controller on the arm with
    the payload, Levenberg-Marquardt steps on the torque history, held over blocks of `block` samples: the arm
    linearised about the current run (:func:`open_loop_model`); the step v minimises
    ‖e − G v‖² + λ‖v‖² subject to |τ + v| ≤ peak torque in every sample of each block (QR of G, then BVLS); it
    is tried on the nonlinear plant (:class:`flexarm.integrator.PlantSimulator`, the plant FMU's integrator)
    and kept if the error falls (then λ shrinks and the arm is linearised anew), else λ grows. At most
    `linearisations` linearisations and `trials` nonlinear runs. The metric: rms over the 11 element angles
    and samples 0..n_slew, degrees (the tables').

    Returns
    -------
    dict
        ``start_rms_deg`` (the unlearned closed loop), ``achieved_rms_deg`` and ``achieved_peak_torque`` (N·m):
        the best nonlinear run, torques within the limits (achievable, so an upper bound of the floor at this
        block length); of the last linearisation, ``linear_constrained_rms_deg`` and
        ``linear_unconstrained_rms_deg`` (its minimum with and without the limits, λ = 0) and
        ``unconstrained_peak_torque`` (what the latter needs); ``linear_1ms_unconstrained_rms_deg`` and its
        peak torque (the arm linearised about the best run, torques free every 1 ms sample, no limits: the
        Riccati sweep of :class:`flexarm.ilc.NormOptimalIlc`, input weight 1e-10); ``steps`` (per nonlinear
        run: λ, the linear prediction, the nonlinear result, kept or not).
    """
    import scipy.optimize

    from .control import TrackingController
    from .integrator import PlantSimulator
    from .model import ArmModel
    from .parameters import load_parameters
    from .trajectory.io import DEFAULT_TRAJECTORY_FILE

    say = progress or (lambda s: None)
    traj = as_trajectory(DEFAULT_TRAJECTORY_FILE if trajectory is None else trajectory)
    m, dt = traj.n_samples, sample_time(traj)
    z_d = desired_states(traj)[:m + 1]
    arm = ArmModel(load_parameters(payload_mass=payload_mass))
    limit = np.asarray(arm.params.peak_torque, dtype=float)

    def replay(tau):
        plant = PlantSimulator(arm, z_d[0])
        return np.array([plant.z.copy()] + [plant.step(t, dt).copy() for t in tau])

    def rms(err):
        return float(np.degrees(np.sqrt(np.mean(np.square(err)))))

    def error(states):
        return (z_d - states)[:, :N]

    start = simulate_trial(TrackingController(traj, "gamma0.1"), m, payload_mass, noise=False)
    tau, states = start["torques"].copy(), replay(start["torques"])
    best = rms(error(states))
    out = {"payload_mass_kg": float(payload_mass), "block_samples": int(block), "slew_samples": int(m),
           "peak_torque_limits": limit.tolist(), "start_rms_deg": rms(error(start["states"])), "steps": []}
    nb = -(-m // block)
    lam, runs = None, 0
    for _ in range(int(linearisations)):
        G = lifted_blocks(open_loop_model(arm, states, tau, dt), block)
        e = error(states)[1:].ravel()
        lo, hi = np.empty(2 * nb), np.empty(2 * nb)
        for b in range(nb):
            seg = tau[b * block:(b + 1) * block]
            lo[2 * b:2 * b + 2], hi[2 * b:2 * b + 2] = -limit - seg.min(axis=0), limit - seg.max(axis=0)
        lo, hi = np.minimum(lo, 0.0), np.maximum(hi, 0.0)  # a sample already at its limit stays there
        q, r = np.linalg.qr(G)
        qe = q.T @ e
        del q

        def lin(x, e=e, G=G):  # sample 0 has no error to remove
            return rms(np.r_[np.zeros(N), e - G @ x])

        v0 = scipy.optimize.lsq_linear(r, qe, bounds=(lo, hi), method="bvls").x
        free = np.linalg.solve(r, qe)
        out["linear_constrained_rms_deg"], out["linear_unconstrained_rms_deg"] = lin(v0), lin(free)
        out["unconstrained_peak_torque"] = np.abs(tau + np.repeat(free.reshape(nb, 2), block, 0)[:m]).max(0).tolist()
        scale = float(np.max(np.sum(r * r, axis=0)))
        lam = DAMPING_START * scale if lam is None else lam
        kept = False
        while runs < trials and not kept:
            v = scipy.optimize.lsq_linear(np.vstack([r, np.sqrt(lam) * np.eye(2 * nb)]), np.r_[qe, np.zeros(2 * nb)],
                                          bounds=(lo, hi), method="bvls").x
            trial = replay(tau + np.repeat(v.reshape(nb, 2), block, axis=0)[:m])
            runs += 1
            r_t = rms(error(trial))
            kept = bool(np.isfinite(r_t) and r_t < best)
            out["steps"].append({"damping": lam / scale, "linear_rms_deg": lin(v), "nonlinear_rms_deg": r_t,
                                 "kept": kept})
            say(f"run {runs}: damping {lam / scale:.1e}, linearised {lin(v):.4f} deg, nonlinear {r_t:.4f} deg"
                + (" (kept)" if kept else ""))
            if kept:
                tau, states, best = tau + np.repeat(v.reshape(nb, 2), block, axis=0)[:m], trial, r_t
                lam *= DAMPING_DOWN
            else:
                lam *= DAMPING_UP
        if not kept:
            break
    out["achieved_rms_deg"], out["achieved_peak_torque"] = best, np.abs(tau).max(axis=0).tolist()
    model = open_loop_model(arm, states, tau, dt)
    e1 = error(states)[1:]
    du = NormOptimalIlc(model, 1.0, 1e-10, None).step(e1)
    out["linear_1ms_unconstrained_rms_deg"] = rms(np.r_[np.zeros((1, N)), e1 - model.simulate(du)])
    out["linear_1ms_unconstrained_peak_torque"] = np.abs(tau + du).max(axis=0).tolist()
    return out
