"""The linearised sampled loop along the gain schedule: plant (exact or a plant scheme's one-step map), zero-order
hold, gain (the LQR, the LQG's filter, the paper's law predicting over a delay), and its fastest growth.
"""

from __future__ import annotations

import functools

import numpy as np

INTEGRATOR_NAMES = {1: "rodas4", 2: "exponential", 3: "gauss", 4: "reference"}
GAIN_SET_NAMES = {1: "gamma1", 2: "gamma0.1", 3: "gamma0", 4: "eq32"}
SCHEDULE_LABELS = {0.2: "200ms", 0.02: "20ms", 0.0: "single"}
CONTROLLERS = {"controller": "", "controller_fb": "", "controller_dlqr": "dlqr-"}


def stability_matrix(X: np.ndarray, integrator: str) -> np.ndarray:
    """R(X): the scheme's one-substep map of the linear system y' = (X/h) y (X = h·M), its stability function
    evaluated on a matrix. All terms are polynomials in X, so they commute and the scalar formulas carry over."""
    from flexarm.model import numpy_kernels

    kern = numpy_kernels()  # RODAS4's coefficients, without loading Numba at a run's start

    eye = np.eye(len(X))
    if integrator == "gauss":  # 2-stage Gauss-Legendre: the (2,2) Padé approximant of exp
        x2 = X @ X / 12
        return np.linalg.solve(eye - X / 2 + x2, eye + X / 2 + x2)
    if integrator == "reference":  # classical RK4
        x2 = X @ X
        return eye + X + x2 / 2 + x2 @ X / 6 + x2 @ x2 / 24
    if integrator == "rodas4":  # as flexarm.integrator.rodas4_stability, stage by stage
        a, c, g = kern.RODAS4_A, kern.RODAS4_C, 1.0 / kern.RODAS4_GAMMA
        inv = np.linalg.inv(g * eye - X)
        ks, u = [], eye
        for stage in range(6):
            if stage:
                u = (eye + sum(a[stage, j] * ks[j] for j in range(stage))) if stage < 5 else u + ks[4]
            f = X @ u + sum(c[stage, j] * ks[j] for j in range(stage))
            ks.append(inv @ f)
        return u + ks[5]
    raise ValueError(f"integrator: no stability function for {integrator!r}")


def plant_zoh(A, B, dt: float, integrator: str = "exact", substeps: int = 2, expm=None):
    """(Φ, Γ) of the linear plant over one step `dt` with the torque held: exact (``exact``, and ``exponential``,
    which is exact on linear dynamics) or the scheme's own map at its nominal substep (RODAS4's error control only
    ever shortens it)."""
    from flexarm.lqr import zoh
    from flexarm.substeps import substep_count

    if integrator in ("exact", "exponential"):
        return zoh(A, B, dt, expm=expm)
    n = substep_count(dt, substeps, integrator)
    nx, nu = B.shape
    aug = np.zeros((nx + nu, nx + nu))
    aug[:nx, :nx], aug[:nx, nx:] = A, B
    step = np.linalg.matrix_power(stability_matrix(aug * (dt / n), integrator), n)
    return step[:nx, :nx], step[:nx, nx:]


def closed_loop(phi, gam, gain, delay: int = 0) -> np.ndarray:
    """The sampled closed loop x⁺ = Φx − ΓK x(k − delay) as one matrix on (x_k, x_{k−1}, …, x_{k−delay})."""
    nx = len(phi)
    if delay == 0:
        return phi - gam @ gain
    m = np.zeros((nx * (delay + 1), nx * (delay + 1)))
    m[:nx, :nx] = phi
    m[:nx, nx * delay:] -= gam @ gain
    m[nx:, :-nx] = np.eye(nx * delay)
    return m


