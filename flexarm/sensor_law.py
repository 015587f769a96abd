"""The sensors' per-sample arithmetic, written once (issue 33 item 4): filter sections, noise, quantisation.

:class:`flexarm.sensors.SensorBank` (the library and the Python sensors FMU) calls these on NumPy arrays, one
value per channel; the native sensors FMU's C is generated from the same functions on CasADi symbols, one channel
at a time (:mod:`fmu_build.law_codegen`). The filters' design is :mod:`flexarm.filter_design`, generated the same
way.
"""

from __future__ import annotations

from .law_ops import clamp, round_half_even


def filter_section(sos, state0, state1, x):
    """One second-order section in direct form II transposed (:func:`scipy.signal.sosfilt`), one sample.

    Parameters
    ----------
    sos : sequence of 6
        b0, b1, b2, a0 (= 1, unused), a1, a2.
    state0, state1 : array_like
        The section's two states per channel, before the sample.
    x : array_like
        The section's input per channel.

    Returns
    -------
    y, state0, state1
        Its output and its states after the sample.
    """
    b0, b1, b2, _, a1, a2 = sos
    y = b0 * x + state0
    return y, b1 * x - a1 * y + state1, b2 * x - a2 * y


def primed_state(unit_state, x):
    """A section's state in steady state for a constant input x, from its state for a unit step."""
    return unit_state * x


def with_noise(y, amplitude, uniform):
    """y plus uniform noise of half-width `amplitude` from a uniform draw in [0, 1)."""
    return y + amplitude * (2.0 * uniform - 1.0)


def quantize(x, lsb, lo_code, hi_code):
    """Round to the nearest multiple of `lsb` (halves to even), the code clipped to [lo_code, hi_code] (±inf: no
    saturation); ``code × lsb``, |error| ≤ lsb/2 inside the range."""
    return clamp(round_half_even(x / lsb), lo_code, hi_code) * lsb
