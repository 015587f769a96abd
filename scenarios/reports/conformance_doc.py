"""``python -m scenarios conformance``: the conformance matrix (:mod:`scenarios.conformance.matrix`) run, printed, and
with ``--write`` published into ``docs/conformance.json`` and the table of ``docs/masters-and-ssp.md`` (a block the
results page renders from the JSON); with it, the noise cases over many seeds (:mod:`scenarios.conformance.seeds`).
"""

from __future__ import annotations

import argparse
import json
import sys

from flexarm.provenance import write_atomic
from scenarios.conformance import hosts, seeds
from scenarios.conformance.matrix import (
    BLOCK,
    DOC_PATH,
    JSON_PATH,
    KINDS,
    MASTERS,
    PUBLISHED,
    REFERENCE,
    SCENARIOS,
    check,
    judge,
    render,
    run_matrix,
)
from scenarios.reports.page_blocks import block, splice_blocks


@block(BLOCK)
def matrix_block(runs) -> str:
    """The generated table of docs/masters-and-ssp.md, from docs/conformance.json (no run)."""
    return render(json.loads(JSON_PATH.read_text()))


@block(seeds.BLOCK)
def noise_seeds_block(runs) -> str:
    """The noise cases over many seeds, from docs/conformance.json (no run)."""
    doc = json.loads(JSON_PATH.read_text())
    if "noise_seeds" not in doc:
        return "(not run: `python -m scenarios conformance --noise-seeds --write`)"
    return seeds.render(doc["noise_seeds"])


def write(doc: dict) -> None:
    """The JSON and the table, each atomically (the document's other generated blocks are left as they are:
    ``results-page`` writes them)."""
    from scenarios.reports.page_blocks import _MARKED

    write_atomic(JSON_PATH, json.dumps(doc, indent=1) + "\n")
    text = DOC_PATH.read_text()
    blocks = {m.group(1): m.group(2).strip("\n") for m in _MARKED.finditer(text)}
    blocks[BLOCK] = render(doc)
    if "noise_seeds" in doc:
        blocks[seeds.BLOCK] = seeds.render(doc["noise_seeds"])
    write_atomic(DOC_PATH, splice_blocks(text, blocks, str(DOC_PATH)))


def _run_seeds(scenarios) -> dict | None:
    """:func:`scenarios.conformance.seeds.run_seeds`, or None after saying which run did not end ok."""
    try:
        return seeds.run_seeds(scenarios)
    except RuntimeError as exc:
        print(f"conformance: noise seeds: {exc}; nothing written", file=sys.stderr)
        return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m scenarios conformance", description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", action="append", choices=SCENARIOS, help="only these scenarios (repeatable)")
    ap.add_argument("--case", action="append", help="only cases with this key (repeatable)")
    ap.add_argument("--kind", action="append", choices=KINDS, help="only this FMU kind (repeatable)")
    ap.add_argument("--master", action="append", choices=list(MASTERS), help="only these masters (repeatable)")
    ap.add_argument("--workers", type=int, default=2, help="archives run at once (default 2)")
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true",
                      help="the published matrix (PUBLISHED: every native case, a part of the Python kind's) into "
                           "docs/ (no selection allowed)")
    mode.add_argument("--check", action="store_true", help="check the committed matrix against this checkout")
    mode.add_argument("--render", action="store_true", help="re-render the table from docs/conformance.json")
    ap.add_argument("--noise-seeds", action="store_true",
                    help=f"only the noise cases over seeds {seeds.SEEDS[0]}..{seeds.SEEDS[-1]} in our master, both "
                         "steppings (with --write: into docs/conformance.json, the matrix as committed); --write "
                         "alone runs them after the matrix")
    args = ap.parse_args(argv)
    selection = args.scenario or args.case or args.kind or args.master
    if args.noise_seeds:
        if args.case or args.kind or args.master or args.check or args.render:
            print("conformance: --noise-seeds runs every noise case of the scenarios (--scenario) on the native "
                  "FMUs in our master; --case, --kind, --master, --check and --render do not apply", file=sys.stderr)
            return 2
        if args.write and args.scenario:
            print("conformance: --noise-seeds --write runs every scenario of the matrix", file=sys.stderr)
            return 2
        problems = check() if args.write else []  # the seeds go beside the committed matrix: of this checkout
        for p in problems:
            print(f"{p} (it runs the noise seeds too)", file=sys.stderr)
        if problems:
            return 1
        data = _run_seeds(args.scenario or SCENARIOS)
        if data is None:
            return 1
        print(seeds.render(data))
        if args.write:
            write({**json.loads(JSON_PATH.read_text()), "noise_seeds": data})
        return 1 if seeds.verdicts(data)["outside"] else 0
    if args.write and selection:
        print("conformance: --write runs the published matrix; --scenario, --case, --kind and --master print a part",
              file=sys.stderr)
        return 2
    if args.check:
        problems = check()
        for p in problems:
            print(p, file=sys.stderr)
        return 1 if problems else 0
    if args.render:
        write(json.loads(JSON_PATH.read_text()))
        return 0
    masters = [REFERENCE, *[m for m in (args.master or MASTERS) if m != REFERENCE]]
    if "omsimulator" in masters and hosts.omsimulator() is None:
        print("conformance: OMSimulator is not installed (FLEXARM_OMSIMULATOR, or OMSimulator on the PATH): its "
              "column is left out", file=sys.stderr)
        masters.remove("omsimulator")
    doc = run_matrix(args.scenario or SCENARIOS, args.kind or KINDS, masters, args.case, workers=args.workers,
                     subset=PUBLISHED if args.write else None)
    print(render(doc))
    if args.write:
        doc["noise_seeds"] = _run_seeds(SCENARIOS)
        if doc["noise_seeds"] is None:
            return 1
        write(doc)
    bad = [1 for r in doc["rows"] for m in masters if m != REFERENCE
           and not judge(r["masters"][m], r["masters"][REFERENCE])]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
