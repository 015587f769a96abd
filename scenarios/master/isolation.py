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


def isolated_instances(isolate: str, instances, foreign) -> list[str]:
    """The instances that run each in a process of their own: every one of `instances` with `isolate` "all",
    the `foreign` ones (:func:`foreign_instances`) with "foreign"; :class:`ScenarioError` for another `isolate`.
    Decided once, when a run is planned (:func:`scenarios.run.setup.prepare`)."""
    if isolate not in ISOLATE:
        raise ScenarioError(f"--isolate: one of {list(ISOLATE)}, got {isolate!r}")
    return list(instances) if isolate == "all" else list(foreign)
