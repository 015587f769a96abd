"""The native plant's step against the arithmetic floor of its own instruction mix (issue 34, item 1).

    python benchmarks/bench_plant_floor.py                       # 2000 steps of Table 2's slew, best of 5
    python benchmarks/bench_plant_floor.py --steps 500 --ghz 3.5 --fp-per-cycle 2

Builds the native plant FMU (linux64) if stale, then drives its shipped binary from C
(``benchmarks/plant_step_timing.c``: fmi2SetReal of the torques, fmi2DoStep of 1 ms, fmi2GetReal of every output)
with the feedforward torques of the committed slew, twice:

* timed, natively: the best wall time per step over the repeats;
* counted, under valgrind's callgrind (``--toggle-collect`` of the three functions, one pass): the instructions
  executed inside them and what they call, each classified by its mnemonic (``objdump -d`` of every object it ran
  in). FP arithmetic: ``[v](add|sub|mul|div|sqrt|min|max)(s|p)(s|d)`` and the fused ``vf[n]m(add|sub)``; a
  flop is one lane of one of those (two for a fused one).

The floor is the step's FP arithmetic instructions at ``--fp-per-cycle`` a cycle (2: two FP ports) and
``--ghz`` (3.5, the issue's figure; this machine's nominal clock is printed beside it, from /proc/cpuinfo, since
a virtual machine exposes no cycle counter). The goal is a step of at most 1.3 times that floor with no more
than 91.7k flops. Divisions and square roots, whose throughput is a few cycles each, are counted apart: a floor
that charges them ``--div-cycles`` each is printed too. Instruction counts are exact and repeatable; the time
is a wall time on a possibly loaded machine, so the best of the repeats is taken.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: FP arithmetic mnemonics (SSE2/AVX, double and single; fused multiply-add forms).
FP_ARITH = re.compile(r"^v?(add|sub|mul|div|sqrt|min|max)(s|p)(s|d)$")
FP_FUSED = re.compile(r"^vf(n?)m(add|sub)(132|213|231)?(s|p)(s|d)$")
GOAL_RATIO = 1.3
GOAL_FLOPS = 91.7e3


def nominal_ghz() -> float | None:
    """The first CPU's clock from /proc/cpuinfo ("cpu MHz"), GHz; None where there is none."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return None
    m = re.search(r"^cpu MHz\s*:\s*([0-9.]+)", text, re.M)
    return float(m.group(1)) / 1e3 if m else None


def lanes(mnemonic: str, operands: str) -> int:
    """Lanes of an FP arithmetic instruction: 1 scalar; packed 2/4 (double) or 4/8 (single) by register width."""
    if not re.search(r"p[sd]$", mnemonic):
        return 1
    wide = "ymm" in operands
    return (4 if wide else 2) if mnemonic.endswith("d") else (8 if wide else 4)


def classify(objects: list[str]) -> dict[str, dict[int, tuple[str, int, bool]]]:
    """Per object, address -> (mnemonic, flops, is FP arithmetic) of every instruction objdump finds."""
    out = {}
    for obj in objects:
        dis = subprocess.run(["objdump", "-d", "--no-show-raw-insn", obj], capture_output=True, text=True)
        table = {}
        for line in dis.stdout.splitlines():
            m = re.match(r"^\s*([0-9a-f]+):\s+(\S+)\s*(.*)$", line)
            if not m:
                continue
            addr, mnem, ops = int(m.group(1), 16), m.group(2), m.group(3)
            if FP_ARITH.match(mnem):
                table[addr] = (mnem, lanes(mnem, ops), True)
            elif FP_FUSED.match(mnem):
                table[addr] = (mnem, 2 * lanes(mnem, ops), True)
            else:
                table[addr] = (mnem, 0, False)
        out[obj] = table
    return out


