"""A scenario file at fault is one line at its place (FILE:LINE:COL: error: ...), before
anything runs, and ``softplc test`` exits 2 for it."""

from __future__ import annotations

from pathlib import Path

import pytest

from runtime.cli import main
from runtime.language.filekind import file_kind
from tests.scenario.kit import DRAWER, PLANT, STORY, cli, run, write


def error_of(tmp_path: Path, entry: str) -> tuple[int, int, str]:
    """(line, column, message) of the error of a scenario of the one expectation ``entry``."""
    out, path, _ = run(tmp_path, [entry])
    assert out.cases == [] and out.error is not None
    where, _, message = out.error.partition(": error: ")
    file, line, col = where.rsplit(":", 2)
    assert file == str(path)
    return int(line), int(col), message


def at(entry: str, part: str) -> int:
    """The column of ``part`` in the scenario line ``  - ENTRY``."""
    return 5 + entry.index(part)


LAST = STORY.count("\n") + 1  # the line of the one expectation


@pytest.mark.parametrize(("entry", "part", "message"), [
    ("{at: 0s, expect: {tester1.oAbrr: 1}}", "tester1.oAbrr",
     "unknown name 'tester1.oAbrr': expected instance.variable, instance.STEP.X, "
     "instance.STEP.T or driver.point (did you mean 'tester1.oAbrir'?)"),
    ("{at: 0s, expect: {tester1.oAbrir: 2}}", "2}",
     "'tester1.oAbrir' is a bool: expected 0 or 1 (true/false), found 2"),
    ("{at: 0s, expect: {tester1.oAbrir: '>= 1'}}", ">= 1",
     "'>=' compares numbers and times: expected == or !="),
    ("{at: 0s, expect: {tester1.sCierres: lots}}", "lots",
     "'tester1.sCierres' is an int: expected a number, found 'lots'"),
    ("{at: 0s, expect: {tester1.gsAbrir.T: 1500us}}", "1500us",
     "the trace holds times in whole ms: 1ms500us for 'tester1.gsAbrir.T' is not one"),
    ("{at: 3s, expect: {tester1.oAbrir: 1}}", "3s",
     "at: 3s is after the run: the last scan of the run is cycle 199 (t = 1s990ms)"),
    ("{cycle: 200, expect: {tester1.oAbrir: 1}}", "200",
     "cycle 200 is not in the run: the last scan of the run is cycle 199 (t = 1s990ms)"),
    ("{from: 1s, to: 3s, never: {tester1.oAbrir: 1}}", "3s",
     "to: 3s is after the run (it lasts 2s)"),
    ("{at: 0s, expcet: {tester1.oAbrir: 1}}", "expcet",
     "unknown key 'expcet' in an expectation at a time or a cycle: expected one of at, "
     "cycle, within, expect, name (did you mean 'expect'?)"),
    ("{at: 0s, never: {tester1.oAbrir: 1}}", "{at",
     "an expectation has one of 'at:'/'cycle:' with 'expect:', 'on_rise:'/'on_fall:' with "
     "'expect:', 'never:', 'always:', 'rises:': this one has at, never"),
    ("{expect: {tester1.oAbrir: 1}}", "{expect",
     "an expectation needs one of 'at:'/'cycle:' with 'expect:', 'on_rise:'/'on_fall:' "
     "with 'expect:', 'never:', 'always:', 'rises:'"),
    ("{rises: {tester1.sCierres: 1}}", "tester1.sCierres",
     "'tester1.sCierres' is an int: edges are of bools"),
    ("{on_rise: tester1.gsAbrir.T, expect: {tester1.oAbrir: 1}}", "tester1.gsAbrir.T",
     "'tester1.gsAbrir.T' is a time: edges are of bools"),
    ("{from: 1s, to: 1s, always: {tester1.oAbrir: 1}}", "{from",
     "empty window: no scan has from <= t < to"),
    ("{at: 0s, expect: {}}", "{}", "expected at least one name: value"),
    # a KeyError traceback before (found by the configs fuzzer: an edge without expect:)
    ("{on_rise: tester1.iAbierto, to: 1s}", "{on_rise",
     "an expectation on a rise needs 'expect: {name: value}' (what the scan where it "
     "rises holds)"),
    ("{on_fall: tester1.iAbierto}", "{on_fall",
     "an expectation on a fall needs 'expect: {name: value}' (what the scan where it "
     "falls holds)"),
    ("{at: 1s, expect: {tester1.oAbrir: 1}, within: soon}", "soon",
     "bad time literal 'soon' for within: expected e.g. 10s, 250ms, 1m30s or T#10s"),
])
def test_a_fault_in_an_expectation_is_one_line_at_its_place(
        tmp_path: Path, entry: str, part: str, message: str) -> None:
    assert error_of(tmp_path, entry) == (LAST, at(entry, part), message)


