"""tests/pairs.py: a timing hold measured in pairs, one of which must hold."""

from __future__ import annotations

import pytest

from tests.pairs import PAIRS, held_in_a_pair


def test_a_hold_met_by_the_first_pair_measures_no_other() -> None:
    def again() -> int:
        raise AssertionError("measured again")
    assert held_in_a_pair("t", 1, lambda p: p == 1, again) == [1]


def test_a_missed_hold_measures_again_until_a_pair_holds() -> None:
    more = iter([5, 2, 7])
    assert held_in_a_pair("t", 9, lambda p: p < 3, lambda: next(more)) == [9, 5, 2]


def test_a_hold_no_pair_meets_fails_with_every_pair() -> None:
    more = iter(range(10, 20))
    with pytest.raises(AssertionError, match=r"none of 3 pair\(s\) held: 9; 10; 11"):
        held_in_a_pair("t", 9, lambda p: p < 3, lambda: next(more))
    assert PAIRS == 3


def test_without_again_the_first_pair_decides() -> None:
    with pytest.raises(AssertionError, match=r"none of 1 pair\(s\) held: 9"):
        held_in_a_pair("t", 9, lambda p: p < 3)