def parse_callgrind(path: Path) -> dict[str, Counter]:
    """Self cost (Ir) per object and instruction address of a ``--dump-instr=yes`` callgrind file (the lines after
    ``calls=`` are a call's inclusive cost and are skipped; addresses may be relative to the previous line's)."""
    names: dict[str, str] = {}
    costs: dict[str, Counter] = {}
    obj, last, skip = None, 0, False
    for line in path.read_text().splitlines():
        if line.startswith(("ob=", "cob=")):  # an object's name is given at its first mention, in either
            m = re.match(r"c?ob=\((\d+)\)(?: (.*))?", line)
            if m.group(2):
                names[m.group(1)] = m.group(2)
            if line.startswith("ob="):
                obj = names[m.group(1)]
            continue
        if line.startswith("calls="):
            skip = True
            continue
        if not line or not (line[0] in "+-*" or line.startswith("0x")):
            continue
        parts = line.split()
        pos = parts[0]
        addr = last if pos == "*" else last + int(pos) if pos[0] in "+-" else int(pos, 16)
        last = addr
        if skip:
            skip = False
            continue
        if len(parts) >= 3 and obj is not None:
            costs.setdefault(obj, Counter())[addr] += int(parts[2])
    return costs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000, help="steps of the slew per timing and for the count")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ghz", type=float, default=3.5, help="clock the floor assumes, GHz (default 3.5)")
    ap.add_argument("--fp-per-cycle", type=float, default=2.0, help="FP arithmetic instructions a cycle (default 2)")
    ap.add_argument("--div-cycles", type=float, default=4.0,
                    help="cycles a division or square root occupies its unit, for the second floor (default 4)")
    args = ap.parse_args()
    for tool in ("valgrind", "objdump", "gcc"):
        if shutil.which(tool) is None:
            print(f"bench_plant_floor: needs {tool} on PATH (apt install valgrind binutils gcc)", file=sys.stderr)
            return 2

    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_native import plant_step_cost_in_c  # the timing host, compiled as there

    from flexarm.trajectory import load_trajectory
    from fmu_build import build_all, build_native_all

    print("building the plant FMUs (if stale) ...", flush=True)
    python = build_all(only=["plant"])
    native = build_native_all({"plant": python["plant"]})["plant"]
    traj = load_trajectory()
    torques = np.array([traj.tau[min(k, len(traj.tau) - 1)] for k in range(args.steps)])
    with tempfile.TemporaryDirectory(prefix="bench-floor-") as tmp:
        tmp = Path(tmp)
        print(f"timing {args.steps} steps from C, best of {args.repeats} ...", flush=True)
        per_step = plant_step_cost_in_c(native, tmp / "t", torques, args.repeats)
        exe = tmp / "t" / "plant_step_timing"
        run = [str(exe), *_host_arguments(native, tmp / "t")]
        print("counting the instructions under callgrind (one pass) ...", flush=True)
        out = tmp / "callgrind.out"
        subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", "--dump-instr=yes",
                        "--collect-atstart=no", "--toggle-collect=fmi2DoStep", "--toggle-collect=fmi2SetReal",
                        "--toggle-collect=fmi2GetReal", *run[:5], "1", *run[6:]],
                       check=True, capture_output=True)
        costs = parse_callgrind(out)
        tables = classify([o for o in costs if Path(o).exists()])  # the FMU's binary is in `tmp`
    n = args.steps
    total = fp = flops = divs = 0
    unknown = 0
    by_object = Counter()
    for obj, counter in costs.items():
        table = tables.get(obj, {})
        for addr, count in counter.items():
            total += count
            by_object[Path(obj).name] += count
            if addr not in table:
                unknown += count
                continue
            mnem, fl, is_fp = table[addr]
            if is_fp:
                fp += count
                flops += fl * count
                if "div" in mnem or "sqrt" in mnem:
                    divs += count
    floor = fp / n / args.fp_per_cycle / (args.ghz * 1e3)  # us
    floor_div = ((fp - divs) / args.fp_per_cycle + divs * args.div_cycles) / n / (args.ghz * 1e3)
    ghz = nominal_ghz()
    print(f"native plant, Table 2's slew, {n} steps of 1 ms (fmi2SetReal + fmi2DoStep + fmi2GetReal, from C):")
    print(f"  measured, best of {args.repeats}:       {per_step * 1e6:8.2f} us a step")
    print(f"  instructions (the three calls): {total / n / 1e3:7.1f} k a step"
          + (f" ({unknown / total:.1%} not classified)" if unknown else ""))
    for name, count in by_object.most_common():
        print(f"    in {name}: {count / n / 1e3:.1f} k")
    print(f"  FP arithmetic instructions:    {fp / n / 1e3:8.1f} k a step, of which {divs / n:.0f} divisions or "
          "square roots")
    print(f"  flops:                         {flops / n / 1e3:8.1f} k a step   (goal: <= {GOAL_FLOPS / 1e3:.1f} k)")
    print(f"  floor at {args.fp_per_cycle:g} FP instructions a cycle, {args.ghz:g} GHz: {floor:6.2f} us"
          f"  -> step / floor {per_step * 1e6 / floor:.2f}   (goal: <= {GOAL_RATIO})")
    print(f"  floor with divisions at {args.div_cycles:g} cycles each:  {floor_div:6.2f} us"
          f"  -> step / floor {per_step * 1e6 / floor_div:.2f}")
    print(f"  (this machine's nominal clock: {ghz:.2f} GHz)" if ghz else "  (no nominal clock in /proc/cpuinfo)")
    return 0


def _host_arguments(fmu: Path, folder: Path) -> list[str]:
    """plant_step_timing's arguments for the FMU unpacked in `folder` by plant_step_cost_in_c (its torques file)."""
    from fmpy import read_model_description

    md = read_model_description(str(fmu))
    var = {v.name: v for v in md.modelVariables}
    outs = ",".join(str(v.valueReference) for v in md.modelVariables if v.causality == "output")
    library = folder / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    return [str(library), (folder / "resources").as_uri(), md.guid, str(folder / "torques.txt"), "REPEATS",
            f"{var['tau1'].valueReference},{var['tau2'].valueReference}", outs]


if __name__ == "__main__":
    raise SystemExit(main())
