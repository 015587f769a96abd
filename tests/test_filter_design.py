"""The sensors' Butterworth design (flexarm.filter_design): SciPy's filter, its mathematics, its generated C twin."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal as sg

from flexarm.filter_design import ORDERS, butterworth_lowpass, butterworth_sections, prewarp_argument

FS = 1000.0  # Hz, the sensors' sample rate
EPS = np.finfo(float).eps
CUTOFFS = np.concatenate([np.geomspace(0.05, 499.0, 60), [10.0, 100.0]])


def _response(sos, hz):
    """The cascade's complex frequency response at `hz`."""
    z = np.exp(1j * 2 * np.pi * hz / FS)
    return np.prod([(b0 + b1 / z + b2 / z**2) / (1 + a1 / z + a2 / z**2) for b0, b1, b2, _, a1, a2 in sos])


@pytest.mark.parametrize("order", list(ORDERS))
def test_the_design_is_scipys_to_the_rounding_of_its_steps(order):
    """SciPy's butter(..., output="sos", fs) and sosfilt_zi. Each coefficient is a few rounded products of terms
    no larger than its row's largest, so 4 ulps of that; SciPy's only other difference is its tangent (NumPy's) and
    warped ** order (the library power). The steady state solves (I − A) zi = B, whose condition number
    amplifies those: 8 ulps times it (measured at most 1.7)."""
    for cutoff in CUTOFFS:
        sos, unit_state = butterworth_lowpass(order, float(cutoff), FS)
        ref = sg.butter(order, cutoff, output="sos", fs=FS)
        assert sos.shape == ref.shape == ((order + 1) // 2, 6)
        row = np.abs(ref).max(axis=1, keepdims=True)
        assert (np.abs(sos - ref) <= 4 * EPS * row).all(), cutoff
        ref_state = sg.sosfilt_zi(ref)
        cond = np.array([np.linalg.cond([[1 + a1, -1.0], [a2, 1.0]]) for *_, a1, a2 in ref])[:, None]
        assert (np.abs(unit_state - ref_state) <= 8 * EPS * cond * np.abs(ref_state).max(axis=1, keepdims=True)).all()


@pytest.mark.parametrize("order", list(ORDERS))
def test_a_butterworth_low_pass_by_its_definition(order):
    """Unit DC gain, −3.01 dB at the cut-off (pre-warped), the N-th order roll-off, every pole inside the unit
    circle and every zero at z = −1 (plus an odd order's cancelling pair at the origin)."""
    for cutoff in (10.0, 100.0, 250.0):
        sos, _ = butterworth_lowpass(order, cutoff, FS)
        assert abs(_response(sos, 0.0) - 1.0) < 1e-12
        assert abs(abs(_response(sos, cutoff)) - 1 / math.sqrt(2)) < 1e-12
        # |H|² = 1 / (1 + (tan(πf/fs) / tan(πf_c/fs))^(2N)) for the bilinear Butterworth
        f = cutoff / 2
        ratio = math.tan(math.pi * f / FS) / math.tan(math.pi * cutoff / FS)
        assert abs(abs(_response(sos, f)) ** 2 - 1 / (1 + ratio ** (2 * order))) < 1e-12
        for b0, b1, b2, a0, a1, a2 in sos:
            assert a0 == 1.0
            assert (np.abs(np.roots([1.0, a1, a2])) < 1.0).all()
            zeros = np.roots([b0, b1, b2]) if b0 else []
            assert all(abs(z + 1) < 1e-6 or abs(z) < 1e-12 for z in zeros)


@pytest.mark.parametrize("order", [1, 2, 5, 8])
def test_the_unit_state_holds_a_constant_input(order):
    """Primed with x × unit_state, the filter passes a held x with no transient (the sensors' priming)."""
    sos, unit_state = butterworth_lowpass(order, 10.0, FS)
    y, _ = sg.sosfilt(sos, np.full(500, 3.7), zi=3.7 * unit_state)
    np.testing.assert_allclose(y, 3.7, rtol=1e-13)


def test_bad_settings_are_refused_by_name():
    with pytest.raises(ValueError, match=r"order: expected an integer in \[1, 8\]"):
        butterworth_lowpass(9, 10.0, FS)
    with pytest.raises(ValueError, match=r"cutoff_hz: expected in \(0, 500\) Hz"):
        butterworth_lowpass(2, 500.0, FS)
    with pytest.raises(ValueError, match="cutoff_hz"):
        butterworth_lowpass(2, 0.0, FS)


def test_the_generated_design_is_the_librarys_bit_for_bit():
    """The CasADi functions the native sensors' C is generated from give the library's numbers exactly (built as
    written: with CasADi's simplification on, a·(1/b) would become a/b)."""
    from fmu_build import law_codegen

    functions = {f.name(): f for f in law_codegen.butterworth_functions()}
    for order in ORDERS:
        design = functions[f"generated_butterworth_order_{order}"]
        for cutoff in CUTOFFS:
            argument = float(functions["generated_prewarp_argument"](cutoff, FS))
            assert argument == prewarp_argument(float(cutoff), FS)
            sos, unit_state = butterworth_sections(order, math.tan(argument))
            got_sos, got_state = design(math.tan(argument))
            np.testing.assert_array_equal(np.asarray(got_sos).ravel(), np.ravel(sos))
            np.testing.assert_array_equal(np.asarray(got_state).ravel(), np.ravel(unit_state))
