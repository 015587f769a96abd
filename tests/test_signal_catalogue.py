"""One signal catalogue (issue 17): flexarm/data/signals.toml is where every FMU signal is declared."""

from __future__ import annotations

import pytest
from fmpy import read_model_description
from fmu_harness import built_fmus

from flexarm import signals
from flexarm.model import OBSERVABLE_NAMES
from flexarm.sensors import MEASURED_SIGNALS, TRUE_SIGNALS
from fmu_build.interface_doc import blocks, render
from fmu_build.registry import DOC_FILE
from scenarios.run.setup import PLANT_STATE


def test_the_committed_interface_document_equals_the_generated_one():
    """Regenerate with `python build_fmus.py --write-doc` after editing the catalogue."""
    text = DOC_FILE.read_text(encoding="utf-8")
    assert blocks(text) == [(f, c) for f in ("plant", "sensors", "controller") for c in ("input", "output")] + [
        ("reference", "output")]
    assert render(text) == text


def test_library_and_scenarios_lists_come_from_the_catalogue():
    # the physics vectors: every signal but the loop's sample indices (docs/control.md)
    assert OBSERVABLE_NAMES == signals.names("plant", "output", indices=False) and len(OBSERVABLE_NAMES) == 40
    assert signals.names("plant", "output")[40:] == ("sample_index", "tau_lag", "tau1_applied", "tau2_applied")
    assert [tuple(s) for s in TRUE_SIGNALS] == [(s.name, s.unit, s.description)
                                                for s in signals.signals("sensors", "input", indices=False)]
    assert [tuple(s) for s in MEASURED_SIGNALS] == [(s.name, s.unit, s.description)
                                                    for s in signals.signals("sensors", "output", indices=False)]
    assert PLANT_STATE == [f"theta{i}" for i in range(1, 12)] + [f"omega{i}" for i in range(1, 12)]


def test_the_catalogue_wires_by_name_with_matching_units():
    """Every sensors input is a plant output, every controller input a sensors output, with the same unit."""
    by = {(s.fmu, s.causality, s.name): s for s in signals.catalogue()}
    for dst, src in (("sensors", "plant"), ("controller", "sensors"), ("plant", "controller")):
        for s in signals.signals(dst, "input"):
            source = by.get((src, "output", s.name))
            if source is None and dst == "controller" and s.group == signals.INDEX_GROUP:
                source = by.get(("plant", "output", s.name))  # the plant's report of the torque it held
            assert source is not None and source.unit == s.unit, (dst, s.name)


@pytest.mark.parametrize("fmu", ["plant", "sensors", "controller", "controller_ff", "controller_fb",
                                 "controller_dlqr"])
def test_each_fmu_declares_exactly_its_catalogue_rows(fmu):
    md = read_model_description(str(built_fmus()[fmu]))
    kind = "controller" if fmu.startswith("controller") else fmu
    for causality in ("input", "output"):
        got = [(v.name, v.unit or "", v.description) for v in md.modelVariables if v.causality == causality]
        want = [(s.name, s.unit, s.description) for s in signals.signals(kind, causality)]
        if kind == "sensors":  # the FMU's text says what the channel is to it (the index's is the catalogue's)
            index = signals.names(kind, causality, signals.INDEX_GROUP)
            want = [(n, u, d if n in index else f"True {d} (plant output {n})" if causality == "input"
                     else f"Measured: {d}") for n, u, d in want]
        assert got == want, (fmu, causality)


def test_a_malformed_catalogue_is_refused_naming_the_row(tmp_path):
    bad = tmp_path / "signals.toml"
    bad.write_text('[[signal]]\nfmu = "plant"\ncausality = "output"\nname = "x"\nunit = "m"\ngroup = "tip"\n')
    with pytest.raises(signals.SignalError, match=r"signal\[0\].*description"):
        signals.catalogue(bad)
    bad.write_text('[[signal]]\nfmu = "arm"\ncausality = "output"\nname = "x"\nunit = "m"\ngroup = "g"\n'
                   'description = "d"\n')
    with pytest.raises(signals.SignalError, match="fmu must be one of"):
        signals.catalogue(bad)
