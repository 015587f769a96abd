"""Checks, plot and command line of the trajectory: ``python -m flexarm.trajectory``.

:func:`verify_against_plant` replays the file's torques open loop in the full
11-element plant; :func:`check_constraints` measures the file's own constraint
residuals; :func:`plot_trajectory` draws it; :func:`main` solves and writes.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from ..model import ArmModel, joint_angles, strain_gauge_angles
from ..parameters import N_ELEMENTS, ArmParameters, load_parameters
from ..provenance import write_atomic
from .geometry import line_distance
from .io import (
    DEFAULT_PLOT_FILE,
    DEFAULT_TRAJECTORY_FILE,
    PAPER_TF,
    SAMPLE_TIME,
    TrajectoryError,
    TrajectoryResult,
    load_trajectory,
    save_trajectory,
)


# -- verification against the full plant -------------------------------------------
def verify_against_plant(result: TrajectoryResult, params: ArmParameters | None = None,
                         settle_s: float = 1.0) -> dict:
    """Replay the file's torques open loop in the full 11-element plant.

    Parameters
    ----------
    result : TrajectoryResult
    params : ArmParameters, optional
        Plant parameters (default: the committed file).
    settle_s : float
        Zero-torque run after t_f, s.

    Returns
    -------
    dict
        ``max_angle_error_deg`` (any element, over the slew),
        ``max_line_distance_mm`` (plant tip from the line, over the slew),
        ``final_tip_error_mm``, ``residual_energy_J`` (T + V at t_f) and
        ``max_energy_after_J`` (over the settling run).
    """
    from ..integrator import simulate

    params = params if params is not None else load_parameters()
    model = ArmModel(params)
    z0 = result.state(0)
    n = result.n_samples
    n_settle = int(round(settle_s / SAMPLE_TIME))
    torques = np.vstack([result.tau[:n], np.zeros((n_settle, 2))])
    z = simulate(model, z0, torques)
    th = z[: n + 1, :N_ELEMENTS]
    tip = np.array([model.tip_position(x) for x in th])
    energy_after = np.array([model.total_energy(x) for x in z[n:]])
    return {
        "max_angle_error_deg": float(np.degrees(np.max(np.abs(th - result.theta)))),
        "max_velocity_error_deg_s": float(np.degrees(np.max(np.abs(z[: n + 1, N_ELEMENTS:] - result.omega)))),
        "max_line_distance_mm": float(1e3 * np.max(np.abs(line_distance(params, tip)))),
        "final_tip_error_mm": float(1e3 * np.linalg.norm(tip[-1] - params.line_end)),
        "residual_energy_J": float(energy_after[0]),
        "max_energy_after_J": float(energy_after.max()),
        "states": z,
    }


def check_constraints(result: TrajectoryResult, params: ArmParameters | None = None) -> dict:
    """Constraint residuals of the file's desired trajectory (its own samples).

    Returns
    -------
    dict
        ``max_line_distance_mm``, ``final_tip_error_mm``, ``final_kinetic_J``,
        ``final_strain_J``, ``max_torque_ratio`` (|τ|/τ_limit),
        ``initial_strain_J``, ``initial_speed`` (rad/s).
    """
    params = params if params is not None else load_parameters()
    model = ArmModel(params)
    lim = params.torque_limit
    return {
        "max_line_distance_mm": float(1e3 * np.max(np.abs(line_distance(params, result.tip)))),
        "final_tip_error_mm": float(1e3 * np.linalg.norm(result.tip[-1] - params.line_end)),
        "final_kinetic_J": model.kinetic_energy(result.state(-1)),
        "final_strain_J": model.strain_energy(result.theta[-1]),
        "max_torque_ratio": float(np.max(np.abs(result.tau) / lim)),
        "initial_strain_J": model.strain_energy(result.theta[0]),
        "initial_speed": float(np.max(np.abs(result.omega[0]))),
        "final_tau": result.tau[-1].tolist(),
    }


# -- plot ---------------------------------------------------------------------------------
def plot_trajectory(result: TrajectoryResult, path: str | os.PathLike = DEFAULT_PLOT_FILE,
                    params: ArmParameters | None = None) -> Path:
    """Tip path against the line, torques against their limits, joint and strain-gauge angles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    params = params if params is not None else load_parameters()
    lim = params.torque_limit
    t = result.t
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    a = ax[0, 0]
    a.plot([params.line_start[0], params.line_end[0]], [params.line_start[1], params.line_end[1]], "k--",
           lw=1, label="line")
    a.plot(result.tip[:, 0], result.tip[:, 1], "C0", label="tip")
    model = ArmModel(params)
    for k in np.linspace(0, len(t) - 1, 6).astype(int):
        pts = model.hinge_positions(result.theta[k])
        a.plot(pts[:, 0], pts[:, 1], "-", color="0.6", lw=0.8)
    a.set_aspect("equal")
    a.set_xlabel("x (m)")
    a.set_ylabel("y (m)")
    a.set_title("tip path (arm drawn at 6 instants)")
    a.legend(loc="best")
    a = ax[0, 1]
    for i, c in ((0, "C0"), (1, "C1")):
        a.step(t, result.tau[:, i], where="post", color=c, label=f"τ{i + 1}")
        a.axhline(lim[i], color=c, ls=":", lw=0.8)
        a.axhline(-lim[i], color=c, ls=":", lw=0.8)
    a.set_xlabel("t (s)")
    a.set_ylabel("torque (N·m)")
    a.set_title("torques and their limits (80 % of peak)")
    a.legend(loc="best")
    a = ax[1, 0]
    q = np.array([joint_angles(th) for th in result.theta])
    a.plot(t, np.degrees(q[:, 0]), label="q1 = θ1")
    a.plot(t, np.degrees(q[:, 1]), label="q2 = θ7 − θ6")
    a.set_xlabel("t (s)")
    a.set_ylabel("joint angle (deg)")
    a.set_title("joint angles")
    a.legend(loc="best")
    a = ax[1, 1]
    e = np.array([strain_gauge_angles(th) for th in result.theta])
    names = ("ε11", "ε12", "ε13", "ε21", "ε22", "ε23")
    for i in range(6):
        a.plot(t, np.degrees(e[:, i]), label=names[i])
    a.set_xlabel("t (s)")
    a.set_ylabel("segment angle (deg)")
    a.set_title("strain-gauge angles")
    a.legend(loc="best", ncol=2, fontsize=8)
    fig.suptitle(f"Minimum-time slew: t_f = {result.t_f:.3f} s (paper {PAPER_TF} s)")
    fig.tight_layout()
    path = Path(path)
    write_atomic(path, lambda fh: fig.savefig(fh, format="png", dpi=110))
    plt.close(fig)
    return path