def _growth_at(worst: dict, loop: np.ndarray, A: np.ndarray, dt: float, t_k: float) -> dict:
    """`worst`, or the growth of the sampled `loop` (its state starting with the arm's, A's) at operating point
    `t_k` when it grows faster: rate (1/s), time, aliased frequency and the arm mode that carries it."""
    ev, vec = np.linalg.eig(loop)
    i = int(np.argmax(np.abs(ev)))
    rate = float(np.log(np.abs(ev[i])) / dt)
    if rate <= worst["growth_per_s"]:
        return worst
    lam, modes = np.linalg.eig(A)
    weight = np.abs(np.linalg.lstsq(modes, vec[:len(A), i], rcond=None)[0])
    return {"growth_per_s": rate, "at_time_s": float(t_k),
            "aliased_frequency_hz": float(abs(np.angle(ev[i])) / (2 * np.pi * dt)),
            "mode_frequency_hz": float(abs(lam[int(np.argmax(weight))].imag) / (2 * np.pi))}


@functools.lru_cache(maxsize=128)
def sampled_loop_growth(gain_name: str, schedule: str, damping_ratio: float, payload_mass: float,
                        dt: float = 1e-3, integrator: str = "exact", substeps: int = 2, delay: int = 0) -> dict:
    """Largest ln ρ(closed loop)/dt (1/s) over the schedule's gain sets, where, the mode's aliased frequency (Hz) and
    the frequency of the arm's mode that carries it (Hz, ``mode_frequency_hz``: the eigenvalue of A whose
    eigenvector weighs most in the growing one), for a controller sampling and holding every `dt` (s), with the
    plant's step map :func:`plant_zoh` (`integrator` ``exact``: the converged plant) and `delay` steps of delay."""
    from flexarm.lqr import GainSchedule, effective_gain
    from flexarm.model import ArmModel, numpy_kernels
    from flexarm.parameters import load_parameters
    from flexarm.trajectory import load_trajectory
    from flexarm.trajectory.io import SAMPLE_TIME

    traj = load_trajectory()
    sched = GainSchedule.load(gain_name, schedule)
    # NumPy kernels: eleven linearisations and exponentials do not pay for loading Numba or scipy.linalg (more
    # than half a second of a run's start-up).
    kernels = numpy_kernels()
    model = ArmModel(load_parameters(payload_mass=payload_mass), damping_ratio=damping_ratio, kernels=kernels)
    worst = {"growth_per_s": -np.inf}
    for t_k, gain in zip(sched.times, sched.gains):
        k = min(int(round(t_k / SAMPLE_TIME)), traj.n_samples)  # the trajectory's sample at t_k
        A, B = model.linearize(traj.state(k))
        phi, gam = plant_zoh(A, B, dt, integrator, substeps, expm=kernels.expm)
        worst = _growth_at(worst, closed_loop(phi, gam, effective_gain(gain), delay), A, dt, t_k)
    return worst


# -- the LQG loop (Kalman filter, predictor, discrete LQR): linear too --------------------------------------------
def lqg_closed_loop(phi_p, gam_p, phi_c, gam_c, M, C, K, K_xi=None, delay: int = 0, dt: float = 1e-3):
    """The sampled LQG loop of :class:`flexarm.lqg.LqgController` at one schedule point as one matrix: the plant
    (Φp, Γp: exact or the run's scheme) measured `delay` samples late (the controller's ``loop_delay_samples``
    equal to the master's delay), the controller's filter (Φc, Γc, M, C), its predictor across the delay, its gain
    K and, with integral action, K_ξ. State: plant errors e_k .. e_{k−delay}, the filter's posterior of sample
    k − delay − 1, the torque deviations of samples k − 1 − delay .. k − 1, and ξ (with integral action)."""
    nx, d = len(phi_p), int(delay)
    sizes = [nx * (d + 1), nx, 2 * (d + 1), 2 if K_xi is not None else 0]
    n = sum(sizes)
    eye = np.eye(n)
    o = np.cumsum([0] + sizes)
    hist = [eye[o[0] + nx * i: o[0] + nx * (i + 1)] for i in range(d + 1)]  # e_k, e_{k-1}, ...
    xp, du = eye[o[1]:o[2]], [eye[o[2] + 2 * i: o[2] + 2 * (i + 1)] for i in range(d + 1)]
    xi = eye[o[3]:o[4]]
    x = phi_c @ xp + gam_c @ du[0]  # time update with the torque of sample k − delay − 1
    post = x + M @ (C @ hist[d] - C @ x)  # the measurement of e_{k − delay}
    now = post
    for i in range(1, d + 1):
        now = phi_c @ now + gam_c @ du[i]
    u = -K @ now - (K_xi @ xi if K_xi is not None else 0)
    rows = [phi_p @ hist[0] + gam_p @ u, *hist[:d], post, *du[1:], u]
    if K_xi is not None:
        rows.append(xi + dt * (C[0:2] @ now))
    return np.vstack(rows)


