"""A measurement belongs to the plant sample it measures (issue 31): the sensors FMU, both kinds.

A Gauss-Seidel master sets the plant's outputs of t_k into the sensors before it reads them at t_k; a Jacobi master
reads the sensors at t_k while their inputs are still the plant's outputs of t_(k-1), and sets those of t_k after.
The sensors see the index that travels with their inputs, so they know that the Jacobi read is of plant sample
k - 1, which they measured at t_(k-1): they give that measurement again, not a second sample of the same values
(a second filter update, the noise draw of sample k). The measurement of plant sample j is then the same, bit for
bit, whatever the master's stepping; only the time it reaches the controller differs.
"""

from __future__ import annotations

import numpy as np
import pytest
from fmpy import extract
from fmu_harness import Slave
from test_sensors_placeholder import MEASURED, TRUE, X1, _fmu

N = 12
#: Noise, both filters and the quantisation on: every part of a sample that has a state or a draw.
SETTINGS = {"noise_enabled": True, "noise_seed": 11, "strain_gauge_filter": True, "accelerometer_filter": True}


def _inputs(j: int) -> np.ndarray:
    """Plant sample j's true signals: X1 moving, so that every sample differs from the one before."""
    return X1 * (1.0 + 0.01 * j) + 1e-4 * np.sin(np.arange(12) + j)


def _run(kind: str, tmp_path, name: str, stepping: str) -> np.ndarray:
    """Rows k = 0..N-1: the sensors' outputs (12 measurements, sample_index_m) read at t_k, in `stepping`."""
    s = Slave(_fmu(kind), extract(_fmu(kind), unzipdir=str(tmp_path / name)), start=False)
    try:
        s.fmu.setupExperiment(startTime=0.0)
        s.fmu.enterInitializationMode()
        s.set(**SETTINGS)
        s.set_vector([*TRUE, "sample_index"], [*_inputs(0), 1.0])  # the initialisation exchange: sample 0
        s.fmu.exitInitializationMode()
        rows = []
        for k in range(N):
            if stepping == "gauss-seidel":  # the plant's outputs of t_k set first, then read
                s.set_vector([*TRUE, "sample_index"], [*_inputs(k), k + 1.0])
                rows.append(s.get([*MEASURED, "sample_index_m"]))
            else:  # Jacobi: read with the inputs of t_(k-1) (at k = 0 those of the exchange), then set t_k's
                rows.append(s.get([*MEASURED, "sample_index_m"]))
                s.set_vector([*TRUE, "sample_index"], [*_inputs(k), k + 1.0])
            s.step()
        assert not s.errors(), s.errors()
        return np.array(rows)
    finally:
        s.close()


@pytest.mark.parametrize("kind", ["native", "python"])
def test_the_measurement_of_a_plant_sample_is_the_same_in_either_stepping(kind, tmp_path):
    gs, jacobi = _run(kind, tmp_path, "gs", "gauss-seidel"), _run(kind, tmp_path, "j", "jacobi")
    np.testing.assert_array_equal(gs[:, 12], np.arange(1.0, N + 1))
    np.testing.assert_array_equal(jacobi[1:, 12], np.arange(1.0, N))  # read at t_k: plant sample k - 1
    # bit for bit: the Jacobi read at t_k is the Gauss-Seidel read at t_(k-1), noise and filters included
    np.testing.assert_array_equal(jacobi[1:], gs[:-1])
    np.testing.assert_array_equal(jacobi[0], gs[0])  # t_0: the exchange's sample 0 in both
    assert np.all(np.abs(gs[1:, :12] - gs[:-1, :12]) > 0)  # the samples differ: the test can tell them apart


@pytest.mark.parametrize("kind", ["native", "python"])
def test_the_same_index_with_other_values_is_measured_anew(kind, tmp_path):
    """The index alone does not make a repeat: inputs that differ are a new sample (a master that lies about the
    index, or an index wired from elsewhere, gets what it sets measured, never a stale measurement)."""
    s = Slave(_fmu(kind), extract(_fmu(kind), unzipdir=str(tmp_path / "u")), start=False)
    try:
        s.fmu.setupExperiment(startTime=0.0)
        s.fmu.enterInitializationMode()
        s.set(**{k: v for k, v in SETTINGS.items() if k != "noise_enabled"})  # noise off: the values show
        s.set_vector([*TRUE, "sample_index"], [*_inputs(0), 1.0])
        s.fmu.exitInitializationMode()
        first = s.get(list(MEASURED))
        s.step()
        s.set_vector([*TRUE, "sample_index"], [*(2.0 * _inputs(0)), 1.0])  # index of sample 0, other values
        again = s.get(list(MEASURED))
        assert not s.errors(), s.errors()
    finally:
        s.close()
    assert not np.array_equal(first, again)
    np.testing.assert_allclose(again[:4], 2.0 * _inputs(0)[:4], rtol=1e-3)  # unfiltered channels: the new values
