"""Energy error of each plant scheme on the free arm over 60 s (issue 24's acceptance figure).

Free arm (zero torque, ζ = 0), all nine flexible modes excited and both joints turning
(:func:`scenarios.reports.scheme_accuracy_parts.free_arm_state`); prints, per scheme, the largest relative energy
error |E/E₀ − 1| and its linear trend (1/s) over the horizon, and the CPU time. The generated table of
docs/model.md comes from the same function (``python -m scenarios.reports.scheme_accuracy --write --part energy``).

Usage: ``python benchmarks/bench_energy.py [--seconds 60] [--scheme gauss:4 ...]`` (Gauss at 4 substeps per
ms over 60 s: a few minutes; the reference, RK4 at 2.5 µs: about ten times longer).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    from scenarios.reports.scheme_accuracy_parts import energy_error

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--scheme", action="append", help="integrator:substeps (default gauss:2, gauss:4, rodas4:2)")
    args = ap.parse_args()
    schemes = args.scheme or ["gauss:2", "gauss:4", "rodas4:2"]
    print(f"free arm, {args.seconds:g} s: largest |E/E0 - 1|, its trend, CPU time")
    for item in schemes:
        integrator, _, sub = item.partition(":")
        r = energy_error(integrator, int(sub or 2), args.seconds)
        if "refused" in r:
            print(f"  {item:14s} refused: {r['refused']}")
            continue
        print(f"  {item:14s} max {r['max_abs']:.3e}   trend {r['trend_per_s']:+.2e} 1/s   "
              f"final {r['final']:+.3e}   ({r['cpu_s']:.0f} s CPU)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
