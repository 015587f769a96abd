"""The generated blocks' machinery: block markers, the registry of block writers, the page's runs.

Below :mod:`scenarios.reports.results_page` (which runs the page and writes the files) and the modules that register
blocks (:mod:`scenarios.reports.cost_doc`, :mod:`scenarios.reports.findings_doc`, the page itself), so that each
of them imports this module and none imports another in a circle.
"""

from __future__ import annotations

import re
import tempfile
import tomllib
from collections.abc import Callable
from pathlib import Path

from scenarios.config import SCENARIO_DIR, load_scenario
from scenarios.run.fmus import DEFAULT_FMU_DIR
from scenarios.run.runner import CaseResult, run_scenario
from scenarios.run.setup import REPO

__all__ = ["BLOCKS", "REPO", "PageRuns", "ResultsPageError", "block", "rewrite_block", "splice_blocks"]


class ResultsPageError(Exception):
    """A scenario of the page ended with an FMU error: nothing is written."""


# ------------------------------------------------------------------------------------ generated blocks
_MARKED = re.compile(r"<!-- results-page:([\w.-]+) begin[^>]*-->(.*?)<!-- results-page:\1 end -->", re.S)
_BEGIN_ANY = re.compile(r"<!-- results-page:([\w.-]+) begin")


class PageRuns(dict):
    """The page's runs (name -> (scenario, results)) and, on request, more runs for the blocks (cached)."""

    def __init__(self, runs: dict[str, tuple], fmu_dir: Path = DEFAULT_FMU_DIR, progress: bool = False):
        super().__init__(runs)
        self.fmu_dir, self.progress = fmu_dir, progress
        self._extra: dict[tuple, list[CaseResult]] = {}

    def metrics(self, name: str, algorithm: str | None = None) -> dict[str, dict | None]:
        """Case key -> metrics (None for a run that did not end ok) of scenario `name`, stepped by `algorithm`
        (None: the scenario's own, from the page's runs)."""
        results = self[name][1] if algorithm is None else self.run(name, algorithm)
        return {r.key: r.metrics for r in results}

    def run(self, name: str, algorithm: str) -> list[CaseResult]:
        """Scenario `name` once more with another stepping `algorithm` (once per page)."""
        if (name, algorithm) not in self._extra:
            if self.progress:
                print(f"results page: running {name} with {algorithm} stepping", flush=True)
            with tempfile.TemporaryDirectory(prefix="flexarm-results-page-") as tmp:
                results = run_scenario(load_scenario(name), Path(tmp), self.fmu_dir, progress=False,
                                       algorithm=algorithm)
            failed = [f"{r.key}: {r.message}" for r in results if r.status == "error"]
            if failed:
                raise ResultsPageError(f"results page: {name} ({algorithm}) had FMU errors: {'; '.join(failed)}")
            self._extra[(name, algorithm)] = results
        return self._extra[(name, algorithm)]


#: Generated block name -> function of the page's runs (:class:`PageRuns`) returning its Markdown.
BLOCKS: dict[str, Callable[[PageRuns], str]] = {}


def block(name: str):
    """Register the decorated function as the writer of block `name` (see the module's docstring)."""
    def register(fn):
        if name in BLOCKS:
            raise ValueError(f"results-page block {name!r} is registered twice")
        BLOCKS[name] = fn
        return fn
    return register


def splice_blocks(text: str, blocks: dict[str, str], where: str = "text") -> str:
    """`text` with every marked block replaced by ``blocks[name]``; a marker without a text in `blocks`, or a
    begin marker without its end, is refused (:class:`ResultsPageError` naming it and `where`)."""
    opened = _BEGIN_ANY.findall(text)
    closed = [m.group(1) for m in _MARKED.finditer(text)]
    if sorted(opened) != sorted(closed):
        raise ResultsPageError(f"{where}: a results-page begin marker without its end marker "
                               f"({sorted(set(opened) - set(closed)) or opened})")
    unknown = sorted(set(closed) - set(blocks))
    if unknown:
        raise ResultsPageError(f"{where}: unknown generated block(s) {unknown}; known: {sorted(blocks)}")

    def replace(m: re.Match) -> str:
        body = blocks[m.group(1)]
        begin = m.group(0)[:m.group(0).index("-->") + 3]
        end = f"<!-- results-page:{m.group(1)} end -->"
        return f"{begin}\n{body}\n{end}" if "\n" in body or m.group(2).startswith("\n") else f"{begin}{body}{end}"

    return _MARKED.sub(replace, text)


def rewrite_block(doc: Path, name: str, body: str) -> Path:
    """Rewrite block `name` of the document `doc` with `body` (atomically), every other block as committed: what
    a benchmark's ``--write`` does after recording its file (the page renders the same block from that file)."""
    from flexarm.provenance import write_atomic

    text = doc.read_text(encoding="utf-8")
    blocks = {m.group(1): m.group(2).strip("\n") for m in _MARKED.finditer(text)}
    blocks[name] = body
    return write_atomic(doc, splice_blocks(text, blocks, str(doc.relative_to(REPO))))


def _paper() -> dict:
    return tomllib.loads((SCENARIO_DIR / "paper_tables.toml").read_text())


def _m(runs: PageRuns, name: str, case: str, metric: str, algorithm: str | None = None) -> float:
    """One metric of one case; a case that did not end ok has no figure to publish (ResultsPageError)."""
    metrics = runs.metrics(name, algorithm).get(case)
    if metrics is None:
        raise ResultsPageError(f"results page: {name} case {case} has no metrics (not ok), a block needs them")
    return metrics[metric]
