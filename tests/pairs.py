"""Timing holds by pairs: an attack phase held to a quiet control phase of the same run.

The test machine is shared: its host takes the processors away now and then, for tens of
ms, whatever runs. One such burst inside one attack phase is not the attack's; an attack
that costs the scan shows in every attack phase. So a pair that misses its hold may be
followed by another quiet phase and another attack, up to ``PAIRS`` pairs, and one pair
must hold. Every pair measured is printed, the ones that missed too."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TypeVar

#: pairs (quiet phase, attack phase) a hold measures at most
PAIRS = 3

P = TypeVar("P")


def held_in_a_pair(what: str, first: P, holds: Callable[[P], bool],
                   again: Callable[[], P] | None = None, pairs: int = PAIRS) -> list[P]:
    """Hold ``first`` (a pair's figures) with ``holds``; while it misses, measure
    ``again()`` (one more quiet phase and one more attack, the same figures), up to
    ``pairs`` in all. Fails, with every pair, when none held; the pairs measured."""
    measured = [first]
    while True:
        pair = measured[-1]
        sys.stderr.write(f"{what}, pair {len(measured)}: {pair}\n")
        if holds(pair):
            return measured
        if again is None or len(measured) >= pairs:
            break
        measured.append(again())
    raise AssertionError(f"{what}: none of {len(measured)} pair(s) held: " +
                         "; ".join(str(p) for p in measured))