# -- command line -----------------------------------------------------------------------------
def _report(result: TrajectoryResult, replay: dict, sens: list[dict] | None) -> str:
    m = result.metadata
    lines = [
        f"t_f = {m['t_f_continuous_s']:.4f} s (continuous optimum); file: {result.t_f:.3f} s = "
        f"{result.n_samples} samples of 1 ms; paper: {PAPER_TF} s "
        f"({100 * (m['t_f_continuous_s'] / PAPER_TF - 1):+.1f} %)",
        f"solver: {m['solver']['status']}, {m['solver']['iterations']} iterations in all stages, "
        f"{m['solver']['solve_time_s']:.1f} s",
        f"tau1 within 1 % of its limit: {100 * m['tau1_on_limit_fraction']:.1f} % of the 1 ms steps "
        f"(tau2: {100 * m['tau2_on_limit_fraction']:.1f} %)",
        f"plant replay: max angle error {replay['max_angle_error_deg']:.4f} deg, max tip-line distance "
        f"{replay['max_line_distance_mm']:.3f} mm, final tip error {replay['final_tip_error_mm']:.3f} mm, "
        f"residual energy {replay['residual_energy_J']:.2e} J",
    ]
    if sens:
        lines.append("sensitivity (t_f, s):")
        lines.append(f"  {'parameter':24s} {'factor':>6s} {'value':>10s} {'t_f':>8s} {'change':>8s}")
        for r in sens:
            lines.append(f"  {r['parameter']:24s} {r['factor']:6.2f} {r['value']:10.5f} "
                         f"{r['t_f_continuous_s']:8.4f} {r['t_f_continuous_s'] - m['t_f_continuous_s']:+8.4f}")
    return "\n".join(lines)


