"""The loop's sample indices: how the FMUs of one loop tell each other which sample a value belongs to.

Design and defence: docs/control.md, "The loop measures its own delay". In short:

* sample k is the instant t_k = k * 1 ms (the controllers' and the trajectory's samples, counted from
  t = 0); it travels as the **index** k + 1, so that 0, the value a master feeds before the first exchange
  (fmpy's ``simulate_ssp`` sets every connected input to 0 over its first step) or an unwired input holds,
  means "no sample yet" and can never be mistaken for sample 0;
* the plant's ``sample_index`` is the index of the sample its outputs belong to; the sensors pass on, as
  ``sample_index_m``, the index present at their inputs when they sampled; a controller's ``tau_index``
  is the index of the sample its torques were computed for; the plant's ``tau_lag`` is how many samples
  late the torque it held was (-1: the torque carried no index);
* the indices are whole numbers carried as Reals (exact up to 2**53): every FMI 2.0 master connects Reals,
  our master and the hosts of the tests connect only Reals, and an index must survive every master a user
  drops the FMUs into.

No FMI here: the Python FMUs call these functions, the native FMUs have their C twins
(``fmus/native/common/loop_index.h``), held together by tests.
"""

from __future__ import annotations

import math

__all__ = ["AUTOMATIC", "NO_DELAY", "NO_INDEX_LAG", "NO_SAMPLE", "SAMPLE_PERIOD", "index_of_time", "is_placeholder",
           "measured_delay", "received_index", "slew_start_samples", "torque_lag", "trajectory_index"]

#: The value of an index that names no sample (a master's zero fill, an unwired input).
NO_SAMPLE = 0
#: The sample period the indices count, s (the trajectory's and the controllers' sample; checked against
#: the committed trajectory in tests/test_loop_index.py).
SAMPLE_PERIOD = 1e-3
#: ``tau_lag`` of a torque that carried no index.
NO_INDEX_LAG = -1.0
#: ``loop_delay`` of torques whose measurements carried no index.
NO_DELAY = -1.0
#: ``loop_delay_samples`` meaning "measure the delay and predict over it" (the start value).
AUTOMATIC = -1
#: An index within this of a whole number is that number (an index is exact in a double; this only absorbs
#: a master that converts through float32 or text).
_WHOLE = 1e-6


def index_of_time(t: float) -> float:
    """The index of the sample at time `t` (s): k + 1 for t = k * 1 ms (nearest), NO_SAMPLE before t = 0."""
    k = round(t / SAMPLE_PERIOD)
    return float(k + 1) if k >= 0 else float(NO_SAMPLE)


def received_index(value: float) -> int | None:
    """The sample k an index received through a connection names, or None for "no sample yet".

    0 (a zero fill, an unwired input), a negative value, a value that is no whole number (no FMU of ours
    sends one) and a non-finite one name no sample.
    """
    if not math.isfinite(value) or value < 1.0 - _WHOLE:
        return None
    whole = round(value)
    if abs(value - whole) > _WHOLE:
        return None
    return int(whole) - 1


def torque_lag(step_start: float, tau_index: float) -> float:
    """``tau_lag``: samples between the sample a held torque was computed for and the sample it is held from.

    `step_start` is the time (s) at which the plant started holding it, `tau_index` the index that came
    with it. :data:`NO_INDEX_LAG` when the index names no sample.
    """
    computed_for = received_index(tau_index)
    if computed_for is None:
        return NO_INDEX_LAG
    return float(round(step_start / SAMPLE_PERIOD) - computed_for)


def measured_delay(k: int, index: float) -> float:
    """The loop delay, in samples, of the torques of sample `k` computed from measurements carrying `index`.

    k − j for the plant sample j the index names (0 in a Gauss-Seidel master; 2 in a Jacobi master at 1 ms
    with separate sensors and controller), :data:`NO_DELAY` when it names none.
    """
    j = received_index(index)
    return NO_DELAY if j is None else float(k - j)


def is_placeholder(index: float, measurements) -> bool:
    """True for what a master feeds before its first exchange: no index and every measurement exactly 0.

    fmpy's ``simulate_ssp`` sets every connected input to 0 over its first step; a real measurement of the
    arm is not exactly 0 on all ten channels at once. An input without an index but with values is taken
    as a measurement of the current sample (an unwired index: the explicit ``loop_delay_samples`` holds).
    """
    return received_index(index) is None and not any(float(m) != 0.0 for m in measurements)


def trajectory_index(index: float, start: int) -> float:
    """`index` (of the master's samples) as an index of the trajectory's samples, for a controller whose slew starts
    `start` samples after t = 0 (docs/control.md, "The slew starts when the loop is live").

    The master's sample j is the trajectory's j − start. A sample before the start names none (:data:`NO_SAMPLE`);
    an index that names no sample is returned as it is. With `start` 0 it is `index` itself.
    """
    if not start:
        return index
    j = received_index(index)
    if j is None:
        return index
    return float(j - start + 1) if j >= start else float(NO_SAMPLE)


def slew_start_samples(slew_start_index: float) -> int:
    """How many samples after t = 0 a controller started the slew, from its output ``slew_start_index`` (the
    index of the master's sample at which the slew's sample 0 ran: 1 at t = 0). Raises ValueError for a value that
    names no sample (the output is read after the run, when the controller has fixed it)."""
    start = received_index(slew_start_index)
    if start is None:
        raise ValueError(f"slew_start_index: {slew_start_index!r} names no sample (a whole number >= 1)")
    return start
