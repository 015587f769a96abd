"""The connect stage of a run: each FMU set's master opened once and every case probed before the first one runs.

A probe initialises the FMUs with a planned case's values and takes one communication step
(:meth:`scenarios.master.cosim.Master.probe`), so a step or a value an FMU refuses is reported with the FMU's
message (:class:`StepRefused`) before anything runs.
"""

from __future__ import annotations

from contextlib import contextmanager

from scenarios.config import ScenarioError
from scenarios.master import cosim as master


class StepRefused(ScenarioError):
    """An FMU refused a case's values or the communication step when probed, before anything ran."""


def probe_cases(setup, m: master.Master, cases) -> None:
    """Initialise and step once per planned case (:class:`scenarios.run.plan.PlannedCase`, values already
    checked); :class:`StepRefused` with the FMU's message."""
    for case in cases:
        outcome = m.probe(case.parameters, setup.scenario.step_size)
        if outcome.status == "error":
            raise StepRefused(f"{setup.scenario.path.name}: case {case.key}, communication step "
                              f"{setup.scenario.step_size:g} s: refused by {outcome.fmu} ({outcome.function} "
                              f"returned {outcome.fmu_status}): {outcome.fmu_message or outcome.message}")


@contextmanager
def connected(plan):
    """Open a master per FMU set of `plan` (:class:`scenarios.run.plan.RunPlan`) and probe its cases, set after
    set; yields [(FMU set, its planned cases, master)] in the plan's order and closes every master on leaving,
    also on error."""
    opened = []
    try:
        for fmu_set, cases in plan.groups:
            opened.append((fmu_set, cases, fmu_set.open_master(plan.algorithm)))
            probe_cases(fmu_set, opened[-1][2], cases)
        yield opened
    finally:
        for _, _, m in opened:
            m.close()
