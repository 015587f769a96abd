"""The noise cases over many seeds (scenarios/conformance/seeds.py): the verdict's arithmetic and a real run."""

from __future__ import annotations

import numpy as np
import pytest

from scenarios.conformance import seeds
from scenarios.conformance.matrix import FIGURES as FLOORS


def _pairs(offset: float, spread: float, n: int = 32, base: float = 1.0):
    rng = np.random.default_rng(3)
    g = base + 0.2 * rng.standard_normal(n)
    return g, g + offset + spread * rng.standard_normal(n)


def test_the_verdict_is_the_interval_against_the_tolerance():
    """Velocity floor 0.05 deg/s, figure 1 deg/s: the tolerance is 0.05 (5 % of 1 = the floor)."""
    floor = FLOORS["rms_velocity_error"]
    g, j = _pairs(0.0, 0.01)
    assert seeds.paired(g, j, floor)["verdict"] == "within"  # interval about ±0.004
    g, j = _pairs(0.2, 0.01)
    assert seeds.paired(g, j, floor)["verdict"] == "outside"  # 0.2 ± 0.004, all beyond 0.05
    g, j = _pairs(0.04, 0.1)
    assert seeds.paired(g, j, floor)["verdict"] == "undecided"  # 0.04 ± 0.035 straddles 0.05
    p = seeds.paired([1.0, 2.0, 3.0], [1.5, 2.5, 3.0], floor)
    assert p["difference"] == pytest.approx(1.0 / 3.0)
    assert p["standard_error"] == pytest.approx(np.std([0.5, 0.5, 0.0], ddof=1) / np.sqrt(3))
    assert p["tolerance"] == pytest.approx(0.1)  # 5 % of the Gauss-Seidel mean 2.0, above the floor


def test_the_noise_cases_are_those_with_noise_on():
    cases = seeds.noise_cases(("table2", "lqg"))
    assert ("table2", "noise") in cases and ("table2", "tip_noise") in cases
    assert ("table2", "none") not in cases and ("lqg", "none_integral") not in cases
    assert ("lqg", "noise_integral") in cases


def test_a_run_over_two_seeds(tmp_path):
    """Table 2's noise cases, seeds 1 and 2, both steppings, native FMUs: the figures are real runs (each seed its
    own realisation; the steppings differ, the same seed in the same stepping repeats) and the table renders them."""
    data = seeds.run_seeds(("table2",), seeds=(1, 2), progress=False)
    assert [(r["scenario"], r["case"]) for r in data["rows"]] == [("table2", "noise"), ("table2", "tip_noise")]
    noise = data["rows"][0]
    for stepping in seeds.STEPPINGS:
        pos = noise[stepping]["rms_position_error"]
        assert len(pos) == 2 and pos[0] != pos[1]  # another seed, another realisation
        assert all(0.001 < x < 0.1 for x in pos)  # noise-driven: far above the noise-free 0.0018 deg, far below 1
    assert noise["gauss-seidel"]["rms_position_error"] != noise["jacobi"]["rms_position_error"]
    again = seeds.run_seeds(("table2",), seeds=(1, 2), progress=False)
    assert again["rows"] == data["rows"]  # seeded: bit for bit
    text = seeds.render(data)
    assert "table2/noise | position, deg" in text and "of 4 figures" in text
    assert sum(seeds.verdicts(data).values()) == 4
