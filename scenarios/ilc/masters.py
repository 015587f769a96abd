"""The learned controller in other FMI masters: an ILC run's result, one self-contained FMU, run elsewhere.

An ILC run (:func:`scenarios.ilc.trials.run_ilc`) writes ``learned_controller.fmu``: the controller with the final
correction inside it as a resource. Here each of the run's evaluation cases becomes an SSP archive with that FMU in
the controller's place and the case's parameters (noise seed included) as the evaluation ran them
(:func:`learned_archives`), and each archive runs, with nothing set, in our master (the scenario's stepping),
libcosim and Ecos (:func:`learned_in_masters`). Each master's slew figures are compared with the run's own learned
figure: the FMU is the result only if every master reproduces it (issue 32: within 1 %).
"""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

from flexarm.provenance import sha256_file
from scenarios.config import Case, Scenario, ScenarioError
from scenarios.conformance import hosts
from scenarios.conformance.ssp import export_ssp
from scenarios.ilc.scenario import load_ilc
from scenarios.metrics import table_metrics
from scenarios.run.setup import desired_states

#: The masters an ILC result must be reproduced in (issue 32): ours steps as the scenario says; libcosim and Ecos
#: step Jacobi.
MASTERS = ("ours", "libcosim", "ecos")
#: Further masters a report shows beside them: our master stepping Jacobi (what libcosim and Ecos should give, the
#: stepping's own effect apart from theirs), OMSimulator (Gauss-Seidel, when installed:
#: :func:`scenarios.conformance.hosts.omsimulator`) and fmpy's ``simulate_ssp`` (no exchange before its first step:
#: the controller starts the slew a sample later, docs/control.md).
MORE_MASTERS = ("ours_jacobi", "omsimulator", "simulate_ssp")
#: Column names.
MASTER_NAMES = {"ours": "our master", "ours_jacobi": "our master, Jacobi", "libcosim": "libcosim", "ecos": "Ecos",
                "omsimulator": "OMSimulator", "simulate_ssp": "fmpy simulate_ssp"}
#: Relative difference from the learned figure within which a master reproduces it (issue 32).
TOLERANCE = 0.01
#: The figures compared: rms position (deg) and velocity (deg/s) error over the slew, as the ILC's table.
FIGURES = ("slew_rms_position_error", "slew_rms_velocity_error")


def learned_archives(scenario: Scenario, summary: dict, folder: Path, out_dir: Path) -> dict[str, Path]:
    """One SSP archive per evaluation case of an ILC run, with the run's learned controller in it.

    Parameters
    ----------
    scenario : Scenario
        The ILC scenario the run was made from (:func:`scenarios.ilc.scenario.load_ilc`; its file is checked
        against the run's SHA-256).
    summary : dict
        The run's summary (``evaluation.json``, :func:`scenarios.ilc.trials.run_ilc`'s return value), with its
        ``learned_controller`` and each evaluation case's ``parameters``.
    folder : Path
        The run's folder (where ``learned_controller.fmu`` is).
    out_dir : Path
        Where the archives go (``<out_dir>/<scenario>/<case>.ssp``).

    Returns
    -------
    dict
        case key -> archive.
    """
    if sha256_file(scenario.path) != summary["scenario_sha256"]:
        raise ScenarioError(f"{scenario.path}: not the scenario file the run in {folder} was made from (SHA-256 "
                            f"{sha256_file(scenario.path)[:12]}..., the run's {summary['scenario_sha256'][:12]}...)")
    learned = summary["learned_controller"]
    fmu = Path(folder) / learned["file"]
    n = summary["settings"].get("evaluate_samples", summary["samples"])
    cases = [Case(key, f"{key}, the learned controller", ev["parameters"],
                  fmus={**scenario.fmus, learned["instance"]: str(fmu)})
             for key, ev in summary["evaluation"].items() if ev.get("learned", {}).get("metrics")]
    return export_ssp(dataclasses.replace(scenario, samples=n, cases=cases), out_dir, kind=summary["fmu_kind"])


def reference_trajectory(summary: dict, folder: Path):
    """The slew the run tracked and compared with: the paper's, or the one re-planned for its payload (the run's
    ``payload_data/``, checked against the SHA-256 the run recorded)."""
    from flexarm.trajectory import load_trajectory

    ref = summary.get("reference", {})
    if ref.get("slew") != "re-planned":
        return load_trajectory()
    from flexarm.payload_data import read_payload_data

    data = read_payload_data(Path(folder) / "payload_data")
    if data.manifest["files"]["trajectory.npz"] != ref["trajectory_sha256"]:
        raise ScenarioError(f"{Path(folder) / 'payload_data'}: not the re-planned slew the run recorded")
    return data.trajectory()


def slew_figures(trace: hosts.Trace, slew_samples: int, trajectory=None) -> dict[str, float]:
    """:data:`FIGURES` of a master's run: the table metrics over samples 0 .. `slew_samples`, against `trajectory`
    (default the paper's slew)."""
    from flexarm.trajectory import load_trajectory

    n = slew_samples
    desired = desired_states(load_trajectory() if trajectory is None else trajectory, trace.time[:n + 1])
    m = table_metrics(trace.tau[:n], trace.theta[:n + 1], trace.omega[:n + 1], desired["theta"], desired["omega"])
    return {f"slew_{k}": float(m[k]) for k in ("rms_position_error", "rms_velocity_error")}


