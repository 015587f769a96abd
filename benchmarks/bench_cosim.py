"""Real-time factor of one full three-FMU co-simulation (plant + sensors + controller, 1 ms).

Runs the first case of a scenario (default: table2, no payload, no noise)
through the fmpy master, after one warm-up run (Numba compilation and FMU
unpacking are start-up costs, reported separately).

    python benchmarks/bench_cosim.py [SCENARIO] [--case KEY] [--repeats N]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from scenarios import master  # noqa: E402
from scenarios.config import load_scenario  # noqa: E402
from scenarios.runner import (  # noqa: E402
    DEFAULT_FMU_DIR,
    connect_by_name,
    desired_trajectory,
    resolve_fmus,
    run_length,
    start_parameters,
)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenario", nargs="?", default="table2")
    ap.add_argument("--case", default=None)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    sc = load_scenario(args.scenario)
    case = next(c for c in sc.cases if args.case in (None, c.key))
    paths = resolve_fmus(sc, DEFAULT_FMU_DIR)
    traj = desired_trajectory()
    n = run_length(sc, traj)
    params = {k: dict(v) for k, v in case.parameters.items()}
    params["plant"] = {**start_parameters(traj), **params.get("plant", {})}
    system = master.System(fmus=paths, order=sc.order, connections=connect_by_name(paths, sc.connections),
                           parameters=params, record=[("plant", "tip_x")], step_size=sc.step_size, n_steps=n)
    t0 = time.perf_counter()
    out = master.run(system)
    first = time.perf_counter() - t0
    if out["status"] != "ok":
        raise SystemExit(f"run failed: {out['message']}")
    walls = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        master.run(system)
        walls.append(time.perf_counter() - t0)
    best = min(walls)
    simulated = n * sc.step_size
    print(f"{sc.name}:{case.key}: {n} steps of {sc.step_size * 1e3:g} ms ({simulated:.3f} s simulated)")
    print(f"  first run (unpack, load, JIT compile): {first:.2f} s")
    print(f"  wall time per run: best {best:.3f} s of {args.repeats} (all: {', '.join(f'{w:.3f}' for w in walls)})")
    print(f"  per 1 ms step: {best / n * 1e6:.0f} µs for all three FMUs and the master")
    print(f"  real-time factor: {simulated / best:.1f}x (goal: 10x)")


if __name__ == "__main__":
    main()
