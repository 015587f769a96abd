"""ILC scenario files: a scenario with an ``[ilc]`` table, its settings read and checked (:class:`IlcSettings`).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from scenarios.config import SCENARIO_DIR, Scenario, ScenarioError, load_scenario

#: Keys of the [ilc] table and what each allows.
ILC_KEYS = {
    "trials": "an integer in [1, 1000]",
    "learn_case": "the key of a case in [[cases]]",
    "seed_base": "an integer >= 0 (trial j uses noise seed seed_base + j)",
    "model_payload_mass": "a payload in [0, 10] kg for the learning's model on the paper's slew (on a re-planned "
                          "slew the model carries the payload it was re-planned for)",
    "settling_model_payload_mass": "a payload in [0, 10] kg for the learning's model at and after t_f "
                                   "(default: model_payload_mass)",
    "error_weight": "a weight > 0, rad^-2",
    "input_weight": "a weight > 0, (N m)^-2",
    "leak_weight": "a weight >= 0, (N m)^-2",
    "learning_gain": "a step factor in (0, 2)",
    "settling_weight": "a factor in [0, 1e6] on error_weight for the samples at and after t_f (1: none)",
    "settling_tip_weight": "a weight in [0, 1e12] m^-2 on the tip deviation the measured angles imply, at and "
                           "after t_f (0: none)",
    "q_filter_cutoff_hz": "a cut-off in [0, 500) Hz (0: no Q-filter)",
    "q_filter_order": "an integer in [1, 8]",
    "settling_q_filter_cutoff_hz": "a cut-off in [0, 500) Hz for the Q-filter at and after t_f (0: none; default "
                                   "q_filter_cutoff_hz)",
    "evaluate_cases": "a list of case keys",
    "evaluate_samples": "an integer in [scenario.samples, 100000]: the length of the evaluate_cases runs, 1 ms "
                        "samples (the correction is zero past its own samples; default scenario.samples)",
    "replan_payload_mass": "a payload in [0, 10] kg: the slew re-planned and the gains designed for the arm carrying "
                           "it, the reference the learning tracks (flexarm.payload_data; absent: the paper's slew)",
    "identify_payload": "true or false: the payload is unknown; trial 0 runs the paper's slew, the payload is "
                        "identified from its measurements (flexarm.payload_fit), the slew re-planned for it, and the "
                        "learning starts on that slew (not with replan_payload_mass)",
    "safeguard": "true or false: each update starts from the trial with the lowest measured error so far, its "
                 "step doubling after a new lowest and halving otherwise (flexarm.ilc_trial.Safeguard; default "
                 "false: every update kept)",
}


@dataclass
class IlcSettings:
    trials: int
    learn_case: str
    seed_base: int
    model_payload_mass: float
    settling_model_payload_mass: float
    error_weight: float
    input_weight: float
    leak_weight: float
    learning_gain: float
    settling_weight: float
    settling_tip_weight: float
    q_filter_cutoff_hz: float
    q_filter_order: int
    settling_q_filter_cutoff_hz: float
    evaluate_cases: list[str]
    evaluate_samples: int
    replan_payload_mass: float | None = None
    identify_payload: bool = False
    safeguard: bool = False

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def _ilc_table(path: Path) -> dict | None:
    try:
        doc = tomllib.loads(path.read_bytes().decode("utf-8"))
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError):
        return None  # not an ILC scenario; load_scenario then refuses the file naming what is wrong
    return doc.get("ilc")


def _path(name) -> Path:
    p = Path(name)
    return SCENARIO_DIR / f"{p.name}.toml" if not p.suffix else p


def is_ilc_scenario(name) -> bool:
    """Whether the scenario name or file has an ``[ilc]`` table (run by :func:`run_ilc`)."""
    p = _path(name)
    return p.is_file() and _ilc_table(p) is not None


def load_ilc(name) -> tuple[Scenario, IlcSettings]:
    """The scenario (validated by :func:`scenarios.config.load_scenario`) and its ``[ilc]`` settings, each
    refused naming the field and what it allows."""
    scenario = load_scenario(name)
    raw = _ilc_table(scenario.path) or {}
    where = f"{scenario.path.name}: ilc"
    unknown = set(raw) - set(ILC_KEYS)
    if unknown:
        raise ScenarioError(f"{where}: keys allowed: {sorted(ILC_KEYS)}, got {sorted(unknown)}")
    keys = [c.key for c in scenario.cases]

    def get(key, default, ok):
        v = raw.get(key, default)
        if not ok(v):
            raise ScenarioError(f"{where}.{key}: {ILC_KEYS[key]}, got {v!r}")
        return v

    def integer(lo, hi):
        return lambda v: isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi

    def number(lo, hi, lo_open=False):
        return lambda v: (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                          and (v > lo if lo_open else v >= lo) and v <= hi)

    s = IlcSettings(
        trials=get("trials", 10, integer(1, 1000)),
        learn_case=get("learn_case", keys[0], lambda v: v in keys),
        seed_base=get("seed_base", 1, integer(0, 2**62)),
        model_payload_mass=float(get("model_payload_mass", 0.0, number(0.0, 10.0))),
        settling_model_payload_mass=float(get("settling_model_payload_mass", raw.get("model_payload_mass", 0.0),
                                              number(0.0, 10.0))),
        error_weight=float(get("error_weight", 1.0, number(0.0, 1e12, True))),
        input_weight=float(get("input_weight", 1e-4, number(0.0, 1e12, True))),
        leak_weight=float(get("leak_weight", 0.0, number(0.0, 1e12))),
        learning_gain=float(get("learning_gain", 1.0, lambda v: number(0.0, 1.999999, True)(v))),
        settling_weight=float(get("settling_weight", 1.0, number(0.0, 1e6))),
        settling_tip_weight=float(get("settling_tip_weight", 0.0, number(0.0, 1e12))),
        q_filter_cutoff_hz=float(get("q_filter_cutoff_hz", 10.0, lambda v: number(0.0, 499.999)(v))),
        q_filter_order=get("q_filter_order", 2, integer(1, 8)),
        settling_q_filter_cutoff_hz=float(get("settling_q_filter_cutoff_hz", raw.get("q_filter_cutoff_hz", 10.0),
                                              lambda v: number(0.0, 499.999)(v))),
        evaluate_cases=list(get("evaluate_cases", [], lambda v: isinstance(v, list) and all(x in keys for x in v))),
        evaluate_samples=0,
        replan_payload_mass=(None if "replan_payload_mass" not in raw else
                             float(get("replan_payload_mass", None, number(0.0, 10.0)))),
        identify_payload=get("identify_payload", False, lambda v: isinstance(v, bool)),
        safeguard=get("safeguard", False, lambda v: isinstance(v, bool)),
    )
    if (s.identify_payload or s.replan_payload_mass is not None) and any(
            k in raw for k in ("model_payload_mass", "settling_model_payload_mass")):
        raise ScenarioError(f"{where}: model_payload_mass and settling_model_payload_mass are for the paper's slew; "
                            "on a re-planned slew the learning's model carries the payload it was re-planned for "
                            "(remove them)")
    if s.identify_payload and s.replan_payload_mass is not None:
        raise ScenarioError(f"{where}.identify_payload: true only without replan_payload_mass (a payload is either "
                            "known or identified), got both")
    if scenario.samples == "trajectory":
        raise ScenarioError(f"{scenario.path.name}: scenario.samples: an integer number of samples for an ILC "
                            "scenario (the slew and the settling after it), got \"trajectory\"")
    s.evaluate_samples = get("evaluate_samples", scenario.samples, integer(scenario.samples, 100_000))
    if abs(scenario.step_size - 1e-3) > 1e-12:
        raise ScenarioError(f"{scenario.path.name}: scenario.step_size_s: 0.001 for an ILC scenario (the learning "
                            f"works on the 1 ms samples), got {scenario.step_size!r}")
    return scenario, s
