"""Which of the paper's columns a run is compared with: chosen by the run's actual parameters, never by its case's key.

The paper's Tables 1-3 (``scenarios/paper_tables.toml``) give one column per case of the scenario that names the
table. A case run with ``--set`` overrides is a different experiment: ``--set plant.payload_mass=0.275`` on case
``none`` is the paper's tip case, not its no-payload one. :func:`paper_columns` therefore matches each case's
parameters and FMUs, as the run applies them, against every case of the unmodified scenario file, and gives the
paper's column of the case they equal; when none does, the run has no paper column (left out, not guessed).
"""

from __future__ import annotations

import tomllib

from scenarios.config import SCENARIO_DIR, Scenario, load_scenario

#: The paper's tables, compared with, never copied into our outputs.
PAPER_FILE = SCENARIO_DIR / "paper_tables.toml"


def paper_tables() -> dict:
    """The content of :data:`PAPER_FILE`."""
    return tomllib.loads(PAPER_FILE.read_text())


def _effective(case, overrides: dict[str, dict] | None) -> tuple[dict, dict]:
    params = {inst: dict(values) for inst, values in case.parameters.items()}
    for inst, values in (overrides or {}).items():
        params[inst] = {**params.get(inst, {}), **values}
    return params, dict(case.fmus)


def paper_columns(scenario: Scenario, overrides: dict[str, dict] | None = None,
                  paper: dict | None = None) -> dict[str, tuple[str, object]]:
    """{case key: (the paper's case key, its column)} for the cases of `scenario` run with `overrides`.

    Parameters
    ----------
    scenario : Scenario
        The scenario as run (perhaps only some of its cases), before `overrides`.
    overrides : dict, optional
        ``--set`` values, {instance: {variable: value}}, applied last to every case.
    paper : dict, optional
        The paper's tables (default :func:`paper_tables`).

    Returns
    -------
    dict
        Only the cases whose parameters and FMUs equal those of a case of the scenario file that the paper's table
        reports (the column is a list of the six metrics, or ``{"unbounded": true}``). A case with no match is
        absent: print no paper column for it.
    """
    if not scenario.paper_table:
        return {}
    table = (paper if paper is not None else paper_tables()).get(scenario.paper_table) or {}
    try:
        shipped = load_scenario(scenario.path)
    except Exception:  # noqa: BLE001 - the file changed under the run: compare with nothing rather than guess
        return {}
    reported = {c.key: _effective(c, None) for c in shipped.cases if c.key in table}
    out = {}
    for case in scenario.cases:
        actual = _effective(case, overrides)
        match = next((k for k in sorted(reported, key=lambda k: k != case.key) if reported[k] == actual), None)
        if match is not None:
            out[case.key] = (match, table[match])
    return out
