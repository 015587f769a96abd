"""The sensors' arithmetic, written once (issue 33 item 4): each channel's scales, filter sections, noise,
quantisation.

:class:`flexarm.sensors.SensorBank` (the library and the Python sensors FMU) calls these on NumPy arrays, one
value per channel; the native sensors FMU's C is generated from the same functions on CasADi symbols, one channel
at a time (:mod:`fmu_build.law_codegen`). The filters' design is :mod:`flexarm.filter_design`, generated the same
way.
"""

from __future__ import annotations

import math

import numpy as np

from .law_ops import clamp, is_symbol, round_half_even


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


def channel_scales(encoder_noise_deg, tachometer_noise_deg_per_s, strain_gauge_noise_deg,
                   accelerometer_noise_m_per_s2, encoder_counts_per_rev, tachometer_full_scale_deg_per_s,
                   gauge_full_scale_curvature_per_m, segment_lengths, accelerometer_full_scale_m_per_s2, adc_codes):
    """Each channel's noise half-width and quantum in SI units, from the settings (at initialisation).

    Parameters
    ----------
    encoder_noise_deg, tachometer_noise_deg_per_s, strain_gauge_noise_deg, accelerometer_noise_m_per_s2 : float
        Noise half-widths as the settings give them.
    encoder_counts_per_rev : float
        The encoders' counts per revolution.
    tachometer_full_scale_deg_per_s, accelerometer_full_scale_m_per_s2 : float
        A/D full scale ±FS.
    gauge_full_scale_curvature_per_m : sequence of 2
        The gauges' full scale as curvature, link 1 and link 2 (three gauges each), 1/m.
    segment_lengths : sequence of 6
        The gauged segments' lengths, m: a gauge digitises curvature, so in angle its full scale is κ_FS·L.
    adc_codes : float
        2^bits of the A/D converter.

    Returns
    -------
    amplitude : ndarray, shape (12,)
        Noise half-widths: rad, rad, rad/s, rad/s, 6 × rad, 2 × m/s².
    encoder_lsb : float
        rad per count.
    full_scale, adc_lsb : ndarray, shape (10,)
        The analogue channels' (tachometers, gauges, accelerometers) full scale and quantum, SI units.
    lo_code, hi_code : float
        The A/D's code range, −2^(bits−1) .. 2^(bits−1) − 1.
    """
    deg = math.pi / 180.0
    kind = object if is_symbol(adc_codes) else float  # the generator's symbols, or numbers
    amplitude = np.array([encoder_noise_deg * deg] * 2 + [tachometer_noise_deg_per_s * deg] * 2
                         + [strain_gauge_noise_deg * deg] * 6 + [accelerometer_noise_m_per_s2] * 2, dtype=kind)
    full_scale = np.array([tachometer_full_scale_deg_per_s * deg] * 2
                          + [gauge_full_scale_curvature_per_m[g // 3] * segment_lengths[g] for g in range(6)]
                          + [accelerometer_full_scale_m_per_s2] * 2, dtype=kind)
    adc_lsb = np.array([2.0 * fs / adc_codes for fs in full_scale], dtype=kind)
    return amplitude, 2.0 * math.pi / encoder_counts_per_rev, full_scale, adc_lsb, -(adc_codes / 2), adc_codes / 2 - 1
