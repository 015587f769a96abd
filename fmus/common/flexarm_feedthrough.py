"""Sampled FMUs of this project (sensors, controllers): outputs that reads cannot change.

The sensors and controller FMUs are *sampled* components with a state that
advances once per sample. :class:`FeedthroughSlave` gives them one rule, on
top of :class:`flexarm_fmu_base.FlexarmSlave`:

**The outputs are a pure function of the committed state and the inputs
present.** :meth:`~FeedthroughSlave.evaluate` computes them from the state
committed at the last ``fmi2DoStep`` (or at initialisation) without changing
it. Reading any output, any number of times, at any moment, changes nothing:

* setting any input marks the outputs *stale*;
* reading an output while they are stale evaluates once and caches the
  result (the cache is only a cache: the same state and inputs give the same
  numbers); reading again returns it;
* ``fmi2DoStep(t, h)`` counts the samples in the step
  (:meth:`~FeedthroughSlave.samples_in_step`), evaluates from the inputs
  present *at ``fmi2DoStep``* (whatever was read before) and calls
  :meth:`~FeedthroughSlave.commit`, which makes the state advance by those
  samples; the outputs are then stale (the next sample belongs to t + h).

A component with direct feedthrough (the sensors, the stateless
controllers, ``controller_lqg`` with ``loop_delay_samples = 0``) evaluates
from its inputs; one without (``controller_lqg`` with a loop delay) returns
what its last commit computed, so its outputs do not depend on the inputs at
all. Either way, what a master reads never depends on how often or when it
reads.

Step sizes (:func:`whole_samples`): a step within 1e-9 s of n whole samples
counts as n samples; n = 0 (a step of at most 1e-9 s, such as the
1.15e-13 s last step a master accumulating time in doubles produces) is
accepted and does nothing: no sample instant lies inside it. Any other step
is refused naming ``step_size``.

The staleness flag is part of the FMU state (``fmi2Get/SetFMUstate``).
This module is bundled into each FMU that uses it and imported by name
(like ``flexarm_fmu_base``): keep it identical across FMUs.
"""

from __future__ import annotations

from abc import abstractmethod

import numpy as np
from flexarm_fmu_base import _INITIALIZATION, FlexarmSlave

__all__ = ["STEP_TOLERANCE", "FeedthroughSlave", "whole_samples"]

#: A step within this many seconds of a whole number of samples counts as that number, s.
STEP_TOLERANCE = 1e-9


def whole_samples(h: float, period: float, what: str) -> int:
    """The number n >= 0 of samples of `period` (s) in a communication step `h` (s).

    Raises
    ------
    ValueError
        Naming ``step_size`` when `h` is not within :data:`STEP_TOLERANCE` of ``n * period``;
        `what` says which sample (e.g. "the controller's 1 ms sample").
    """
    n = round(h / period)
    if abs(h - n * period) > STEP_TOLERANCE:
        raise ValueError(f"step_size: {h!r} s is not a whole multiple of {what} ({period:g} s; allowed: n * "
                         f"{period:g} s within {STEP_TOLERANCE:g} s, n = 0, 1, 2, ...; a step of n = 0 samples "
                         "does nothing)")
    return n


