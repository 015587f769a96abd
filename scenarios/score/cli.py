"""``python -m scenarios score CONTROLLER | --write-baseline``: options, and what the command does."""

from __future__ import annotations

import re
from pathlib import Path

from ..config import ScenarioError
from . import baseline, battery


def add_parser(sub, default_out: Path, default_fmu_dir: Path, kind_options) -> None:
    score = sub.add_parser("score", help="score a controller on the fixed battery (Tables 1-3, robustness, "
                                         "Gauss-Seidel and Jacobi) beside our baselines: one HTML page + JSON")
    score.add_argument("controller", nargs="?",
                       help=f"a .fmu path (relative to the current directory) or one of our baselines "
                            f"{[c.name for c in battery.BASELINES]}")
    score.add_argument("--out", type=Path, default=default_out / "score",
                       help="results folder (default: ./results/score); the page goes to OUT/<controller>/")
    score.add_argument("--fmu-dir", type=Path, default=default_fmu_dir, help="where built FMUs live")
    kind_options(score)
    score.add_argument("--set", dest="sets", action="append", default=[], metavar="controller.VARIABLE=VALUE",
                       help="set a controller parameter in every run (e.g. controller.kd1=6; repeatable); the "
                            "battery fixes the plant's and the sensors'")
    score.add_argument("--workers", type=int, help="local Dask cluster: worker processes (default: the cores)")
    score.add_argument("--scheduler", help="address of a running Dask scheduler, e.g. tcp://host:8786")
    score.add_argument("--serial", action="store_true", help="run in this process, no Dask")
    score.add_argument("--quiet", action="store_true", help="no progress lines")
    score.add_argument("--write-baseline", action="store_true",
                       help="run our baselines through the battery (native FMUs) and rewrite "
                            "scenarios/score/baseline.json (needs a checkout)")


def controller_of(value: str) -> battery.Controller:
    """A .fmu path (made absolute) or a baseline name; ScenarioError naming the allowed values."""
    if value.endswith(".fmu"):
        path = Path(value).expanduser().resolve()
        if not path.is_file():
            raise ScenarioError(f"controller: no FMU at {path}")
        return battery.Controller(re.sub(r"\W", "_", path.stem) or "controller", str(path))
    try:
        return battery.named(value)
    except ValueError as exc:
        raise ScenarioError(str(exc)) from None


def with_sets(controller: battery.Controller, sets: list[str]) -> battery.Controller:
    """`controller` with ``--set controller.VARIABLE=VALUE`` added to its parameters (checked against its model
    description before anything runs); another instance is refused, naming it."""
    from dataclasses import replace

    from ..config import parse_assignment

    extra = {}
    for text in sets:
        inst, var, value = parse_assignment(text)
        if inst != "controller":
            raise ScenarioError(f"--set {text}: the score sets the controller's parameters only (controller.VARIABLE"
                                f"=VALUE); the battery fixes {inst}'s, got {inst!r}")
        extra[var] = value
    if not extra:
        return controller
    return replace(controller, parameters={**controller.parameters, **extra})


def main(args) -> int:
    from scenarios.run.outdir import run_folder

    from .page import render
    from .run import run_battery

    kw = dict(workers=args.workers, scheduler=args.scheduler, serial=args.serial, progress=not args.quiet)
    if args.write_baseline:
        from flexarm.provenance import checkout_refusal

        refusal = checkout_refusal("python -m scenarios score --write-baseline", "scenarios/score/baseline.json")
        if refusal:
            raise ScenarioError(refusal)
        results = {c.name: run_battery(c, "native", args.fmu_dir, args.native_fmu_dir, **kw)
                   for c in battery.BASELINES}
        print(f"wrote {baseline.write(results, 'native')}")
        return 0
    if not args.controller:
        raise ScenarioError("score: a controller (a .fmu path or one of our baselines "
                            f"{[c.name for c in battery.BASELINES]}), or --write-baseline")
    controller = with_sets(controller_of(args.controller), args.sets)
    base = baseline.load()  # refused before anything runs when it was made with another battery
    kind = args.kind or "python"
    result = run_battery(controller, kind, args.fmu_dir, args.native_fmu_dir, **kw)
    from flexarm.provenance import git_commit, package_version, sha256_file

    meta = {"fmu": Path(controller.fmu).name if controller.fmu.endswith(".fmu") else controller.fmu,
            "fmu_sha256": sha256_file(controller.fmu) if controller.fmu.endswith(".fmu") else None,
            "kind": kind, "wall_time_s": round(result["wall_time_s"], 2), "workers": result["workers"],
            "commit": git_commit(), "version": package_version(), "baseline_commit": base.get("commit"),
            "baseline_kind": base.get("kind")}
    with run_folder(args.out, controller.name) as folder:
        render(controller.name, result, base, meta, folder)
    out = Path(args.out) / controller.name
    cases = result["cases"]
    bad = {k: r for k, r in cases.items() if r["status"] != "ok"}
    print(f"score {controller.name}: {len(cases) - len(bad)} of {len(cases)} runs stable "
          f"({result['wall_time_s']:.1f} s, {result['workers'] or 'no'} Dask workers)")
    for k, r in bad.items():
        print(f"   {k}: {r['status']}" + (f" ({r['message']})" if r.get("message") else ""))
    print(f"   page: {out / 'index.html'}\n   numbers: {out / 'score.json'}")
    return 1 if any(r["status"] == "error" for r in cases.values()) else 0
