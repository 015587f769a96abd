"""Sweep throughput: co-simulations per minute, in-process (serial) vs a Dask local cluster.

The same points both ways (default: Table 2's noisy case, full-length runs,
payload 0 / 0.1 / 0.2 / 0.3 kg x noise seeds 1-4 = 16 runs). Cold: including
start-up (loading the FMUs in this process; starting the cluster, its worker
processes and their FMUs). Warm: the same points again on the loaded FMUs /
running workers (excluding start-up), repeated with the two ways
interleaved, the best pass counting (other work on the machine only ever
slows a pass down). The metrics of the two ways are checked to agree bit
for bit.

    python benchmarks/bench_sweep.py [--workers 2] [--seeds 4] [--samples trajectory] [--repeats 3] [--fmu-dir DIR]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from scenarios.run.fmus import DEFAULT_FMU_DIR
from scenarios.sweep import close_loaded, iter_dask, iter_serial, load_sweep, local_cluster, plan_sweep

SWEEP = """
[sweep]
name = "bench"
scenario = "table2"
case = "noise"
samples = {samples}

[axes]
plant.payload_mass = [0.0, 0.1, 0.2, 0.3]
sensors.noise_seed = {{ range = [1, {seeds}] }}
"""


def _timed(label: str, n: int, run) -> tuple[float, list[dict]]:
    t0 = time.perf_counter()
    records = run()
    dt = time.perf_counter() - t0
    bad = [r for r in records if r["status"] != "ok"]
    per_run = sum(r["wall_time_s"] for r in records) / len(records)
    print(f"  {label:44s} {n:3d} runs in {dt:6.2f} s = {60 * n / dt:6.1f} runs/min (one run {per_run:.3f} s)"
          + (f"  ({len(bad)} not ok: {bad[0]['message'][:80]})" if bad else ""))
    return dt, records


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seeds", type=int, default=4, help="noise seeds per payload (4 payloads)")
    ap.add_argument("--samples", default="trajectory", help="run length: \"trajectory\" (full slew) or steps")
    ap.add_argument("--repeats", type=int, default=3, help="warm passes of each way, interleaved (best counts)")
    ap.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR)
    args = ap.parse_args()
    samples = '"trajectory"' if args.samples == "trajectory" else int(args.samples)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.toml"
        path.write_text(SWEEP.format(samples=samples, seeds=args.seeds))
        plan = plan_sweep(load_sweep(path), args.fmu_dir)
    points, n = plan.points, len(plan.points)
    print(f"{n} co-simulations (samples = {args.samples}), {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.2f} at the start")

    from distributed import Client

    cold_s, serial = _timed("serial, cold (incl. loading the FMUs)", n, lambda: list(iter_serial(plan, points)))
    t0 = time.perf_counter()
    cluster = local_cluster(args.workers)
    client = Client(cluster)
    start = time.perf_counter() - t0
    warm_s, warm_d = [], []
    try:
        cold_d, dask_recs = _timed(f"{args.workers} workers, cold (incl. loading the FMUs)", n,
                                   lambda: list(iter_dask(client, plan, points)))
        print(f"  {'+ starting the cluster and worker processes':44s}     {start:6.2f} s")
        cold_d += start
        for _ in range(args.repeats):  # interleaved, so that a busy spell on the machine hits both ways
            warm_s.append(_timed("serial, warm (FMUs loaded)", n, lambda: list(iter_serial(plan, points)))[0])
            warm_d.append(_timed(f"{args.workers} workers, warm (workers and FMUs loaded)", n,
                                 lambda: list(iter_dask(client, plan, points)))[0])
        client.run(close_loaded)
    finally:
        close_loaded()
        client.close()
        cluster.close()

    metrics = {r["key"]: r["metrics"] for r in serial}
    same = all(r["metrics"] == metrics[r["key"]] for r in dask_recs)
    bs, bd = min(warm_s), min(warm_d)
    print(f"metrics serial == Dask, bit for bit: {same}; load average {os.getloadavg()[0]:.2f} at the end")
    print(f"excluding start-up (best of {args.repeats}): serial {60 * n / bs:.1f} runs/min, "
          f"{args.workers} workers {60 * n / bd:.1f} runs/min, speed-up {bs / bd:.2f}x")
    print(f"including start-up (cold): serial {60 * n / cold_s:.1f} runs/min, "
          f"{args.workers} workers {60 * n / cold_d:.1f} runs/min, speed-up {cold_s / cold_d:.2f}x")


if __name__ == "__main__":
    main()
