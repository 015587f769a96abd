"""Scenario files: the shipped ones load, and bad ones are refused with the field named."""

import pytest

from flexarm.provenance import write_atomic
from scenarios.config import ScenarioError, list_scenarios, load_scenario

GOOD = """
[scenario]
name = "mine"
samples = 10
order = ["plant", "controller"]
[fmus]
plant = "plant"
controller = "controller_ff"
[parameters.plant]
payload_mass = 0.1
[[cases]]
key = "a"
[[cases]]
key = "b"
parameters.plant.payload_mass = 0.2
"""


def write(tmp_path, text):
    p = tmp_path / "s.toml"
    p.write_text(text)
    return p


def test_shipped_scenarios_load():
    names = {s.name for s in list_scenarios()}
    assert {"table1", "table2", "table3"} <= names
    t2 = load_scenario("table2")
    assert [c.key for c in t2.cases] == ["none", "noise", "tip", "tip_noise"]
    assert t2.samples == "trajectory" and t2.step_size == 0.001
    tip_noise = t2.cases[3].parameters
    assert tip_noise["plant"]["payload_mass"] == 0.275 and tip_noise["sensors"]["noise_enabled"] is True
    assert t2.cases[0].parameters["plant"]["payload_mass"] == 0.0


def test_cases_override_base_parameters(tmp_path):
    sc = load_scenario(write(tmp_path, GOOD))
    assert sc.cases[0].parameters["plant"]["payload_mass"] == 0.1
    assert sc.cases[1].parameters["plant"]["payload_mass"] == 0.2


@pytest.mark.parametrize("old,new,field", [
    ('samples = 10', 'samples = -3', "scenario.samples"),
    ('samples = 10', 'samples = 10\nstep_size_s = 0.0', "scenario.step_size_s"),
    ('order = ["plant", "controller"]', 'order = ["plant"]', "scenario.order"),
    ('[parameters.plant]', '[parameters.plnt]', "parameters.plnt"),
    ('key = "a"', 'key = "a b"', "cases[0].key"),
    ('key = "b"', 'key = "a"', "unique keys"),
    ('name = "mine"', 'name = "mine"\nsampels = 3', "sampels"),
    ('key = "b"', 'key = "b"\nfmus.contoller = "controller_fb"', "cases[1].fmus.contoller"),
    ('key = "b"', 'key = "b"\nfmu.controller = "controller_fb"', "cases[1]: keys allowed"),
])
def test_bad_fields_are_named(tmp_path, old, new, field):
    with pytest.raises(ScenarioError, match=field.replace("[", r"\[").replace("]", r"\]")):
        load_scenario(write(tmp_path, GOOD.replace(old, new, 1)))


def test_cases_may_swap_an_fmu(tmp_path):
    sc = load_scenario(write(tmp_path, GOOD.replace('key = "b"', 'key = "b"\nfmus.controller = "controller_fb"')))
    assert sc.cases[0].fmus == {"plant": "plant", "controller": "controller_ff"}
    assert sc.cases[1].fmus == {"plant": "plant", "controller": "controller_fb"}
    swaps = {c.key: c.fmus["controller"] for c in load_scenario("compare_ff_fb").cases}
    assert swaps == {"ff": "controller_ff", "fb": "controller_fb", "both": "controller",
                     "ff_tip": "controller_ff", "fb_tip": "controller_fb", "both_tip": "controller"}


def test_unknown_scenario_lists_the_known_ones():
    with pytest.raises(ScenarioError, match="table2"):
        load_scenario("tabel2")


def test_atomic_write_leaves_nothing_half_written(tmp_path):
    target = tmp_path / "out.json"
    write_atomic(target, "old")

    class Exploding:
        def encode(self):
            raise OSError("disk full")  # the failure happens after the temporary file exists

    with pytest.raises(OSError, match="disk full"):
        write_atomic(target, Exploding())
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]
