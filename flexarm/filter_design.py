"""The sensors' Butterworth low-pass design, written once (issue 33 item 4): second-order sections and their state.

:func:`butterworth_lowpass` is what ``scipy.signal.butter(order, cutoff_hz, output="sos", fs=sample_rate_hz)``
and ``scipy.signal.sosfilt_zi`` return, computed step by step as SciPy computes them (prototype poles, pre-warped
low-pass, bilinear transform at fs = 2, "nearest" pairing into sections, each section's steady state by a 2×2
solve with partial pivoting). :class:`flexarm.sensors.SensorBank` (the library and the Python sensors FMU) calls it
on numbers; the native sensors FMU's design is generated from :func:`butterworth_sections` on CasADi symbols, one
function per order (:mod:`fmu_build.law_codegen`), and takes the tangent from the portable one. So a change to the
filter is made here and nowhere else.

Two steps are fixed by the order alone, which is what lets them be generated without a search: the prototype's
poles (constants of the order), and which pole pairs go into which section (a Butterworth pole lies closer to the
unit circle the closer its prototype lies to the imaginary axis, whatever the cut-off). The one choice that
depends on the cut-off, where the odd orders' zero at z = 0 goes, is a selection. One deliberate difference from
SciPy: the gain's ``warped ** order`` is a product of `order` factors (generated C calls no library power), which
can move the gain by an ulp or two. ``tests/test_filter_design.py`` holds it to SciPy.
"""

from __future__ import annotations

import math

import numpy as np

from .law_ops import as_written, is_symbol, select

#: Orders the design is generated for (the sensors' settings allow these).
ORDERS = range(1, 9)


def prewarp_argument(cutoff_hz, sample_rate_hz):
    """π·w_n/2 for w_n = cutoff / Nyquist: 4·tan of it is the pre-warped analog cut-off at fs = 2 (SciPy's
    ``iirfilter``), so the digital filter's −3 dB point is exactly `cutoff_hz`."""
    wn = cutoff_hz / (sample_rate_hz / 2)
    return math.pi * wn / 2.0


