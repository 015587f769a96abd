"""CPU time of the minimum-time solve: a cold solve, then a re-plan for a payload warm-started from it.

Run: ``python benchmarks/bench_trajectory.py [--payload KG] [--from-file] [--intervals N] [--fatrop-only]
[--no-interpreted]``.
After IPOPT's two solves, FATROP's cold solve (:func:`flexarm.trajectory.solve.solve_minimum_time_fatrop`: IPOPT's
rigid warm-up, then FATROP) against the committed file, and FATROP's re-plan
(:func:`flexarm.trajectory.replan_minimum_time`) from the committed file, each in a fresh process as a user runs it:
on the compiled, cached solver (:mod:`flexarm.trajectory.compiled`; a first run on a machine builds the cache and is
printed apart) beside the interpreted one, the two results compared, and the compiled one against IPOPT's re-plan
(``--fatrop-only``: only FATROP's).
Each figure is split into making the NLP and IPOPT solvers (``problem._cached_solver``, timed here)
and the rest per IPOPT iteration (almost all of it MUMPS factorising the KKT systems).
Goals (issue 32): warm re-plan <= 10 CPU-s, cold solve <= 60 CPU-s. CPU time (os.times, this
process and its children), not wall time: the machine is shared. Peak memory is the process's
largest resident set so far (it only grows: each figure covers everything before it).
The cold solve is compared with the committed trajectory (t_f, torques, angles): the same
problem solved again must give the same file to the solver's tolerance.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from flexarm import load_parameters
from flexarm.trajectory import load_trajectory, problem, solve_minimum_time
from flexarm.trajectory.warm import solution_from_trajectory


def _cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


_BUILD = [0.0]  # CPU-s spent making NLPs and IPOPT solvers (problem._cached_solver), summed


def _timed_solver_maker(make):
    def timed(*args, **kwargs):
        c0 = _cpu()
        try:
            return make(*args, **kwargs)
        finally:
            _BUILD[0] += _cpu() - c0

    return timed


problem._cached_solver = _timed_solver_maker(problem._cached_solver)


def _split(r, cpu: float, build: float) -> str:
    """'of which making solvers B CPU-s, the rest I CPU-s per iteration'."""
    its = r.metadata["solver"]["iterations"]
    return (f"of which making the NLP and solvers {build:.1f} CPU-s, the rest {(cpu - build) / its:.3f} CPU-s "
            "per iteration")


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def _stages(r) -> str:
    return ", ".join(f"{s['label']} {s['iterations']}" for s in r.metadata["solver"]["stages"])


def _report_warm(label: str, r, cpu: float, build: float) -> None:
    print(f"warm re-plan, {label}: {cpu:6.1f} CPU-s (goal <= 10), {r.metadata['solver']['iterations']} iterations "
          f"({_stages(r)}), t_f = {r.t_f:.3f} s (continuous {r.metadata['t_f_continuous_s']:.5f} s), "
          f"peak memory {_peak_mb():.0f} MB; {_split(r, cpu, build)}", flush=True)


def _replan_fatrop(loaded, committed, payload: float, interpreted: bool = True):
    """FATROP's re-plan from the committed file as a user's new process runs it, compiled and interpreted.

    Each re-plan runs in a fresh Python process (``--replan-child``), whose whole CPU time is the figure: imports,
    reading the file, the solver (loaded from the compiled-solver cache, :mod:`flexarm.trajectory.compiled`, or
    made anew when interpreted), both solves. A first run on a machine builds the cache first; that run is
    printed apart. Returns the compiled re-plan.
    """
    from flexarm.trajectory import compiled

    runs = [("compiled", {})] + ([("interpreted", {compiled.DISABLE_VARIABLE: "0"})] if interpreted else [])
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, env in runs:
            attempts = 2 if label == "compiled" else 1  # the first may build the cache
            for _ in range(attempts):
                out = Path(tmp) / f"{label}.npz"
                c0 = _cpu()
                done = subprocess.run([sys.executable, __file__, "--replan-child", "--payload", str(payload),
                                       "--out", str(out)], env={**os.environ, **env}, capture_output=True, text=True)
                cpu = _cpu() - c0
                if done.returncode != 0:
                    print(f"FATROP re-plan ({label}) failed: {done.stderr[-1500:]}", flush=True)
                    return None
                built = "cached in" in done.stderr
                r = load_trajectory(out)
                what = ("first run on this machine: compiling the interval functions and making the solver, then "
                        "the re-plan" if built else "the re-plan in a fresh process, everything included")
                print(f"FATROP re-plan, payload {payload} kg, from the committed file, {label}: {cpu:6.1f} CPU-s, "
                      f"{what} (goal <= 10); {r.metadata['solver']['iterations']} iterations ({_stages(r)}), "
                      f"t_f = {r.t_f:.3f} s (continuous {r.metadata['t_f_continuous_s']:.7f} s)", flush=True)
                results[label] = r
                if not built:
                    break
    entries = [e for e in compiled.cache_folder().glob("*") if e.is_dir()]
    if entries:
        sizes = ", ".join(f"{e.name} {sum(f.stat().st_size for f in e.iterdir()) / 1e6:.0f} MB" for e in entries)
        print(f"compiled-solver cache {compiled.cache_folder()}: {sizes}", flush=True)
    if "interpreted" in results:
        _compare("compiled against interpreted re-plan", results["compiled"], results["interpreted"])
    return results["compiled"]


def _replan_child(payload: float, out: str) -> int:
    """The re-plan as a new process runs it (``--replan-child``): writes the result to `out`."""
    from flexarm.trajectory import replan_minimum_time, save_trajectory

    result = replan_minimum_time(load_parameters().with_payload(payload), load_trajectory())
    save_trajectory(result, Path(out))
    return 0


def _cold_fatrop(params, committed, intervals: int):
    """FATROP's cold solve (IPOPT's rigid warm-up, then FATROP's two stages), against the committed file."""
    from flexarm.trajectory.solve import solve_minimum_time_fatrop

    c0 = _cpu()
    r = solve_minimum_time_fatrop(params, n_intervals=intervals)
    cpu = _cpu() - c0
    print(f"cold solve, FATROP after IPOPT's rigid warm-up: {cpu:6.1f} CPU-s (goal <= 60), making its solver "
          f"included, {r.metadata['solver']['iterations']} iterations ({_stages(r)}), t_f = {r.t_f:.3f} s "
          f"(continuous {r.metadata['t_f_continuous_s']:.7f} s), peak memory {_peak_mb():.0f} MB", flush=True)
    _compare("FATROP's cold solve against the committed file", r, committed)
    return r


