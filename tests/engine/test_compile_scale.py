"""Compiling a chart grows linearly with its size, in memory and in source: measured by
ratios (tracemalloc peaks, characters of generated code), never by wall-clock time.

The shapes an attacker chose: a selection (OR) divergence of n branches from one step, all
on the same condition (the priority of file order made every branch test every earlier
one: n²/2 terms, 1.6 GB at 1000 branches), and a chain of n steps. Doubling n must about
double the peak memory of ``compile_grafcet`` (generate, ``compile``, ``exec``) and the
generated source; quadratic growth would quadruple them."""

from __future__ import annotations

import tracemalloc
from collections.abc import Callable
from pathlib import Path

import pytest

from runtime.compiler.codegen import Compiler, compile_grafcet
from runtime.language.grafcetfile import load_grafcet
from runtime.language.model import Grafcet


def fan_text(n: int, scan: str = "immediate") -> str:
    """Step s0 and n branches b0..b(n-1), each entered from s0 on iGo (all at once: the
    first in file order wins) and left back to s0 on iStop."""
    lines = ["grafcet: Fan", f"scan: {scan}", "inputs: [iGo, iStop]", "outputs: [oMotor]",
             "steps:", "  s0: {initial: true}"]
    lines += [f"  b{i}: {{actions: [oMotor]}}" for i in range(n)]
    lines.append("transitions:")
    for i in range(n):
        lines += [f"  - {{from: s0, to: b{i}, when: iGo}}",
                  f"  - {{from: b{i}, to: s0, when: iStop}}"]
    return "\n".join(lines) + "\n"


def chain_text(n: int) -> str:
    """A loop of n steps, each passed on a rise of iGo."""
    lines = ["grafcet: Chain", "inputs: [iGo]", "outputs: [oMotor]", "steps:",
             "  s0: {initial: true}"]
    lines += [f"  s{i}: {{actions: [oMotor]}}" for i in range(1, n)]
    lines.append("transitions:")
    lines += [f"  - {{from: s{i}, to: s{(i + 1) % n}, when: ↑iGo}}" for i in range(n)]
    return "\n".join(lines) + "\n"


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


def assert_linear(what: str, small: float, large: float) -> None:
    """``large`` measured at twice the size of ``small``: at most 2.4 times it (linear
    is 2, quadratic 4)."""
    assert large <= 2.4 * small, (f"{what} grows faster than the chart: x{large / small:.2f} "
                                  f"for twice the size ({small:.0f} -> {large:.0f})")


SHAPES = {"fan immediate": (fan_text, 150), "fan codesys": (lambda n: fan_text(n, "codesys"), 150),
          "fan stable": (lambda n: fan_text(n, "stable"), 150), "chain": (chain_text, 300)}


@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_compiling_grows_linearly(shape: str, tmp_path: Path) -> None:
    text, n = SHAPES[shape]
    charts: list[Grafcet] = []
    for k in (n, 2 * n):
        path = tmp_path / f"{k}.yaml"
        path.write_text(text(k), encoding="utf-8")
        charts.append(load_grafcet(str(path)))
    sources = [len(Compiler(g).generate()) for g in charts]
    assert_linear(f"{shape}: the generated source", *sources)
    peaks = [peak(lambda g=g: compile_grafcet(g)) for g in charts]
    assert_linear(f"{shape}: the memory of compile_grafcet", *peaks)