def butterworth_lowpass(order: int, cutoff_hz: float, sample_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Second-order sections of a Butterworth low-pass, and each section's state for a unit step in steady state.

    Parameters
    ----------
    order : int
        Filter order, in :data:`ORDERS`.
    cutoff_hz, sample_rate_hz : float
        −3 dB frequency and sample rate, Hz; 0 < cutoff < sample rate / 2.

    Returns
    -------
    sos : ndarray, shape ((order + 1) // 2, 6)
        b0, b1, b2, a0 (= 1), a1, a2 per section, as ``scipy.signal.butter(..., output="sos", fs=...)``.
    unit_state : ndarray, shape ((order + 1) // 2, 2)
        ``scipy.signal.sosfilt_zi(sos)``: direct form II transposed states of each section for a unit input held
        forever.
    """
    if order not in ORDERS:
        raise ValueError(f"order: expected an integer in [{ORDERS[0]}, {ORDERS[-1]}], got {order!r}")
    if not 0.0 < cutoff_hz < sample_rate_hz / 2:
        raise ValueError(f"cutoff_hz: expected in (0, {sample_rate_hz / 2:g}) Hz (below Nyquist), got {cutoff_hz!r}")
    sos, unit_state = butterworth_sections(order, math.tan(prewarp_argument(cutoff_hz, sample_rate_hz)))
    return np.array(sos, dtype=float), np.array(unit_state, dtype=float)


def _abs(x):
    return select(x < 0, -x, x)


def _mul(a, b):
    return a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0]


def _div(a, b):
    """a / b for complex numbers as (re, im): NumPy's division (Smith's method), divided by the larger part."""
    if not any(is_symbol(v) for v in (*a, *b)):
        return _smith(a, b, abs(b[0]) >= abs(b[1]))
    by_re, by_im = _smith(a, b, True), _smith(a, b, False)
    re_larger = _abs(b[0]) >= _abs(b[1])
    return select(re_larger, by_re[0], by_im[0]), select(re_larger, by_re[1], by_im[1])


def _smith(a, b, re_larger: bool):
    if re_larger:
        rat = b[1] / b[0]
        scl = 1.0 / (b[0] + b[1] * rat)
        return (a[0] + a[1] * rat) * scl, (a[1] - a[0] * rat) * scl
    rat = b[0] / b[1]
    scl = 1.0 / (b[1] + b[0] * rat)
    return (a[0] * rat + a[1]) * scl, (a[1] * rat - a[0]) * scl


def prototype_poles(order: int) -> list[tuple[float, float]]:
    """The analog prototype's poles −exp(jπm/(2N)), m = −N+1, −N+3, …, N−1, as ``scipy.signal.buttap`` computes
    them (constants of the order)."""
    m = np.arange(-order + 1, order, 2)
    poles = -np.exp(1j * np.pi * m / (2 * order))
    return [(float(p.real), float(p.imag)) for p in poles]


def butterworth_sections(order: int, tan_prewarp):
    """The design from the tangent of :func:`prewarp_argument`, on numbers or on CasADi symbols.

    Returns
    -------
    sos, unit_state : lists of rows
        As :func:`butterworth_lowpass`, as nested lists (of symbols on the generator's path, built as written:
        :func:`flexarm.law_ops.as_written`).
    """
    if is_symbol(tan_prewarp):
        with as_written():
            return _sections(order, tan_prewarp)
    return _sections(order, tan_prewarp)


def _sections(order: int, tan_prewarp):
    warped = 2 * 2.0 * tan_prewarp
    poles, den_prod = [], None
    for analog in prototype_poles(order):  # lp2lp (× warped), then the bilinear transform at fs = 2
        lp = (warped * analog[0], warped * analog[1])
        den = (4.0 - lp[0], -lp[1])
        poles.append(_div((4.0 + lp[0], lp[1]), den))
        den_prod = den if den_prod is None else _mul(den_prod, den)
    gain = warped
    for _ in range(order - 1):
        gain = gain * warped
    gain = gain * _div((1.0, 0.0), den_prod)[0]
    # Sections from the last: the pole pair closest to the unit circle first (m = −N+1, +j half); an odd order's
    # real pole (m = 0) pairs with SciPy's added pole at z = 0, in the first section.
    n_sections = (order + 1) // 2
    zero_at_origin_free = order % 2  # the odd orders' added zero at z = 0, until a section takes it
    sos = [None] * n_sections
    for k in range(n_sections):
        section = n_sections - 1 - k
        p1 = poles[k]
        p2 = (p1[0], -p1[1]) if 2 * k + 1 < order else (0.0, 0.0)
        zeros = []
        for pick in range(2):  # the nearest zero to p1 of those left: −1, or the odd orders' one at the origin
            if order % 2 == 0:
                zeros.append(-1.0)
                continue
            origin_nearer = _abs(0.0 - p1[0]) < _abs(-1.0 - p1[0])
            last_left = k == n_sections - 1 and pick == 1  # the last zero left is taken whatever its distance
            take = zero_at_origin_free if last_left else select(origin_nearer, zero_at_origin_free, 0.0)
            zeros.append(select(take, 0.0, -1.0))
            zero_at_origin_free = select(take, 0.0, zero_at_origin_free)
        prod = _mul((-p1[0], -p1[1]), (-p2[0], -p2[1]))
        sos[section] = [1.0, -zeros[1] + -zeros[0], (-zeros[0]) * (-zeros[1]), 1.0, -p2[0] + -p1[0], prod[0]]
    sos[0] = [sos[0][0] * gain, sos[0][1] * gain, sos[0][2] * gain, *sos[0][3:]]
    return sos, _unit_states(sos)


def _unit_states(sos):
    """``scipy.signal.sosfilt_zi``: each section's ``lfilter_zi`` (LAPACK's 2×2 solve with partial pivoting),
    scaled by the DC gains of the sections before it."""
    states, scale = [], 1.0
    for b0, b1, b2, a0, a1, a2 in sos:
        m00, m01, m10, m11 = 1 + a1, -1.0, a2, 1.0
        r0, r1 = b1 - a1 * b0, b2 - a2 * b0
        swap = _abs(m10) > _abs(m00)
        m00, m10 = select(swap, m10, m00), select(swap, m00, m10)
        m01, m11 = select(swap, m11, m01), select(swap, m01, m11)
        r0, r1 = select(swap, r1, r0), select(swap, r0, r1)
        lower = m10 * (1.0 / m00)
        x1 = (r1 - lower * r0) / (m11 - lower * m01)
        x0 = (r0 - m01 * x1) / m00
        states.append([scale * x0, scale * x1])
        scale = scale * ((b0 + b1 + b2) / (a0 + a1 + a2))
    return states