def learned_in_masters(name, summary: dict, folder: Path, masters=MASTERS) -> dict:
    """Run each evaluation case's archive (:func:`learned_archives`) in `masters` and compare with the run.

    Returns
    -------
    dict
        ``{"masters": [...], "fmpy_validate": [problems of the learned FMU], "cases": {case: {"learned": the run's
        figures, master: figures or {"error": message}, ...}}, "within": the masters reproducing every figure of
        every case within :data:`TOLERANCE`}``. A master that fails is an entry with its error, never a crash.
    """
    from fmpy.validation import validate_fmu

    scenario, _ = load_ilc(name)
    out = {"masters": list(masters), "tolerance": TOLERANCE, "cases": {},
           "fmpy_validate": validate_fmu(str(Path(folder) / summary["learned_controller"]["file"]))}
    traj = reference_trajectory(summary, folder)
    with tempfile.TemporaryDirectory(prefix="flexarm-ilc-masters-") as tmp:
        archives = learned_archives(scenario, summary, folder, Path(tmp) / "ssp")
        for key, ssp in archives.items():
            row = {"learned": {k: summary["evaluation"][key]["learned"]["metrics"][k] for k in FIGURES}}
            for master in masters:
                try:
                    if master == "ours":
                        trace = hosts.run_ours(ssp, scenario, summary["fmu_kind"], scenario.algorithm,
                                               Path(tmp) / f"{key}-ours")
                    elif master == "ours_jacobi":
                        trace = hosts.run_ours(ssp, scenario, summary["fmu_kind"], "jacobi",
                                               Path(tmp) / f"{key}-ours-jacobi")
                    elif master == "omsimulator":
                        trace = hosts.run_omsimulator(ssp, Path(tmp) / f"{key}-omsimulator")
                    else:
                        trace = {"libcosim": hosts.run_libcosim, "ecos": hosts.run_ecos,
                                 "simulate_ssp": hosts.run_simulate_ssp}[master](ssp)
                    row[master] = slew_figures(trace, summary["slew_samples"], traj)
                except Exception as exc:  # noqa: BLE001 - a master that fails is an entry, not a crash
                    row[master] = {"error": f"{type(exc).__name__}: {exc}"[:300]}
            out["cases"][key] = row
    out["within"] = [m for m in masters if out["cases"] and all(reproduces(row[m], row["learned"])
                                                                 for row in out["cases"].values())]
    return out


def reproduces(figures: dict, learned: dict) -> bool:
    """Whether a master's figures are within :data:`TOLERANCE` (relative) of the learned ones (an error: no)."""
    return "error" not in figures and all(abs(figures[k] - learned[k]) <= TOLERANCE * abs(learned[k])
                                          for k in FIGURES)


__all__ = ["FIGURES", "MASTERS", "MASTER_NAMES", "MORE_MASTERS", "TOLERANCE", "learned_archives",
           "learned_in_masters", "reference_trajectory", "reproduces", "slew_figures"]


def main(argv=None) -> int:
    """``python -m scenarios.ilc.masters SCENARIO [--out results]``: check an ILC run's learned controller in our
    master, libcosim and Ecos; prints a line per case and master; exit 0 when every master reproduces every figure
    within :data:`TOLERANCE` and `fmpy validate` finds nothing, 1 when not, 2 for a run that is not there."""
    import argparse
    import json
    import sys

    ap = argparse.ArgumentParser(prog="python -m scenarios.ilc.masters", description=main.__doc__.splitlines()[0])
    ap.add_argument("scenario", help="the ILC scenario the run was given (a shipped name or a file)")
    ap.add_argument("--out", type=Path, default=Path("results"), help="the run's --out (default ./results)")
    args = ap.parse_args(argv)
    scenario, _ = load_ilc(args.scenario)
    folder = args.out / scenario.name
    try:
        summary = json.loads((folder / "evaluation.json").read_text())
    except (OSError, ValueError) as exc:
        print(f"error: {folder / 'evaluation.json'}: {exc} (run `python -m scenarios run {args.scenario}` first)",
              file=sys.stderr)
        return 2
    if not summary.get("learned_controller") or not any("parameters" in ev for ev in summary["evaluation"].values()):
        print(f"error: {folder}: the run wrote no learned controller with its evaluation's parameters (stopped, no "
              "evaluation cases, or written by an older version: run it again)", file=sys.stderr)
        return 2
    try:
        res = learned_in_masters(args.scenario, summary, folder)
    except ScenarioError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for key, row in res["cases"].items():
        print(f"{key}: the run {row['learned'][FIGURES[0]]:.6g} deg / {row['learned'][FIGURES[1]]:.6g} deg/s")
        for m in res["masters"]:
            got = row[m]
            print(f"  {m:9s} " + (f"error: {got['error']}" if "error" in got else
                                  f"{got[FIGURES[0]]:.6g} deg / {got[FIGURES[1]]:.6g} deg/s "
                                  + ("within" if reproduces(got, row["learned"]) else "OUTSIDE")
                                  + f" {100 * TOLERANCE:g} %"))
    print("fmpy validate: " + ("; ".join(res["fmpy_validate"]) or "no problems"))
    return 0 if res["within"] == res["masters"] and not res["fmpy_validate"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
