"""The FMI robustness tests of the Python FMUs (tests/test_fmu_robustness.py), run on the native FMUs.

The same test functions, collected here with fixtures that give the native set: wrong-state calls,
non-finite values, 200 instantiate/free cycles, GUID and type checks, NULL pointers and status
queries, errors that reach a host instantiated without logging.
"""

from __future__ import annotations

import fmu_harness
import pytest
import test_fmu_robustness
from fmpy import extract
from native_fmus import native_fmus
from test_fmu_robustness import (  # noqa: F401 - collected here, with this module's fixtures
    test_errors_reach_a_host_that_instantiates_without_logging,
    test_instantiate_checks_guid_and_type,
    test_instantiate_free_cycles_keep_memory_bounded,
    test_non_finite_values_return_error_and_the_fmu_stays_usable,
    test_null_pointers_unknown_categories_and_status_queries,
    test_wrong_state_calls_return_error_with_a_message,
)


@pytest.fixture(scope="module")
def fmus():
    return native_fmus()


@pytest.fixture(scope="module")
def unzipped(fmus, tmp_path_factory) -> dict[str, str]:
    return {name: extract(str(path), unzipdir=str(tmp_path_factory.mktemp(f"native_{name}")))
            for name, path in fmus.items()}


@pytest.fixture(autouse=True)
def _enumeration_start_values(monkeypatch):
    """The native controllers' gain_set and omega7_estimate are Enumerations (the interface contract); the
    robustness module's helper knows the Python FMUs' types of today: teach it Enumeration (an integer)."""
    known = test_fmu_robustness._start_value
    monkeypatch.setattr(test_fmu_robustness, "_start_value",
                        lambda var: int(var.start) if var.type == "Enumeration" else known(var))
    known_set = fmu_harness.Slave.set

    def set_values(self, **values):
        for name, value in values.items():
            var = self.vars[name]
            if var.type == "Enumeration":
                self.fmu.setInteger([var.valueReference], [int(value)])
            else:
                known_set(self, **{name: value})

    monkeypatch.setattr(fmu_harness.Slave, "set", set_values)

