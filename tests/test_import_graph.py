"""The import graph of the project's Python (issue 33 item 3): folders import only downwards, and no module imports
itself back through others.

Folders, lowest first: ``flexarm`` (the physics library) < ``fmus`` (FMU sources) < ``fmu_build`` (build code) <
``scenarios`` (the master and the runs) < ``benchmarks``. Every import counts, those inside functions too: a lazy
import still makes the importing module depend on the imported one.

Inside ``scenarios`` the sub-packages are layered the same way (:data:`SCENARIO_LAYERS`): a module imports only
from its own sub-package or from a lower layer.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("flexarm", "fmus", "fmu_build", "scenarios", "benchmarks")
#: The parts of ``scenarios``, lowest first; a part is a sub-package or a top-level module (``scenarios`` itself is
#: its ``__init__``). Each tuple is one layer: its parts do not import one another.
SCENARIO_LAYERS = (
    ("scenarios", "config", "metrics", "results"),  # scenario files, the paper's metrics, result files
    ("analysis",),  # models a run is checked against
    ("master",),  # the co-simulation master and what drives FMUs
    ("run",),  # a scenario's run: FMUs chosen, set up, run, judged, written
    ("sweep", "conformance", "score"),  # many runs: sweeps, other masters, a controller's score
    ("ilc",),  # learning between trials (keeps its journal as a sweep does)
    ("reports",),  # generators of documents
    ("commands",),  # what each command does
    ("__main__",),  # the command line
)


def _modules() -> dict[str, Path]:
    mods = {}
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return mods


def import_graph() -> dict[str, set[str]]:
    """Module -> the project's modules it imports (the longest known prefix of each imported name)."""
    mods = _modules()

    def known(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for mod, path in mods.items():
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        out = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                out.update(filter(None, (known(a.name) for a in node.names)))
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")
                    base = ".".join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))
                for a in node.names:  # `from pkg import module` imports the module, `from mod import name` the mod
                    target = known(f"{base}.{a.name}") if f"{base}.{a.name}" in mods else known(base)
                    if target:
                        out.add(target)
        out.discard(mod)
        graph[mod] = out
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on, found, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return found


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """Every import of a module from a folder above its own (``importer -> imported``), sorted."""
    rank = {f: i for i, f in enumerate(FOLDERS)}
    return sorted(f"{m} -> {t}" for m, out in graph.items() for t in out
                  if rank[t.split(".")[0]] > rank[m.split(".")[0]])


def scenario_part(module: str) -> str:
    """The part of ``scenarios`` a module belongs to (its sub-package, or itself at the top level)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def upward_scenario_imports(graph: dict[str, set[str]], layers=SCENARIO_LAYERS) -> list[str]:
    """Every import inside ``scenarios`` of a part from a layer above or beside its own (``importer -> imported``)."""
    rank = {part: i for i, layer in enumerate(layers) for part in layer}
    out = []
    for m, targets in graph.items():
        if m.split(".")[0] != "scenarios":
            continue
        for t in targets:
            if t.split(".")[0] != "scenarios" or scenario_part(t) == scenario_part(m):
                continue
            if rank[scenario_part(t)] >= rank[scenario_part(m)]:
                out.append(f"{m} -> {t}")
    return sorted(out)


def test_every_part_of_scenarios_is_in_a_layer():
    parts = {scenario_part(m) for m in import_graph() if m.split(".")[0] == "scenarios"}
    assert parts == {p for layer in SCENARIO_LAYERS for p in layer}


def test_scenario_parts_import_only_downwards():
    assert upward_scenario_imports(import_graph()) == []


def test_folders_import_only_downwards():
    assert upward_imports(import_graph()) == []


def test_no_import_circle_between_modules():
    assert cycles(import_graph()) == []


def test_the_checks_can_fail():
    """A made-up graph with a circle and an upward import is caught; lazy imports inside functions count."""
    graph = {"flexarm.a": {"flexarm.b"}, "flexarm.b": {"flexarm.a", "scenarios.x"}, "scenarios.x": set()}
    assert cycles(graph) == [["flexarm.a", "flexarm.b"]]
    assert upward_imports(graph) == ["flexarm.b -> scenarios.x"]
    assert "fmu_build.native_build" in import_graph()["fmu_build.native"]  # imported inside a function there
    layers = (("scenarios",), ("run",), ("reports", "sweep"))
    graph = {"scenarios.run.a": {"scenarios.reports.b", "scenarios.run.c"},
             "scenarios.sweep.d": {"scenarios.reports.b"}, "scenarios.reports.b": {"scenarios.run.a"}}
    assert upward_scenario_imports(graph, layers) == ["scenarios.run.a -> scenarios.reports.b",
                                                      "scenarios.sweep.d -> scenarios.reports.b"]
