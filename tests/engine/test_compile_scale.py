"""Compiling a chart grows linearly with its size, in memory and in source: measured by
ratios (tracemalloc peaks, characters of generated code), never by wall-clock time.

The shapes an attacker chose: a selection (OR) divergence of n branches from one step, all
on the same condition (the priority of file order made every branch test every earlier
one: n²/2 terms, 1.6 GB at 1000 branches), and a chain of n steps. Four times n must be
about four times the peak memory of ``compile_grafcet`` (generate, ``compile``, ``exec``)
and the generated source; quadratic growth would make them sixteen times."""

from __future__ import annotations

import dis
import tracemalloc
from collections.abc import Callable
from functools import partial
from pathlib import Path
from types import CodeType

import pytest

from bench.compile import chart_text
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


#: what CPython's compiler puts before a function's own code: one MAKE_CELL per cell, the
#: closure's COPY_FREE_VARS, RESUME (CACHE and EXTENDED_ARG are parts of instructions)
PROLOGUE = frozenset({"RESUME", "MAKE_CELL", "COPY_FREE_VARS", "CACHE", "EXTENDED_ARG",
                      "NOP"})


def cell_moves(g: Grafcet) -> int:
    """The instructions CPython's compiler moves to put the cells of ``make`` in place:
    it inserts one MAKE_CELL per cell at the start of the function's first basic block,
    moving what that block already holds each time (3.11 to 3.13), so cells x the length
    of that block (its instructions up to the first jump or return)."""
    code = compile(Compiler(g).generate(), "<scale>", "exec")
    make = next(c for c in code.co_consts if isinstance(c, CodeType) and c.co_name == "make")
    first = 0
    for ins in dis.get_instructions(make):
        if "JUMP" in ins.opname or ins.opname.startswith("RETURN"):
            break
        first += ins.opname not in PROLOGUE
    return len(make.co_cellvars) * first


@pytest.mark.parametrize("shape", ["blocks", "chain"])
def test_compile_puts_the_cells_in_place_in_linear_work(shape: str, tmp_path: Path) -> None:
    """Python's ``compile()`` of a 4000-step chart's scan took 7.4 times the machine
    instructions of a 1000-step one: the first basic block of ``make`` held the unpacking
    of every slot, behind which each of the cells' MAKE_CELL was inserted (n² moves).
    Counted as those moves, not timed: four times the chart, about four times the moves
    (14-15 times before make's first line ended that block)."""
    text = chart_text if shape == "blocks" else chain_text
    moves = []
    for k in (150, 600):
        path = tmp_path / f"{k}.yaml"
        path.write_text(text(k), encoding="utf-8")
        moves.append(cell_moves(load_grafcet(str(path))))
    assert moves[0] > 0, "make has no cell: the count measures nothing"
    assert_linear(f"{shape}: the instructions moved to make the cells", moves[0], moves[1],
                  4)