def annotate_with_replay(result: TrajectoryResult, params: ArmParameters) -> dict:
    """Replay `result` in the plant (:func:`verify_against_plant`) and record the replay and the constraint checks
    (:func:`check_constraints`) in its metadata, as every written slew carries them; returns the replay."""
    replay = verify_against_plant(result, params)
    result.metadata["plant_replay"] = {k: v for k, v in replay.items() if k != "states"}
    result.metadata["constraints"] = check_constraints(result, params)
    return replay


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m flexarm.trajectory",
                                 description="Solve the minimum-time straight-line slew and write the 1 ms file.")
    ap.add_argument("--params", default=None, help="parameter file (default: the committed Sandia arm)")
    ap.add_argument("--payload", type=float, default=None, help="tip payload, kg (default: the file's)")
    ap.add_argument("--intervals", type=int, default=200, help="collocation intervals (default 200)")
    ap.add_argument("--degree", type=int, default=5, help="Radau points per interval (default 5)")
    ap.add_argument("--out", default=str(DEFAULT_TRAJECTORY_FILE), help="output .npz (a .json sidecar is written)")
    ap.add_argument("--plot", default=None, help="also write this PNG")
    ap.add_argument("--sensitivity", action="store_true",
                    help="also solve with stator mass and rotor-2 inertia at ±20 %% (stored in the metadata)")
    ap.add_argument("--quiet", action="store_true", help="no IPOPT output")
    ap.add_argument("--replan", action="store_true",
                    help="re-plan with FATROP from the committed file (its grid) instead of a cold IPOPT solve; "
                         "needs --out (the committed file stays the unloaded slew)")
    ap.add_argument("--fatrop", action="store_true",
                    help="the cold solve with FATROP after IPOPT's rigid warm-up (lands on the committed file to the "
                         "solvers' tolerance; the default IPOPT solve reproduces it exactly)")
    args = ap.parse_args(argv)
    if args.replan and args.fatrop:
        ap.error("--replan already solves with FATROP (from the committed file); --fatrop is for a cold solve")
    if args.replan and Path(args.out).resolve() == Path(DEFAULT_TRAJECTORY_FILE).resolve():
        ap.error("--replan: give --out FILE; the committed file is the start of every re-plan and stays as it is")
    from .solve import (  # CasADi: only when solving
        replan_minimum_time,
        sensitivity,
        solve_minimum_time,
        solve_minimum_time_fatrop,
    )

    try:
        params = load_parameters(args.params, payload_mass=args.payload)
        if args.replan:
            result = replan_minimum_time(params, load_trajectory(), args.intervals, args.degree,
                                         verbose=not args.quiet)
        else:
            solve = solve_minimum_time_fatrop if args.fatrop else solve_minimum_time
            result = solve(params, n_intervals=args.intervals, degree=args.degree, verbose=not args.quiet)
        replay = annotate_with_replay(result, params)
        sens = None
        if args.sensitivity:
            sens = sensitivity(result, params, verbose=not args.quiet)
            result.metadata["sensitivity"] = sens
    except TrajectoryError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    json_path = save_trajectory(result, args.out)
    print(f"wrote {args.out} and {json_path}")
    if args.plot:
        print(f"wrote {plot_trajectory(result, args.plot, params)}")
    print(_report(result, replay, sens))
    return 0
