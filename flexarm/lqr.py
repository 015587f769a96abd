"""LQR gain schedules along the minimum-time trajectory (paper sections 4-6, eq. 32): the command line.

``python -m flexarm.lqr`` designs every gain set (:mod:`flexarm.gain_sets`) on
every schedule (:mod:`flexarm.gain_schedule`), prints the diagnostics of
:mod:`flexarm.lqr_design` and, with ``--write``, writes the files in
``flexarm/data/gains/`` (and the LQG design and payload-bank files, :mod:`flexarm.lqg_design`,
:mod:`flexarm.lqg_bank`). This
module also re-exports the names of those three modules, so ``flexarm.lqr.X``
keeps working.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from .gain_schedule import (  # noqa: F401 - re-exported
    DEFAULT_GAIN_DIR,
    FILE_FORMAT,
    LINEARIZATIONS,
    REGENERATE_COMMAND,
    SCHEDULES,
    GainSchedule,
    StaleDataError,
    as_trajectory,
    default_trajectory_path,
    design_schedule,
    desired_states,
    load_desired,
    operating_times,
    read_design_metadata,
    trajectory_from_states,
)
from .gain_sets import (  # noqa: F401 - re-exported
    GAIN_SET_NAMES,
    WEIGHT_NAMES,
    GainError,
    canonical_name,
    is_discrete,
    resolve_gain_set,
    state_weight,
)
from .lqg_bank import BANK_SCHEDULES, design_bank
from .lqg_design import DEFAULT_LQG_DIR, design_lqg
from .lqr_design import (  # noqa: F401 - re-exported
    DEFAULT_DT,
    MEASURED_VELOCITY_STATES,
    OMEGA7_CHOICES,
    R_PAPER,
    GainDesign,
    design_gain,
    discrete_riccati_residual,
    discretize,
    effective_gain,
    gain_magnitudes,
    measurement_map,
    reduce_gain,
    riccati_residual,
    scaling_transform,
    zoh,
)
from .model import ArmModel
from .parameters import load_parameters
from .provenance import refuse_outside_checkout
from .provenance import sha256_file as file_sha256  # noqa: F401 - re-exported (older name)


# -- CLI -----------------------------------------------------------------------------------
def _table(schedules: list[GainSchedule]) -> str:
    head = (f"{'gain set':<15}{'sched':>7}{'sets':>5}{'max|K|':>10}{'|K|vel2':>9}{'max|KC|':>9}"
            f"{'max res':>10}{'rho full':>13}{'rho reduced':>13}{'rho impl':>13}{'maxRe full':>11}{'maxRe red':>11}")
    lines = [head, "-" * len(head)]
    for s in schedules:
        mag = gain_magnitudes(s.gains)
        eff = float(np.abs(effective_gain(s.gains)).max())
        lines.append(f"{s.name:<15}{s.schedule:>7}{len(s.times):>5}{mag['overall']:>10.4g}"
                     f"{mag['velocity_measured']:>9.3g}{eff:>9.4g}{s.residuals.max():>10.2e}"
                     f"{s.rho_full.max():>13.8f}{s.rho_reduced.max():>13.8f}{s.rho_implemented.max():>13.8f}"
                     f"{np.max(s.max_real_full):>11.4g}{np.max(s.max_real_reduced):>11.4g}")
    return "\n".join(lines)


def main(argv=None) -> int:
    """Command line: design the gain schedules, print diagnostics, optionally write the files."""
    ap = argparse.ArgumentParser(prog="python -m flexarm.lqr", description=__doc__.split("\n")[0])
    ap.add_argument("--trajectory", default=str(default_trajectory_path()),
                    help="trajectory .npz (default: flexarm/data/trajectory.npz)")
    ap.add_argument("--params", default=None, help="parameter file (default: the committed Sandia arm)")
    ap.add_argument("--sets", nargs="+", default=list(GAIN_SET_NAMES), help="gain-set names")
    ap.add_argument("--schedules", nargs="+", default=list(SCHEDULES), choices=list(SCHEDULES))
    ap.add_argument("--linearization", default="paper", choices=LINEARIZATIONS)
    ap.add_argument("--write", action="store_true", help="write <set>_<schedule>.npz/.json")
    ap.add_argument("--out", default=str(DEFAULT_GAIN_DIR), help="output directory for --write")
    ap.add_argument("--per-set", action="store_true", help="also print each operating point's numbers")
    ap.add_argument("--no-lqg", action="store_true", help="skip the LQG design files (flexarm.lqg_design)")
    ap.add_argument("--lqg-only", action="store_true", help="only the LQG design files (no LQR gain sets)")
    ap.add_argument("--lqg-out", default=str(DEFAULT_LQG_DIR), help="output directory of the LQG design files")
    args = ap.parse_args(argv)
    writes_package = args.write and (Path(args.out).resolve() == Path(DEFAULT_GAIN_DIR).resolve() or (
        not args.no_lqg and Path(args.lqg_out).resolve() == Path(DEFAULT_LQG_DIR).resolve()))
    if writes_package and refuse_outside_checkout("python -m flexarm.lqr", "the gain and LQG design files in "
                                                  "flexarm/data (or pass --out/--lqg-out and --no-lqg)"):
        return 2
    if not Path(args.trajectory).exists():
        print(f"error: trajectory file {args.trajectory} does not exist", file=sys.stderr)
        return 2
    model = ArmModel(load_parameters(args.params))
    traj, _, traj_sha = load_desired(args.trajectory)
    print(f"trajectory {args.trajectory} ({traj.t_f:.3f} s, sha256 {traj_sha[:12]}...), "
          f"linearization={args.linearization}, R = 10 I2")
    done = []
    for name in [] if args.lqg_only else args.sets:
        for sched in args.schedules:
            s = design_schedule(model, args.trajectory, name, sched, linearization=args.linearization)
            done.append(s)
            if args.write:
                s.save(args.out)
            if args.per_set:
                for k, tk in enumerate(s.times):
                    mag = gain_magnitudes(s.gains[k])
                    print(f"  {s.name} {sched} t={tk:6.3f} max|K|={mag['overall']:9.4g} res={s.residuals[k]:.2e} "
                          f"rho_full={s.rho_full[k]:.9f} rho_red={s.rho_reduced[k]:.9f}")
    if done:
        print(_table(done))
        print("\nmax|K|: full gain; |K|vel2: theta1/theta7 velocity columns; max|KC|: gain on the true state as "
              "implemented (reduced, rigid-bracket reconstruction, tachometers); res: relative Riccati residual "
              "(original coordinates, see module doc); rho: spectral radius of Phi - Gamma K (1 ms ZOH) with the "
              "full, reduced and implemented gain; maxRe: max Re eig(A - BK), continuous, full / reduced gain.")
    if args.write and done:
        print(f"wrote {len(done)} schedules to {args.out}")
    if not args.no_lqg:
        for sched in args.schedules:
            lqg = design_lqg(model, args.trajectory, sched)
            rho_f = max(np.abs(np.linalg.eigvals(p - m @ lqg.C @ p)).max() for p, m in zip(lqg.Phi, lqg.M))
            print(f"LQG {sched}: {len(lqg.times)} points, max |K| {np.abs(lqg.K).max():.4g}, max |M| "
                  f"{np.abs(lqg.M).max():.4g}, filter spectral radius {rho_f:.6f}")
            if args.write:
                print(f"  wrote {lqg.save(args.lqg_out)}")
            if sched in BANK_SCHEDULES:  # the multiple-model LQG's filters (controller_lqg estimator=payload_bank)
                bank = design_bank(model.params, trajectory=args.trajectory, schedule=sched)
                print(f"LQG bank {sched}: {len(bank.filters)} filters, payload masses {bank.masses.tolist()} kg")
                if args.write:
                    print(f"  wrote {bank.save(args.lqg_out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
