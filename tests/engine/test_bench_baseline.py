"""The hand-written baselines of bench/scan.py agree with the compiled plant.

bench.scan times the compiled drawer tester against two hand-written versions; a ratio
means something only if they compute the same thing. These run the bench's own check
(short, not a timing test) and show that it catches a baseline that diverges.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import bench.handwritten as hw
from bench.scan import PERIOD, check_baselines, check_counts, compiled_record, write_files

N = 10  # testers: at 10 phases of the input pattern
CYCLES = 2 * PERIOD + 300  # every tester through the whole story twice


def test_both_baselines_match_the_compiled_plant_at_every_cycle(tmp_path: Path) -> None:
    assert check_baselines(str(tmp_path), N, CYCLES) == {}


def test_the_check_story_ends_a_test_and_starts_a_new_one(tmp_path: Path) -> None:
    """The count limit is exercised: some tester reaches 1000 closes and later restarts
    from 0 (otherwise a baseline wrong about the limit would pass)."""
    ppath, spath = write_files(str(tmp_path), N, CYCLES)
    record = compiled_record(ppath, spath, N, check_counts(N))
    width = len(hw.FIELDS)
    count = hw.FIELDS.index("sCierres")
    ended = [i for i in range(N)
             if any(a[i * width + count] == hw.LIMIT and b[i * width + count] == 0
                    for a, b in zip(record, record[1:], strict=False))]
    assert ended, "no tester finished a test and began a new one"


@pytest.mark.parametrize(("name", "value"), [("LIMIT", hw.LIMIT + 1),
                                             ("TEN_S", hw.TEN_S + hw.CYCLE_NS)])
def test_the_check_names_a_baseline_that_diverges(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str, value: int) -> None:
    """Both baselines written with a wrong limit of closes, or a failure time one cycle
    late: the check reports each, at a cycle and a tester."""
    monkeypatch.setattr(hw, name, value)
    found = check_baselines(str(tmp_path), N, CYCLES)
    assert sorted(found) == ["hand", "inline"]
    for why in found.values():
        assert why.startswith("cycle ") and ", tester t" in why
