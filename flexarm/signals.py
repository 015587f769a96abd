"""The signal catalogue: every input and output of the project's FMUs, from ``flexarm/data/signals.toml``.

One row per FMU variable (name, unit, description, causality, which FMU, group),
in each FMU's order. Everything that lists signals is generated from it: the
plant's observables order (:data:`flexarm.model.OBSERVABLE_NAMES`), the sensor
vectors (:data:`flexarm.sensors.TRUE_SIGNALS`, ``MEASURED_SIGNALS``), the FMUs'
input and output variables, the scenarios' record lists and the tables of
``docs/fmu-interface.md``. Standard library only (the FMUs read it too).
"""

from __future__ import annotations

import functools
import tomllib
from pathlib import Path
from typing import NamedTuple

#: The catalogue file.
SIGNAL_FILE = Path(__file__).resolve().parent / "data" / "signals.toml"
FMUS = ("plant", "sensors", "controller", "reference")
CAUSALITIES = ("input", "output")
#: The group of the loop's sample indices (docs/control.md, "The loop measures its own delay"): whole numbers
#: carried as Reals, not physical signals; the physics vectors (observables, sensor channels) leave them out.
INDEX_GROUP = "index"
#: The first index of a run: sample k = 0 carries 1, so a master's zero fill (0) reads as "no sample yet".
NO_SAMPLE = 0


class Signal(NamedTuple):
    """One input or output of one FMU."""

    fmu: str
    causality: str
    name: str
    unit: str
    group: str
    description: str


class SignalError(ValueError):
    """The catalogue file is malformed (names the row and the field)."""


@functools.lru_cache(maxsize=4)
def catalogue(path: str | Path = SIGNAL_FILE) -> tuple[Signal, ...]:
    """Every row of the catalogue, in file order; checked (fields, FMU, causality, unique names per FMU)."""
    rows = tomllib.loads(Path(path).read_text(encoding="utf-8")).get("signal", [])
    out, seen = [], set()
    for i, row in enumerate(rows):
        missing = [f for f in Signal._fields if not isinstance(row.get(f), str) or not row.get(f)]
        if missing or set(row) - set(Signal._fields):
            raise SignalError(f"{path}: signal[{i}]: needs the text fields {list(Signal._fields)} and no others "
                              f"(missing {missing}, unknown {sorted(set(row) - set(Signal._fields))})")
        s = Signal(**row)
        if s.fmu not in FMUS or s.causality not in CAUSALITIES:
            raise SignalError(f"{path}: signal[{i}] {s.name}: fmu must be one of {FMUS} and causality one of "
                              f"{CAUSALITIES}, got {s.fmu!r}, {s.causality!r}")
        if (s.fmu, s.name) in seen:
            raise SignalError(f"{path}: signal[{i}]: {s.fmu}.{s.name} appears twice")
        seen.add((s.fmu, s.name))
        out.append(s)
    return tuple(out)


def signals(fmu: str, causality: str | None = None, groups: tuple[str, ...] | str | None = None,
            indices: bool = True) -> tuple[Signal, ...]:
    """The signals of one FMU, in order; optionally of one causality and of some groups.

    ``indices=False`` leaves out the sample indices (group :data:`INDEX_GROUP`): the physical signals only.
    """
    if fmu not in FMUS:
        raise SignalError(f"fmu: one of {FMUS}, got {fmu!r}")
    groups = (groups,) if isinstance(groups, str) else groups
    return tuple(s for s in catalogue() if s.fmu == fmu and (causality is None or s.causality == causality)
                 and (groups is None or s.group in groups) and (indices or s.group != INDEX_GROUP))


def names(fmu: str, causality: str | None = None, groups: tuple[str, ...] | str | None = None,
          indices: bool = True) -> tuple[str, ...]:
    """Names of :func:`signals`."""
    return tuple(s.name for s in signals(fmu, causality, groups, indices))
