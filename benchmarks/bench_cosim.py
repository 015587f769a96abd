"""Real-time factor of one full three-FMU co-simulation (plant + sensors + controller, 1 ms).

Runs one case of a scenario (default: table2, no payload, no noise) through
the fmpy master. Loading the FMUs (unpacking, Numba compilation) is a
start-up cost, reported separately; the timed runs reuse the loaded FMUs
(``fmi2Reset`` between runs), as the scenario runner and sweeps do.

    python benchmarks/bench_cosim.py [SCENARIO] [--case KEY] [--repeats N] [--algorithm jacobi]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from scenarios.config import load_scenario
from scenarios.master import cosim as master
from scenarios.run.fmus import DEFAULT_FMU_DIR
from scenarios.run.runner import simulate_case
from scenarios.run.setup import prepare


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenario", nargs="?", default="table2")
    ap.add_argument("--case", default=None)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR, help="built FMUs (built there if missing)")
    ap.add_argument("--algorithm", choices=master.ALGORITHMS, default="gauss-seidel")
    args = ap.parse_args()
    sc = load_scenario(args.scenario)
    case = next(c for c in sc.cases if args.case in (None, c.key))
    setup = prepare(sc, args.fmu_dir, names=case.fmus or None)
    t0 = time.perf_counter()
    with setup.open_master(args.algorithm) as m:
        load = time.perf_counter() - t0
        t0 = time.perf_counter()
        out, _ = simulate_case(setup, m, case.parameters)
        first = time.perf_counter() - t0
        if out["status"] != "ok":
            raise SystemExit(f"run failed: {out['message']}")
        walls = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            simulate_case(setup, m, case.parameters)
            walls.append(time.perf_counter() - t0)
    best = min(walls)
    n = setup.n_steps
    simulated = n * sc.step_size
    print(f"{sc.name}:{case.key}: {n} steps of {sc.step_size * 1e3:g} ms ({simulated:.3f} s simulated), "
          f"{args.algorithm}, recording {len(setup.record)} signals")
    print(f"  load FMUs: {load:.2f} s; first run (Numba compilation): {first:.2f} s")
    print(f"  wall time per run: best {best:.3f} s of {args.repeats} (all: {', '.join(f'{w:.3f}' for w in walls)})")
    print(f"  per 1 ms step: {best / n * 1e6:.0f} µs for all three FMUs and the master")
    print(f"  real-time factor: {simulated / best:.1f}x (goal: 10x)")


if __name__ == "__main__":
    main()
