"""Which FMUs of a run go into a process of their own (scenarios/master/fmu_proxy.py), from the command line's
``--isolate`` and ``--step-timeout`` (docs/outcomes.md, "FMUs that are not ours")."""

from __future__ import annotations

from scenarios.config import Scenario, ScenarioError

#: ``--isolate``: which FMUs run in a process of their own: "foreign" (given as a .fmu path), or "all".
ISOLATE = ("foreign", "all")


def foreign_instances(scenario: Scenario, controller: str | None = None,
                      names: dict[str, str] | None = None) -> list[str]:
    """The instances whose FMU is given as a .fmu path (someone else's, or ours by path): not one of this
    project's FMU names, which this project builds and tests. `names` (instance -> FMU name or path) defaults
    to the scenario's ``[fmus]``; `controller` replaces the controller's."""
    names = dict(scenario.fmus if names is None else names)
    if controller is not None:
        names["controller"] = controller
    return sorted(inst for inst, name in names.items() if name.endswith(".fmu"))


def apply(setup, isolate: str, step_timeout: float):
    """Set a :class:`scenarios.run.setup.Setup`'s isolated instances (`isolate` "all": every one; "foreign": those
    it was prepared with) and step timeout; returns the setup."""
    if isolate not in ISOLATE:
        raise ScenarioError(f"--isolate: one of {list(ISOLATE)}, got {isolate!r}")
    if isolate == "all":
        setup.isolate = list(setup.paths)
    setup.step_timeout = step_timeout
    return setup