@functools.lru_cache(maxsize=64)
def lqg_loop_growth(gain_name: str, schedule: str, damping_ratio: float, payload_mass: float,
                    integrator: str = "exact", substeps: int = 2, delay: int = 0, integral: bool = False) -> dict:
    """As :func:`sampled_loop_growth` for the LQG controller with one Kalman filter per schedule point
    (estimator = kalman) at 1 ms, along the design's operating points."""
    from flexarm.lqg_design import LqgDesign

    design = LqgDesign.load(schedule)
    w = design.weight_index(gain_name)

    def gains(i: int, n: int):
        if integral:
            return design.K_integral[i, w, :, :n], design.K_integral[i, w, :, n:]
        return design.K[i, w], None

    return _filtered_loop_growth(design, gains, damping_ratio, payload_mass, integrator, substeps, delay)


@functools.lru_cache(maxsize=64)
def predicted_loop_growth(gain_name: str, schedule: str, damping_ratio: float, payload_mass: float,
                          integrator: str = "exact", substeps: int = 2, delay: int = 2) -> dict:
    """As :func:`lqg_loop_growth` for the paper's law predicting over `delay` samples (a Jacobi master: the law
    measures the delay; :class:`flexarm.lqg.PredictedTracking`): the LQG design's filter and predictor of the
    schedule, the paper's law on the predicted measurement: its reduced gain on its reconstruction of it
    (:func:`flexarm.lqr.effective_gain`, K E C)."""
    from flexarm.lqg_design import LqgDesign
    from flexarm.lqr import GainSchedule, effective_gain

    design = LqgDesign.load(schedule)
    on_prediction = effective_gain(GainSchedule.load(gain_name, schedule).gains)
    # one gain per slew point; at the design's hold point (t_f) the law keeps its last gains
    last = len(design.slew_times) - 1
    return _filtered_loop_growth(design, lambda i, n: (on_prediction[min(i, last)], None),
                                 damping_ratio, payload_mass, integrator, substeps, delay)


def _filtered_loop_growth(design, gains, damping_ratio: float, payload_mass: float, integrator: str, substeps: int,
                          delay: int) -> dict:
    """The growth of :func:`lqg_closed_loop` along the design's operating points, `gains(i, n_states)` giving the
    gain (and the integral gain or None) at point i."""
    from flexarm.model import ArmModel, numpy_kernels
    from flexarm.parameters import load_parameters
    from flexarm.trajectory import load_trajectory
    from flexarm.trajectory.io import SAMPLE_TIME

    dt = 1e-3
    traj = load_trajectory()
    kernels = numpy_kernels()
    model = ArmModel(load_parameters(payload_mass=payload_mass), damping_ratio=damping_ratio, kernels=kernels)
    worst = {"growth_per_s": -np.inf}
    for i, t_k in enumerate(design.times):
        k = min(int(round(t_k / SAMPLE_TIME)), traj.n_samples)
        A, B = model.linearize(traj.state(k))
        phi, gam = plant_zoh(A, B, dt, integrator, substeps, expm=kernels.expm)
        K, K_xi = gains(i, len(A))
        loop = lqg_closed_loop(phi, gam, design.Phi[i], design.Gamma[i], design.M[i], design.C, K, K_xi, delay, dt)
        worst = _growth_at(worst, loop, A, dt, t_k)
    return worst
