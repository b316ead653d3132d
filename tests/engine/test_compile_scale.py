"""Compiling a chart grows linearly with its size, in memory and in source: measured by
ratios (tracemalloc peaks, characters of generated code), never by wall-clock time.

The shapes an attacker chose: a selection (OR) divergence of n branches from one step, all
on the same condition (the priority of file order made every branch test every earlier
one: n²/2 terms, 1.6 GB at 1000 branches), and a chain of n steps. Four times n must be
about four times the peak memory of ``compile_grafcet`` (generate, ``compile``, ``exec``)
and the generated source; quadratic growth would make them sixteen times."""

from __future__ import annotations

import tracemalloc
from collections.abc import Callable
from functools import partial
from pathlib import Path

import pytest

from bench.divergence import chain_text, fan_text
from runtime.compiler.codegen import Compiler, compile_grafcet
from runtime.language.grafcetfile import load_grafcet
from runtime.language.model import Grafcet


def peak(fn: Callable[[], object]) -> int:
    """The peak of memory allocated while ``fn`` runs, bytes."""
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        fn()
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def assert_linear(what: str, small: float, large: float, factor: int = 2) -> None:
    """``large`` measured at ``factor`` times the size of ``small``: at most 1.5 times
    ``factor`` times it (linear is ``factor``, quadratic its square; the allowance covers
    a table doubling its capacity at one size and not at the other)."""
    assert large <= 1.5 * factor * small, (
        f"{what} grows faster than the chart: x{large / small:.2f} for {factor} times the "
        f"size ({small:.0f} -> {large:.0f})")


SHAPES: dict[str, tuple[Callable[[int], str], int]] = {
    "fan immediate": (fan_text, 75), "fan codesys": (lambda n: fan_text(n, "codesys"), 75),
    "fan stable": (lambda n: fan_text(n, "stable"), 75), "chain": (chain_text, 150)}


@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_compiling_grows_linearly(shape: str, tmp_path: Path) -> None:
    text, n = SHAPES[shape]
    charts: list[Grafcet] = []
    for k in (n, 4 * n):
        path = tmp_path / f"{k}.yaml"
        path.write_text(text(k), encoding="utf-8")
        charts.append(load_grafcet(str(path)))
    small, large = (len(Compiler(g).generate()) for g in charts)
    assert_linear(f"{shape}: the generated source", small, large, 4)
    small, large = (peak(partial(compile_grafcet, g)) for g in charts)
    assert_linear(f"{shape}: the memory of compile_grafcet", small, large, 4)
