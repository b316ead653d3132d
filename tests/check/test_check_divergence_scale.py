"""``softplc check`` of a wide OR divergence grows linearly with its branches: counted and
measured by ratios (solver calls, diagnostics, tracemalloc peaks), never timed.

A divergence of n branches from one step has n²/2 pairs of transitions: G201 decided each
pair (4000 branches: more than eight minutes) and warned once per pair on the same
condition; G204 compared each transition entering the step with each one leaving it. Now a
transition on the same condition as an earlier one is paired with that one only, the other
pairs are decided up to a bound that grows with the chart (a note says so), and G204 looks
conditions up (bench/divergence.py prints the times)."""

from __future__ import annotations

import tracemalloc
from pathlib import Path
from typing import Any

import pytest

from bench.divergence import fan_text
from runtime.checker import rules
from runtime.checker.logic import Logic
from runtime.checker.rules import check_grafcet
from runtime.language.grafcetfile import load_grafcet
from tests.engine.test_compile_scale import assert_linear


def measured(path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[int, int, int, list[Any]]:
    """(solver calls, diagnostics, peak bytes, diagnostics) of checking ``path``."""
    g = load_grafcet(str(path))
    calls = [0]
    solve = Logic.solve

    def counting(self: Logic, *args: Any, **kwargs: Any) -> Any:
        calls[0] += 1
        return solve(self, *args, **kwargs)
    monkeypatch.setattr(Logic, "solve", counting)
    tracemalloc.start()
    try:
        diags = check_grafcet(g)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
        monkeypatch.setattr(Logic, "solve", solve)
    return calls[0], len(diags), peak, diags


@pytest.mark.parametrize("distinct", [False, True], ids=["same condition", "exclusive"])
def test_a_wide_divergence_checks_in_linear_work(distinct: bool, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    got = []
    for n in (60, 240):
        path = tmp_path / f"fan{n}.yaml"
        path.write_text(fan_text(n, distinct=distinct), encoding="utf-8")
        got.append(measured(path, monkeypatch))
    (s1, d1, p1, _), (s2, d2, p2, diags) = got
    assert_linear("the solver calls", s1, s2, 4)
    assert_linear("the diagnostics", max(d1, 1), max(d2, 1), 4)
    assert_linear("the memory of check", p1, p2, 4)
    g201 = [d for d in diags if d.code == "G201"]
    if distinct:  # the pairs past the bound are not decided, and a note says so
        (note,) = g201
        assert note.severity == "note" and "exclusivity decided for " in note.message
        assert s2 <= rules.PAIRS_AT_LEAST + rules.PAIRS_PER_TRANSITION * 480 + 2 * 480
    else:  # each branch after the first: one warning, against the first
        assert len(g201) == 239 and all("s0 → b0 (line" in d.message for d in g201)


def test_a_divergence_within_the_bound_is_decided_whole(tmp_path: Path) -> None:
    """Ten exclusive branches and ten on one condition: every pair decided, no note."""
    path = tmp_path / "f.yaml"
    path.write_text(fan_text(10, distinct=True), encoding="utf-8")
    diags = check_grafcet(load_grafcet(str(path)))
    assert not [d for d in diags if d.code == "G201"], [str(d) for d in diags]
    path.write_text(fan_text(10), encoding="utf-8")
    g201 = [d for d in check_grafcet(load_grafcet(str(path))) if d.code == "G201"]
    assert len(g201) == 9 and {d.severity for d in g201} == {"warning"}
