"""A master's placeholder is not a measurement (issue 31 item 2): the sensors FMU, both kinds.

fmpy's ``simulate_ssp`` sets every connected input to 0 over its first step. The sensors must not measure that
(q = 0 is 86 deg from the arm's start; the filters would be primed at 0 and ring for tens of samples): they pass
on zeros with index 0, so the controller sees "no sample yet", keep their filters unprimed, and draw no noise, so
that the first real measurement gets the first draws, as in a master that exchanged values in initialisation:
the plant's sample j has the same noise in every master.
"""

from __future__ import annotations

import numpy as np
import pytest
from fmpy import extract
from fmu_harness import Slave, built_fmus
from native_fmus import native_fmus

TRUE = ("q1", "q2", "qd1", "qd2", "eps1", "eps2", "eps3", "eps4", "eps5", "eps6", "acc1_n", "acc2_n")
MEASURED = ("q1_m", "q2_m", "qd1_m", "qd2_m", "eps1_m", "eps2_m", "eps3_m", "eps4_m", "eps5_m", "eps6_m",
            "acc1_m", "acc2_m")
#: A true signal vector of the arm (rad, rad/s, m/s2) and the sample index it travels with (sample 1).
X1 = np.array([-1.5, 0.2, 0.3, -0.1, 1e-3, -2e-3, 5e-4, 1e-3, 2e-3, -1e-3, 0.5, -0.8])


def _fmu(kind: str) -> str:
    return str((native_fmus() if kind == "native" else built_fmus())["sensors"])


def _run(kind: str, tmp_path, first_is_placeholder: bool, **params) -> np.ndarray:
    """Sample 0 (a placeholder or the measurement of X1 at index 1), then sample 1 of X1 at index 2."""
    s = Slave(_fmu(kind), extract(_fmu(kind), unzipdir=str(tmp_path / f"u{int(first_is_placeholder)}")), start=False)
    try:
        s.fmu.setupExperiment(startTime=0.0)
        s.fmu.enterInitializationMode()
        s.set(**params)
        s.fmu.exitInitializationMode()
        first = np.zeros(12) if first_is_placeholder else X1
        s.set_vector([*TRUE, "sample_index"], [*first, 0.0 if first_is_placeholder else 1.0])
        out0 = s.get([*MEASURED, "sample_index_m"])
        s.step()
        s.set_vector([*TRUE, "sample_index"], [*X1, 2.0])
        out1 = s.get([*MEASURED, "sample_index_m"])
        assert not s.errors(), s.errors()
        return np.vstack([out0, out1])
    finally:
        s.close()


@pytest.mark.parametrize("kind", ["native", "python"])
def test_a_placeholder_is_passed_on_as_no_sample_and_primes_nothing(kind, tmp_path):
    filters = {"strain_gauge_filter": True, "accelerometer_filter": True}
    out = _run(kind, tmp_path, True, **filters)
    np.testing.assert_array_equal(out[0], np.zeros(13))  # zeros, index 0: "no sample yet" for the controller
    # the first real sample primes the filters at steady state: without noise the output is the input itself
    np.testing.assert_allclose(out[1][:12], X1, rtol=1e-12, atol=1e-15)  # primed filter: x through DC gain 1
    assert out[1][12] == 2.0


@pytest.mark.parametrize("kind", ["native", "python"])
def test_a_placeholder_draws_no_noise(kind, tmp_path):
    """The first real measurement after a placeholder is the first real measurement of a run without one."""
    noisy = {"noise_enabled": True, "noise_seed": 7}
    skipped, measured = _run(kind, tmp_path, True, **noisy), _run(kind, tmp_path, False, **noisy)
    assert not np.array_equal(measured[0][:12], X1)  # the noise is on
    np.testing.assert_array_equal(skipped[0], np.zeros(13))  # and still no noise on a placeholder
    # X1 measured first in both runs: the same draws, bit for bit (the index passed on is the one received)
    np.testing.assert_array_equal(skipped[1][:12], measured[0][:12])
    assert not np.array_equal(skipped[1][:12], measured[1][:12])  # the second draws differ from the first
