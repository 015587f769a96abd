"""Wall time of the minimum-time solve: cold (rigid warm-up included) and warm after a payload change.

Run: ``python benchmarks/bench_trajectory.py [--intervals N]``. Goals: cold < 60 s, warm < 10 s.
"""

from __future__ import annotations

import argparse
import time

from flexarm import load_parameters
from flexarm.trajectory import solve_minimum_time


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--intervals", type=int, default=200)
    ap.add_argument("--payload", type=float, default=0.275, help="payload of the warm-started re-solve, kg")
    args = ap.parse_args(argv)
    params = load_parameters()
    t0 = time.perf_counter()
    base = solve_minimum_time(params, n_intervals=args.intervals, verbose=False)
    cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    warm = solve_minimum_time(params.with_payload(args.payload), n_intervals=args.intervals, warm_start=base,
                              verbose=False)
    warm_time = time.perf_counter() - t0

    def iters(r):
        return r.metadata["solver"]["iterations"]

    print(f"cold solve  : {cold:6.1f} s (goal < 60 s), {iters(base)} iterations, t_f = {base.t_f:.3f} s")
    print(f"warm re-solve, payload {args.payload} kg: {warm_time:6.1f} s (goal < 10 s), {iters(warm)} iterations, "
          f"t_f = {warm.t_f:.3f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