def _compare(label: str, a, b) -> None:
    if len(a.t) != len(b.t):
        print(f"{label}: t_f {a.t_f:.3f} s against {b.t_f:.3f} s", flush=True)
        return
    dtau = np.abs(a.tau - b.tau).max(axis=0)
    print(f"{label}: continuous t_f {a.metadata['t_f_continuous_s'] - b.metadata['t_f_continuous_s']:+.2e} s, "
          f"largest torque difference {dtau[0]:.2e} / {dtau[1]:.2e} N·m, angles "
          f"{np.abs(a.theta - b.theta).max():.2e} rad", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--intervals", type=int, default=200)
    ap.add_argument("--payload", type=float, default=0.275, help="payload of the warm-started re-plan, kg")
    ap.add_argument("--from-file", action="store_true",
                    help="warm-start from the committed file (primal point only: the file holds no multipliers) "
                         "instead of the cold solve's primal-dual solution, and skip the cold solve")
    ap.add_argument("--fatrop-only", action="store_true",
                    help="only FATROP's cold solve and its re-plan from the committed file (no IPOPT solve of the "
                         "flexible arm)")
    ap.add_argument("--interpreted", action=argparse.BooleanOptionalAction, default=True,
                    help="also re-plan with the interpreted solver, beside the compiled one (about 25 CPU-s)")
    ap.add_argument("--replan-child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.replan_child:
        return _replan_child(args.payload, args.out)
    params = load_parameters()
    committed = load_trajectory()
    loaded = params.with_payload(args.payload)
    if args.fatrop_only:
        _cold_fatrop(params, committed, args.intervals)
        _replan_fatrop(loaded, committed, args.payload, args.interpreted)
        return 0
    if args.from_file:
        c0, b0 = _cpu(), _BUILD[0]
        guess = solution_from_trajectory(committed, params)
        warm = solve_minimum_time(loaded, n_intervals=args.intervals, warm_start=guess, verbose=False)
        _report_warm(f"payload {args.payload} kg, from the committed file", warm, _cpu() - c0, _BUILD[0] - b0)
        return 0
    c0, b0 = _cpu(), _BUILD[0]
    cold = solve_minimum_time(params, n_intervals=args.intervals, verbose=False)
    cold_cpu = _cpu() - c0
    print(f"cold solve: {cold_cpu:6.1f} CPU-s (goal <= 60), {cold.metadata['solver']['iterations']} iterations "
          f"({_stages(cold)}), t_f = {cold.t_f:.3f} s (continuous {cold.metadata['t_f_continuous_s']:.6f} s), "
          f"peak memory {_peak_mb():.0f} MB; {_split(cold, cold_cpu, _BUILD[0] - b0)}", flush=True)
    status = 0
    if len(cold.t) != len(committed.t):
        print(f"against the committed file: t_f {cold.t_f:.3f} s differs from {committed.t_f:.3f} s")
        status = 1
    else:
        dtau = np.abs(cold.tau - committed.tau).max(axis=0)
        dtf = cold.metadata["t_f_continuous_s"] - committed.metadata["t_f_continuous_s"]
        dth = np.abs(cold.theta - committed.theta).max()
        print(f"against the committed file: continuous t_f {dtf:+.2e} s, largest torque difference "
              f"{dtau[0]:.2e} / {dtau[1]:.2e} N·m, angles {dth:.2e} rad", flush=True)
    c0, b0 = _cpu(), _BUILD[0]
    warm = solve_minimum_time(loaded, n_intervals=args.intervals, warm_start=cold, verbose=False)
    _report_warm(f"payload {args.payload} kg, from the cold solve", warm, _cpu() - c0, _BUILD[0] - b0)
    if args.intervals == committed.metadata["discretisation"]["intervals"]:
        _cold_fatrop(params, committed, args.intervals)
        fatrop = _replan_fatrop(loaded, committed, args.payload, args.interpreted)
        if fatrop is not None:
            _compare("FATROP's re-plan against IPOPT's", fatrop, warm)
    return status


if __name__ == "__main__":
    raise SystemExit(main())
