"""docs/model.md's plant cost table, rendered from ``docs/plant-step-cost.json`` (issue 24: cost per 1 ms step).

``python benchmarks/bench_plant_step.py --write`` times the steps and writes the JSON (date, commit, machine, load
average before and after) and the block; ``python -m scenarios results-page`` renders the same block from the
committed JSON and ``--check`` fails when the text differs. Neither re-times anything: timings on a shared machine
do not repeat, the render does.
"""

from __future__ import annotations

import json

from scenarios.reports.page_blocks import REPO, PageRuns, block, rewrite_block

COST_JSON = REPO / "docs" / "plant-step-cost.json"
DOC = REPO / "docs" / "model.md"
COLUMNS = (("library_us", "library `advance()`, Numba"), ("python_fmu_us", "Python plant FMU"),
           ("native_fmu_us", "native plant FMU (C)"))


def render(data: dict) -> str:
    """The table and the line that says where, when and under what load it was measured."""
    rows = data["rows"]
    base = rows["rodas4|2"]
    lines = ["| scheme, substeps per ms | " + " | ".join(label for _, label in COLUMNS) + " |",
             "|---|" + "---|" * len(COLUMNS)]
    for key, row in rows.items():
        integrator, sub = key.split("|")
        name = f"{integrator}, {sub}" + (" (RK4 at 2.5 µs)" if integrator == "reference" else "")
        lines.append(f"| {name} | " + " | ".join(f"{row[k]:.0f} µs ({row[k] / base[k]:.1f}×)" for k, _ in COLUMNS)
                     + " |")
    m = data["machine"]
    lines += ["", f"Median per 1 ms step after warm-up (FMUs: doStep and every output, through fmpy; in brackets "
              f"the ratio to rodas4 in the same column), measured {data['date'][:10]} at commit "
              f"`{data['commit'][:12]}` on {m['cpus']} CPUs ({m['processor']}, Python {m['python']}), load "
              f"average {data['load_average_before'][0]:.1f} before and {data['load_average_after'][0]:.1f} after: "
              "on a shared machine the ratios hold better than the absolute figures."]
    return "\n".join(lines)


@block("plant-step-cost")
def _plant_step_cost(runs: PageRuns) -> str:
    return render(json.loads(COST_JSON.read_text(encoding="utf-8")))


def write_block(data: dict):
    """Rewrite docs/model.md's block from `data` (atomically); returns the path."""
    return rewrite_block(DOC, "plant-step-cost", render(data))
