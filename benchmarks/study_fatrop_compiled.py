"""Study: FATROP's re-plan with its NLP functions compiled to C, beside the interpreted ones (issue 32 item 1).

The re-plan (:func:`flexarm.trajectory.replan_minimum_time`, payload 0.275 kg, from the committed file) spends its
CPU in three places: making the solver (CasADi's AD of the stage-form NLP), evaluating the Hessian and the
constraint Jacobian through CasADi's virtual machine, and FATROP's own iterations. This study asks how much
compiling the NLP's functions takes off: it makes the solver as the re-plan does, writes its functions as C
(``generate_dependencies``), compiles them with gcc, loads them back (``nlpsol(..., "nlp.so")``) and re-plans
with both solvers in one run. It prints the CPU time of each step, the evaluation time per function and the
iterations, and checks that both re-plans give the same t_f and torques (to FATROP's tolerance).

Measured once (2026-12-05, 2 cores, idle, ``-O1``): C file 50 MB, gcc 527 CPU-s, library 28 MB; loading it 5.6
CPU-s; the re-plan solves in 11.1 CPU-s (Hessian 2.1 s, Jacobian 1.7 s of it) against 19.3 CPU-s interpreted
after 13.8 CPU-s making: a re-plan of about 17 CPU-s once the library is built, where the goal is 10. What is
left is FATROP's own work (about 7 CPU-s for 93 iterations), so compiling alone does not reach the goal.

    python benchmarks/study_fatrop_compiled.py [--opt -O1] [--keep DIR | --library DIR/replan_nlp.so]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

from flexarm import load_parameters
from flexarm.trajectory import load_trajectory, replan_minimum_time
from flexarm.trajectory import stage_form as sf


def cpu() -> float:
    """This process's and its finished children's CPU time (gcc included), s."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def timed_replan(loaded, committed, form):
    """The re-plan on `form`, with each solve's evaluation times: (result, CPU-s, [per-solve stats])."""
    stats, original = [], sf.solve_stage_form

    def solve(f, *args, **kwargs):
        result = original(f, *args, **kwargs)
        stats.append({k: v for k, v in f.solver.stats().items() if k.startswith("t_proc_nlp")})
        return result

    sf.solve_stage_form = solve
    try:
        c0 = cpu()
        result = replan_minimum_time(loaded, committed, form=form)
        return result, cpu() - c0, stats
    finally:
        sf.solve_stage_form = original


def report(label: str, result, seconds: float, stats: list[dict]) -> None:
    evals = {k.removeprefix("t_proc_nlp_"): sum(s.get(k, 0.0) for s in stats) for k in stats[0]}
    shown = ", ".join(f"{k} {v:.2f}" for k, v in evals.items() if v > 0.005)
    print(f"{label}: solving {seconds:.1f} CPU-s, {result.metadata['solver']['iterations']} iterations, "
          f"t_f = {result.t_f:.3f} s (continuous {result.metadata['t_f_continuous_s']:.7f} s); evaluations "
          f"{sum(evals.values()):.2f} CPU-s ({shown}), the rest FATROP's own", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--opt", default="-O1", help="gcc's optimisation level (default -O1)")
    ap.add_argument("--keep", type=Path, help="write the C file and the library here (default: a temporary folder)")
    ap.add_argument("--library", type=Path, help="a library an earlier run wrote (--keep) for this code and CasADi: "
                                                 "load it instead of writing and compiling the C again")
    args = ap.parse_args(argv)
    params, committed = load_parameters(), load_trajectory()
    loaded = params.with_payload(0.275)
    c0 = cpu()
    form = sf.stage_form(loaded)
    made = cpu() - c0
    print(f"interpreted solver made in {made:.1f} CPU-s", flush=True)
    interpreted, seconds, stats = timed_replan(loaded, committed, form)
    report("interpreted", interpreted, seconds, stats)
    library = args.library
    if library is None:
        folder = args.keep or Path(tempfile.mkdtemp(prefix="fatrop_compiled_"))
        folder.mkdir(parents=True, exist_ok=True)
        source, library = folder / "replan_nlp.c", folder / "replan_nlp.so"
        c0 = cpu()
        form.solver.generate_dependencies(source.name)
        os.replace(source.name, source)
        print(f"C written in {cpu() - c0:.1f} CPU-s: {source.stat().st_size / 1e6:.1f} MB", flush=True)
        c0 = cpu()
        subprocess.run(["gcc", "-fPIC", "-shared", args.opt, str(source), "-o", str(library)], check=True)
        print(f"gcc {args.opt}: {cpu() - c0:.1f} CPU-s, library {library.stat().st_size / 1e6:.1f} MB", flush=True)
    _, dims, lbg, ubg = sf.stage_nlp(loaded, form.N, form.d)
    c0 = cpu()
    solver = ca.nlpsol("replan", "fatrop", str(library),
                       {"structure_detection": "manual", **dims, "print_time": False,
                        "fatrop": {**sf.FATROP_OPTIONS, "max_iter": 300}})
    print(f"compiled solver loaded in {cpu() - c0:.1f} CPU-s", flush=True)
    compiled, seconds, stats = timed_replan(loaded, committed, sf.StageForm(solver, form.N, form.d, form.n, lbg, ubg))
    report("compiled", compiled, seconds, stats)
    same_grid = len(compiled.t) == len(interpreted.t)
    torque = np.max(np.abs(compiled.tau - interpreted.tau)) if same_grid else float("nan")
    print(f"compiled against interpreted: t_f {compiled.t_f:.3f} / {interpreted.t_f:.3f} s, torques at most "
          f"{torque:.2e} N·m apart", flush=True)
    return 0 if same_grid and torque < 1e-3 else 1


if __name__ == "__main__":
    raise SystemExit(main())