class FeedthroughSlave(FlexarmSlave):
    """A :class:`FlexarmSlave` whose outputs at t_k are computed from the inputs set at t_k.

    Subclasses implement :meth:`setup` (build from the parameters),
    :meth:`evaluate` (outputs of the current sample), :meth:`samples_in_step`,
    optionally :meth:`commit`, :meth:`get_sample_state` and
    :meth:`set_sample_state`.
    """

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._input_vr_set = frozenset(i for i, v in enumerate(self._vars) if v.causality == "input")
        self._output_vr_set = frozenset(self._output_vrs)
        self._stale = True
        self._ready = False
        self.outputs_read = False  # an output was read since initialisation (a master that exchanges values)

    # -- hooks ---------------------------------------------------------------------
    @abstractmethod
    def setup(self) -> None:
        """Build the component from the parameters (called at initialisation). Raise on bad values."""

    @abstractmethod
    def evaluate(self) -> np.ndarray:
        """Outputs (table order) at ``self.time``: a function of the committed state and the inputs present.

        May be called any number of times per communication point; it must
        not change the committed state (what it derives for :meth:`commit`
        is recomputed at every call).
        """

    @abstractmethod
    def samples_in_step(self, t: float, h: float) -> int:
        """Samples n >= 0 in a step from t of size h (s); raise naming ``step_size`` if not allowed.

        Called before anything changes; n = 0: the step does nothing (see :func:`whole_samples`).
        """

    def commit(self, t: float, h: float, n: int) -> None:
        """Advance the state by the n >= 1 samples of the step, from the inputs present (``fmi2DoStep``).

        Called right after :meth:`evaluate` with the inputs present at ``fmi2DoStep``.
        """

    def get_sample_state(self) -> dict:
        """JSON-serialisable snapshot of the subclass's state."""
        return {}

    def set_sample_state(self, state: dict) -> None:
        """Restore :meth:`get_sample_state`."""

    # -- FlexarmSlave hooks ---------------------------------------------------------
    def initialize(self) -> None:
        self._ready = False
        self._stale = True
        self.outputs_read = False
        self.setup()
        self._ready = True

    def step(self, t: float, h: float) -> None:
        n = self.samples_in_step(t, h)
        if n == 0:
            return  # no sample instant inside the step: nothing changes
        self._refresh()  # the outputs of the inputs present now (any set since a read made them stale)
        self.commit(t, h, n)
        self._stale = True

    def get_internal_state(self) -> dict:
        return {"stale": self._stale, "ready": self._ready, "outputs_read": self.outputs_read,
                "sample": self.get_sample_state() if self._ready else None}

    def set_internal_state(self, state: dict) -> None:
        self._stale = bool(state["stale"])
        self._ready = bool(state["ready"])
        self.outputs_read = bool(state["outputs_read"])  # what the master did before the state: part of it
        if self._ready:
            self.set_sample_state(state["sample"])

    # -- sampling -------------------------------------------------------------------
    def _refresh(self) -> None:
        """Bring the cached outputs up to date (a cache: evaluating again gives the same numbers)."""
        if self._stale:
            outputs = self.evaluate()
            self.set_outputs(outputs)
            self._stale = False

    def _before_get(self, vrs) -> None:
        try:
            if not self._stale or self._output_vr_set.isdisjoint(vrs):
                return
            if self._needs_init and self._mode == _INITIALIZATION:
                self._ensure_initialized()  # outputs read in initialisation mode must be consistent
            if self._ready:
                self._refresh()
            self.outputs_read = True
        except Exception as exc:  # never let an exception reach pythonfmu (see flexarm_fmu_base)
            self._exception(f"evaluating the outputs at t = {self.time!r} s", exc)

    def _after_set(self, vrs) -> None:
        if not self._input_vr_set.isdisjoint(vrs):
            self._stale = True

    def get_real(self, vrs):
        self._before_get(vrs)
        return super().get_real(vrs)

    def get_integer(self, vrs):
        self._before_get(vrs)
        return super().get_integer(vrs)

    def get_boolean(self, vrs):
        self._before_get(vrs)
        return super().get_boolean(vrs)

    def get_string(self, vrs):
        self._before_get(vrs)
        return super().get_string(vrs)

    def set_real(self, vrs, values):
        super().set_real(vrs, values)
        self._after_set(vrs)

    def set_integer(self, vrs, values):
        super().set_integer(vrs, values)
        self._after_set(vrs)

    def set_boolean(self, vrs, values):
        super().set_boolean(vrs, values)
        self._after_set(vrs)

    def set_string(self, vrs, values):
        super().set_string(vrs, values)
        self._after_set(vrs)
