"""``python -m scenarios conformance``: the conformance matrix (:mod:`scenarios.conformance.matrix`) run, printed, and
with ``--write`` published into ``docs/conformance.json`` and the table of ``docs/masters-and-ssp.md`` (a block the
results page renders from the JSON).
"""

from __future__ import annotations

import argparse
import json
import sys

from flexarm.provenance import write_atomic
from scenarios.conformance import hosts
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


def write(doc: dict) -> None:
    """The JSON and the table, each atomically (the document's other generated blocks are left as they are:
    ``results-page`` writes them)."""
    from scenarios.reports.page_blocks import _MARKED

    write_atomic(JSON_PATH, json.dumps(doc, indent=1) + "\n")
    text = DOC_PATH.read_text()
    blocks = {m.group(1): m.group(2).strip("\n") for m in _MARKED.finditer(text)}
    blocks[BLOCK] = render(doc)
    write_atomic(DOC_PATH, splice_blocks(text, blocks, str(DOC_PATH)))


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
    args = ap.parse_args(argv)
    selection = args.scenario or args.case or args.kind or args.master
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
        write(doc)
    bad = [1 for r in doc["rows"] for m in masters if m != REFERENCE
           and not judge(r["masters"][m], r["masters"][REFERENCE])]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
