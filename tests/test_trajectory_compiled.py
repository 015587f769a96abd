"""The compiled, cached solvers (flexarm.trajectory.compiled): the functions CasADi compiles are the ones it
interprets, the cache is keyed by what an entry is made from, a damaged entry is made again, and without a compiler
the caller gets None (its interpreted solver).

Tolerances: the generated C performs the SX graph's operations in the graph's order, so on x86-64 the compiled
values are the interpreted ones bit for bit; 1e-13 relative leaves room for a compiler that contracts a*b + c into a
fused multiply-add (one rounding less per operation, on platforms where FMA is baseline).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from flexarm import load_parameters
from flexarm.trajectory import compiled
from flexarm.trajectory import stage_form as sf

REL = 1e-13


def _toy(scale: float = 1.0) -> ca.Function:
    x, p = ca.SX.sym("x", 3), ca.SX.sym("p", 2)
    g = ca.vertcat(ca.sin(x[0]) * x[1] * p[0], x[2] ** 3 + scale * p[1] * x[0] * x[1])
    return ca.Function("toy", [x, p], [g, ca.sumsqr(x) * p[0]], ["x", "p"], ["g", "cost"])


def _derivatives(functions) -> ca.Function:
    """What an NLP solver asks of its oracle: g, its Jacobian and the Lagrangian's Hessian, by CasADi's MX AD."""
    (toy,) = functions
    x, p, lam = ca.MX.sym("x", 3), ca.MX.sym("p", 2), ca.MX.sym("lam", 2)
    g, cost = toy(x, p)
    hessian, _ = ca.hessian(cost + ca.dot(lam, g), x)
    return ca.Function("toy_derivatives", [x, p, lam], [g, ca.jacobian(g, x), hessian])


def _values(f: ca.Function, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [np.asarray(v) for v in f(rng.normal(size=3), rng.normal(size=2), rng.normal(size=2))]


def _close(a: list[np.ndarray], b: list[np.ndarray]) -> bool:
    return all(np.allclose(x, y, rtol=REL, atol=REL * max(1.0, np.abs(y).max())) for x, y in zip(a, b))


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv(compiled.CACHE_VARIABLE, str(tmp_path))
    monkeypatch.delenv(compiled.DISABLE_VARIABLE, raising=False)
    return tmp_path


def test_compiled_derivatives_are_the_interpreted_ones_and_a_second_process_loads_them(cache):
    lines = []
    made = compiled.load_or_make("toy", [_toy()], _derivatives, "options", ("p",), progress=lines.append)
    assert any(line.startswith("compiling") for line in lines) and any("cached in" in line for line in lines)
    interpreted = _derivatives([_toy()])
    for seed in range(3):
        assert _close(_values(made, seed), _values(interpreted, seed))
    lines.clear()
    loaded = compiled.load_or_make("toy", [_toy()], _derivatives, "options", ("p",), progress=lines.append)
    assert lines == []  # from the cache: nothing compiled, nothing made
    assert _close(_values(loaded, 7), _values(interpreted, 7))
    assert len(list(cache.iterdir())) == 1


def test_a_changed_function_or_option_is_a_new_entry_and_the_cache_keeps_those_used_last(cache):
    import os
    import time

    first = compiled.load_or_make("toy", [_toy()], _derivatives, "options", ("p",), progress=lambda _: None)
    other = compiled.load_or_make("toy", [_toy(2.0)], _derivatives, "options", ("p",), progress=lambda _: None)
    assert len(list(cache.iterdir())) == 2
    assert not _close(_values(first, 1), _values(other, 1))  # the scaled term reached the compiled code
    assert _close(_values(other, 1), _values(_derivatives([_toy(2.0)]), 1))
    entries = {e: (e / "toy.casadi").stat().st_mtime for e in cache.iterdir()}
    first_entry = min(entries, key=entries.get)
    for e in entries:  # the first made is the one used last: a load renews its time
        os.utime(e / "toy.casadi", (time.time() - 100, time.time() - 100))
    compiled.load_or_make("toy", [_toy()], _derivatives, "options", ("p",), progress=lambda _: None)
    lines = []
    compiled.load_or_make("toy", [_toy()], _derivatives, "other options", ("p",), progress=lines.append)
    kept = set(cache.iterdir())
    assert len(kept) == compiled.KEEP_ENTRIES and first_entry in kept  # _toy(2.0)'s entry, used least lately, went
    assert any(line.startswith("removed") for line in lines)


def test_a_damaged_entry_is_made_again(cache):
    compiled.load_or_make("toy", [_toy()], _derivatives, "options", ("p",), progress=lambda _: None)
    (entry,) = cache.iterdir()
    (entry / "toy.casadi").write_bytes(b"not a serialised CasADi function")
    lines = []
    again = compiled.load_or_make("toy", [_toy()], _derivatives, "options", ("p",), progress=lines.append)
    assert any("did not load" in line for line in lines)
    assert _close(_values(again, 2), _values(_derivatives([_toy()]), 2))
    assert ca.Function.load(str(entry / "toy.casadi")).name() == "toy_derivatives"


def test_turned_off_or_without_a_compiler_the_caller_gets_none(cache, monkeypatch):
    monkeypatch.setenv(compiled.DISABLE_VARIABLE, "0")
    assert compiled.load_or_make("toy", [_toy()], _derivatives, "options", ("p",)) is None
    monkeypatch.delenv(compiled.DISABLE_VARIABLE)
    monkeypatch.setenv("PATH", str(cache))
    monkeypatch.delenv("CC", raising=False)
    assert compiled.c_compiler() is None
    assert list(cache.iterdir()) == []


def test_the_replan_solver_compiled_evaluates_what_the_interpreted_one_does():
    """The re-plan's solver as shipped (N = 200, d = 5; from the user's cache, built there on first use): its
    constraint Jacobian and Lagrangian Hessian at the committed slew's point, against the interpreted solver's."""
    from flexarm.trajectory import load_trajectory
    from flexarm.trajectory.warm import solution_from_trajectory

    params = load_parameters().with_payload(0.275)
    fast, slow = sf.stage_form(params), sf.stage_form(params, compiled=False)
    x = fast.point(solution_from_trajectory(load_trajectory(), params), params)
    p = fast.parameters(params)
    lam = np.random.default_rng(0).normal(size=fast.lbg.size)
    for name, args in (("nlp_jac_g", [x, p]), ("nlp_hess_l", [x, p, 1.0, lam])):
        a = [np.asarray(ca.DM(v).nonzeros()) for v in fast.solver.get_function(name)(*args)]
        b = [np.asarray(ca.DM(v).nonzeros()) for v in slow.solver.get_function(name)(*args)]
        assert _close(a, b), name


def test_an_unwritable_cache_folder_means_the_interpreted_solver(tmp_path, monkeypatch):
    blocked = tmp_path / "a file, not a folder"
    blocked.write_text("")
    monkeypatch.setenv(compiled.CACHE_VARIABLE, str(blocked))
    monkeypatch.delenv(compiled.DISABLE_VARIABLE, raising=False)
    lines = []
    assert compiled.load_or_make("toy", [_toy()], _derivatives, "options", ("p",), progress=lines.append) is None
    assert any("cannot be written" in line for line in lines)