def test_a_fault_in_the_set_section_is_the_script_reader_s(tmp_path: Path) -> None:
    head = STORY.replace("tester1.iMarcha: 1", "tester1.oAbrir: 1", 1)
    out, path, _ = run(tmp_path, ["{at: 0s, expect: {tester1.oAbrir: 0}}"], head)
    line = head.split("\n").index("  - {at: 500ms, tester1.oAbrir: 1}") + 1
    assert out.error == (f"{path}:{line}:17: error: 'tester1.oAbrir' is not an input or chart "
                         "flag of tester1")


@pytest.mark.parametrize(("head", "where", "message"), [
    ("duration: 1s\nexpect:\n", (1, 1),
     "a scenario needs 'plant: FILE' (the plant it runs, relative to the scenario)"),
    (f"plant: {PLANT}\nexpect:\n", (1, 1),
     "the scenario needs 'duration:' or 'cycles:' (or a 'script:' that has one)"),
    (f"plant: {PLANT}\nduration: 1s\nexpects: []\nexpect:\n", (3, 1),
     "unknown key 'expects' in a scenario: expected one of plant, description, script, "
     "duration, cycles, set, expect (did you mean 'expect'?)"),
])
def test_a_fault_in_the_scenario_s_keys(tmp_path: Path, head: str, where: tuple[int, int],
                                        message: str) -> None:
    out, path, _ = run(tmp_path, ["{at: 0s, expect: {tester1.oAbrir: 0}}"], head)
    assert out.error == f"{path}:{where[0]}:{where[1]}: error: {message}"


def test_a_missing_plant_or_script_is_one_line(tmp_path: Path) -> None:
    out, path, _ = run(tmp_path, ["{at: 0s, expect: {t.x: 0}}"],
                       "plant: nowhere.yaml\nduration: 1s\nexpect:\n")
    assert out.error is not None
    assert out.error.startswith(f"{tmp_path / 'nowhere.yaml'}:1:1: error: ")
    out, path, _ = run(tmp_path, ["{at: 0s, expect: {tester1.oAbrir: 0}}"],
                       f"plant: {PLANT}\nscript: nowhere.yaml\nexpect:\n")
    assert out.error is not None
    assert out.error.startswith(f"{tmp_path / 'nowhere.yaml'}:1:1: error: ")


def test_the_script_s_inputs_and_length_come_with_it(tmp_path: Path) -> None:
    """``script:`` takes a simulation script's ``set:`` and length; the scenario's own
    ``set:`` adds to it and its own length wins."""
    head = (f"plant: {PLANT}\nscript: {DRAWER / 'story.yaml'}\n"
            "set:\n  - {at: 100ms, tester2.iMarcha: 1}\nexpect:\n")
    out, _, _ = run(tmp_path, ["{at: 500ms, expect: {tester1.gsAbrir.X: 1}}",
                               "{at: 100ms, expect: {tester2.gsAbrir.X: 1}}"], head)
    assert out.scans == 1750 and [c.failure for c in out.cases] == [None, None]
    out, _, _ = run(tmp_path, ["{at: 500ms, expect: {tester1.gsAbrir.X: 1}}"],
                    head.replace("set:", "cycles: 60\nset:"))
    assert out.scans == 60 and out.failed == []


def test_softplc_test_exits_2_on_a_file_error_and_prints_its_line(tmp_path: Path) -> None:
    path, _ = write(tmp_path, ["{at: 0s, expect: {tester1.oAbrr: 1}}"])
    status, out = cli("test", str(path))
    assert status == 2
    assert f"{path}:{LAST}:23: error: unknown name 'tester1.oAbrr'" in out
    assert out.endswith("softplc test: 1 scenario: 0 passed, 0 failed, 1 in error "
                        f"({out.rsplit('(', 1)[1]}")


def test_a_scenario_is_a_kind_of_file(tmp_path: Path) -> None:
    path, _ = write(tmp_path, ["{at: 0s, expect: {tester1.oAbrir: 0}}"])
    assert file_kind(str(path)) == "scenario"
    assert file_kind(str(DRAWER / "story.yaml")) == "script"
    assert file_kind(str(DRAWER / "drawer_tester.test.yaml")) == "scenario"


def test_softplc_check_reads_a_scenario_as_softplc_test_does(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good, _ = write(tmp_path, ["{at: 0s, expect: {tester1.oAbrir: 0}}"], name="g.test.yaml")
    bad, _ = write(tmp_path, ["{at: 0s, expect: {tester1.oAbrr: 1}}"], name="b.test.yaml")
    assert main(["check", str(good)]) == 0
    assert main(["check", str(bad)]) == 2
    assert f"{bad}:{LAST}:23: error: unknown name 'tester1.oAbrr'" in capsys.readouterr().out
