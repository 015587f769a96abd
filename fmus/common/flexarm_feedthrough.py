"""Direct-feedthrough sampling for this project's FMUs (sensors, controllers).

The sensors and controller FMUs are *sampled* components: their outputs at a
communication point t_k are a function of the inputs present at t_k (direct
feedthrough), not of the inputs held over the previous step. A master sets
the inputs at t_k and then reads the outputs, which must already reflect
them. :class:`FeedthroughSlave` implements that on top of
:class:`flexarm_fmu_base.FlexarmSlave`:

* setting any input marks the outputs *stale*;
* reading any output while they are stale evaluates :meth:`~FeedthroughSlave.evaluate`
  once (the sample k) and publishes the result; reading again returns the
  same numbers without re-evaluating;
* ``fmi2DoStep(t_k, h)`` first takes the sample if nobody read the outputs
  (so the sequence of samples, e.g. the noise stream, does not depend on
  which outputs the master reads), then calls :meth:`~FeedthroughSlave.commit`
  and marks the outputs stale: the next sample belongs to t_k + h.

If an input is set again after the outputs were read at the same
communication point, the next read evaluates again *from the same committed
state* (the subclass rolls back any state it advanced in
:meth:`~FeedthroughSlave.evaluate`), so each communication point advances
the internal state exactly once, with the inputs present at ``fmi2DoStep``.

The staleness flag is part of the FMU state (``fmi2Get/SetFMUstate``).
This module is bundled into each FMU that uses it and imported by name
(like ``flexarm_fmu_base``): keep it identical across FMUs.
"""

from __future__ import annotations

from abc import abstractmethod

import numpy as np
from flexarm_fmu_base import _INITIALIZATION, FlexarmSlave

__all__ = ["FeedthroughSlave"]


class FeedthroughSlave(FlexarmSlave):
    """A :class:`FlexarmSlave` whose outputs at t_k are computed from the inputs set at t_k.

    Subclasses implement :meth:`setup` (build from the parameters),
    :meth:`evaluate` (outputs of the current sample), optionally
    :meth:`commit`, :meth:`check_step`, :meth:`get_sample_state` and
    :meth:`set_sample_state`.
    """

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._input_vr_set = frozenset(i for i, v in enumerate(self._vars) if v.causality == "input")
        self._output_vr_set = frozenset(self._output_vrs)
        self._stale = True
        self._ready = False

    # -- hooks ---------------------------------------------------------------------
    @abstractmethod
    def setup(self) -> None:
        """Build the component from the parameters (called at initialisation). Raise on bad values."""

    @abstractmethod
    def evaluate(self) -> np.ndarray:
        """Outputs (table order) of the sample at ``self.time`` from the current inputs.

        May be called several times per communication point (each time the
        inputs changed after a read); every call must start from the state
        committed at the previous :meth:`commit`.
        """

    def commit(self, t: float, h: float) -> None:
        """Make the sample of the current communication point final (called by ``fmi2DoStep``)."""

    def check_step(self, t: float, h: float) -> None:
        """Raise if a step from t of size h (s) is not allowed (before anything changes)."""

    def get_sample_state(self) -> dict:
        """JSON-serialisable snapshot of the subclass's state."""
        return {}

    def set_sample_state(self, state: dict) -> None:
        """Restore :meth:`get_sample_state`."""

    # -- FlexarmSlave hooks ---------------------------------------------------------
    def initialize(self) -> None:
        self._ready = False
        self._stale = True
        self.setup()
        self._ready = True

    def step(self, t: float, h: float) -> None:
        self.check_step(t, h)
        self._refresh()
        self.commit(t, h)
        self._stale = True

    def get_internal_state(self) -> dict:
        return {"stale": self._stale, "ready": self._ready,
                "sample": self.get_sample_state() if self._ready else None}

    def set_internal_state(self, state: dict) -> None:
        self._stale = bool(state["stale"])
        self._ready = bool(state["ready"])
        if self._ready:
            self.set_sample_state(state["sample"])

    # -- sampling -------------------------------------------------------------------
    def _refresh(self) -> None:
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
