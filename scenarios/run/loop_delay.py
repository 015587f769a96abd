"""What a run learns from the loop's sample indices (docs/control.md, "The loop measures its own delay").

The FMUs carry sample indices through the loop; a run records the controller's measured loop delay and the one
its law predicts over, and warns (in the run's JSON) when they contradict each other. The indices themselves
are bookkeeping, not signals: a run records none of them as one (an index also grows past the divergence limit
of a long run).
"""

from __future__ import annotations

import numpy as np

from flexarm.signals import FMUS, INDEX_GROUP, signals

#: Every sample-index signal name of the catalogue (group ``index``).
INDEX_NAMES = frozenset(s.name for f in FMUS for s in signals(f, groups=INDEX_GROUP))

#: A controller's measured loop delay and the one its law predicts over (docs/control.md, "The loop measures its
#: own delay"): recorded to check them, not written to the CSV.
LOOP_DELAY_OUTPUTS = ("loop_delay", "loop_delay_assumed")


def loop_delay_record(descriptions: dict, driver: str) -> list[tuple[str, str]]:
    """The torques' source's loop-delay outputs, when it has both (a user's controller need not)."""
    have = {v.name for v in descriptions[driver].modelVariables if v.causality == "output"}
    return [(driver, n) for n in LOOP_DELAY_OUTPUTS] if have.issuperset(LOOP_DELAY_OUTPUTS) else []


def loop_delay_warnings(out: dict, record: list[tuple[str, str]]) -> list[str]:
    """A warning when the controller's law predicted over another delay than the loop's (the signals removed).

    The automatic delay of controller_lqg needs up to two communication points to see a master's stepping
    (one to receive an indexed measurement, one to see it late), so two contradicting points are not warned.
    """
    if not record:
        return []
    (_, measured_name), (_, assumed_name) = record
    measured, assumed = (out["signals"].pop(f"{inst}.{name}") for inst, name in record)
    bad = np.flatnonzero((measured >= 0) & (measured != assumed))
    if len(bad) <= 2:
        return []
    i = bad[-1]
    return [f"loop delay: {record[0][0]} predicted over {assumed[i]:g} sample(s) where the loop delay measured from "
            f"the sample indices was {measured[i]:g} ({measured_name} vs {assumed_name}) at {len(bad)} of "
            f"{len(measured)} communication points, the last at t = {out['time'][i]:.6g} s: its torques were "
            "computed for a master stepping otherwise (set loop_delay_samples = -1, automatic)"]


#: The controller output that says when it started the slew (docs/control.md, "The slew starts when the loop is live").
SLEW_START_OUTPUT = "slew_start_index"


def slew_start_record(descriptions: dict, driver: str) -> list[tuple[str, str]]:
    """The torques' source's ``slew_start_index`` output, when it has one (a user's controller need not)."""
    have = {v.name for v in descriptions[driver].modelVariables if v.causality == "output"}
    return [(driver, SLEW_START_OUTPUT)] if SLEW_START_OUTPUT in have else []


def slew_start(out: dict, record: list[tuple[str, str]]) -> int:
    """Samples after t = 0 at which the controller started the slew (0 without the output; the signal removed).
    Raises ValueError when the controller's last value names no sample (a controller that lies: no figures)."""
    from flexarm.loop_index import slew_start_samples

    if not record:
        return 0
    (inst, name), = record
    values = out["signals"].pop(f"{inst}.{name}")
    done = values[np.isfinite(values)]
    return slew_start_samples(float(done[-1])) if len(done) else 0
