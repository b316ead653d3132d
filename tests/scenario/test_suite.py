"""``softplc test``: scenarios found by their name beside the plant, run in parallel worker
processes with the same outcome as in one, the exit status as pytest's (0, 1, and 2 for a
file in error, 5 for none found), and the JUnit XML report validated against Jenkins'
JUnit schema (junit-10.xsd, fetched as tests/scenario/junitschema.py says)."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest

from runtime.scenario.suite import discover, run_all, summarize
from tests.scenario.junitschema import JUNIT
from tests.scenario.kit import DRAWER, cli, write

PASSING = "{at: 500ms, expect: {tester1.gsAbrir.X: 1}}"
FAILING = "{at: 500ms, expect: {tester1.gsAbrir.X: 0}}"
BAD = "{at: 500ms, expect: {tester1.nothing: 0}}"


@pytest.fixture(scope="module")
def junit_schema() -> Any:
    return JUNIT.validator()


def test_scenarios_are_found_by_their_name_hidden_directories_left_out(tmp_path: Path
                                                                       ) -> None:
    for sub in ("a", "b/c", ".hidden", "__pycache__"):
        (tmp_path / sub).mkdir(parents=True)
        write(tmp_path / sub, [PASSING])
    (tmp_path / "a" / "story.yaml").write_text("duration: 1s\n", encoding="utf-8")
    write(tmp_path / "a", [PASSING], name="notes.yaml")
    files, errors = discover([str(tmp_path), str(tmp_path / "a" / "notes.yaml"),
                              str(tmp_path / "a"), str(tmp_path / "missing")])
    assert files == [str(tmp_path / "a" / "s.test.yaml"), str(tmp_path / "b/c/s.test.yaml"),
                     str(tmp_path / "a" / "notes.yaml")]  # named: taken; each file once
    assert errors == [f"{tmp_path / 'missing'}:1:1: error: no such file or directory"]


def test_parallel_workers_give_what_one_process_gives(tmp_path: Path) -> None:
    for k, entries in enumerate([[PASSING], [FAILING, PASSING], [BAD], [PASSING] * 3]):
        write(tmp_path, entries, name=f"s{k}.test.yaml")
    files, _ = discover([str(tmp_path)])

    def plain(jobs: int) -> list[Any]:
        return [(o.path, o.error, [(c.name, c.failure) for c in o.cases], o.scans)
                for o in run_all(files, jobs)]
    one, four = plain(1), plain(4)
    assert one == four
    assert [len(o[2]) for o in one] == [1, 2, 0, 3]
    assert sum(1 for o in one for c in o[2] if c[1]) == 1
    summary = summarize(run_all(files, 2), [])
    assert (summary.passed, summary.failed, summary.in_error) == (5, 1, 1)


@pytest.mark.parametrize(("entries", "status"), [
    ([[PASSING]], 0), ([[PASSING], [FAILING]], 1), ([[FAILING], [BAD]], 2), ([], 5)])
def test_the_exit_status_is_pytest_s(tmp_path: Path, entries: list[list[str]],
                                     status: int) -> None:
    for k, e in enumerate(entries):
        write(tmp_path, e, name=f"s{k}.test.yaml")
    got, out = cli("test", str(tmp_path))
    assert got == status, out
    if status == 5:
        assert out == f"softplc test: no scenario found in {tmp_path} (files named *.test.yaml)\n"


def test_a_path_that_names_nothing_is_a_file_error(tmp_path: Path) -> None:
    write(tmp_path, [PASSING])
    status, out = cli("test", str(tmp_path), str(tmp_path / "gone.test.yaml"))
    assert status == 2
    assert f"{tmp_path / 'gone.test.yaml'}:1:1: error: no such file or directory" in out


def test_the_junit_report_validates_against_jenkins_schema(tmp_path: Path,
                                                           junit_schema: Any) -> None:
    write(tmp_path, [PASSING, FAILING], name="a.test.yaml")
    write(tmp_path, [BAD], name="b.test.yaml")
    write(tmp_path, [PASSING], name="c.test.yaml")
    report = tmp_path / "report.xml"
    status, _ = cli("test", str(tmp_path), str(tmp_path / "gone.yaml"), "--junit",
                    str(report))
    assert status == 2
    junit_schema.validate(str(report))
    root = junit_schema.to_dict(str(report))
    assert (root["@tests"], root["@failures"], root["@errors"]) == ("5", "1", "2")
    suites = {s["@name"]: s for s in root["testsuite"]}
    a = suites[str(tmp_path / "a.test.yaml")]
    assert (a["@tests"], a["@failures"], a["@errors"]) == ("2", "1", "0")
    failing = [c for c in a["testcase"] if "failure" in c]
    assert len(failing) == 1 and failing[0]["@name"].startswith("line ")
    (failure,) = failing[0]["failure"]
    assert failure["@message"].startswith(f"{tmp_path / 'a.test.yaml'}:")
    assert failure["@type"] == "expectation"
    b = suites[str(tmp_path / "b.test.yaml")]
    assert b["@errors"] == "1"
    assert "unknown name 'tester1.nothing'" in b["testcase"][0]["error"][0]["@message"]
    assert suites[str(tmp_path / "gone.yaml")]["@errors"] == "1"


def test_the_junit_report_of_the_example_plants(tmp_path: Path, junit_schema: Any) -> None:
    report = tmp_path / "report.xml"
    status, out = cli("test", str(DRAWER), "--junit", str(report))
    assert status == 0, out
    junit_schema.validate(str(report))


def test_an_output_file_that_cannot_be_written_is_one_line(tmp_path: Path) -> None:
    write(tmp_path, [PASSING])
    status, out = cli("test", str(tmp_path / "s.test.yaml"), "--junit", str(tmp_path))
    assert status == 2


def test_scenarios_beside_a_copied_plant(tmp_path: Path) -> None:
    """A plant directory copied elsewhere keeps its scenarios working: their paths are
    relative to the scenario."""
    shutil.copytree(DRAWER, tmp_path / "drawer")
    status, out = cli("test", str(tmp_path / "drawer"))
    assert status == 0, out
    assert out.splitlines()[0].startswith(f"{tmp_path / 'drawer' / 'drawer_tester.test.yaml'}: "
                                          "50 passed (1750 scans, ")


def test_the_bench_scenario_passes(tmp_path: Path) -> None:
    """bench/scenario.py times a scenario that holds (its numbers mean a whole check, not
    failures being described); 2,000 scans here, not a timing test."""
    from bench.scenario import scenario_text
    from runtime.scenario.run import run_scenario

    path = tmp_path / "bench.test.yaml"
    path.write_text(scenario_text(2000), encoding="utf-8")
    out = run_scenario(str(path))
    assert out.error is None and out.scans == 2000
    assert len(out.cases) == 24 and out.failed == []


def _dying(path: str) -> Any:
    """run_scenario, but a worker given ``dies.test.yaml`` is killed."""
    import os
    import signal

    from runtime.scenario.run import run_scenario

    if path.endswith("dies.test.yaml"):
        os.kill(os.getpid(), signal.SIGKILL)
    return run_scenario(path)


def test_a_worker_that_dies_is_a_file_error_not_a_traceback(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A worker killed while it runs a scenario (out of memory, a signal): that scenario is
    in error, one line (and any scenario left unfinished with it), never a traceback."""
    import runtime.scenario.suite as suite

    monkeypatch.setattr(suite, "run_scenario", _dying)
    write(tmp_path, [PASSING], name="a.test.yaml")
    write(tmp_path, [PASSING], name="dies.test.yaml")
    files, _ = discover([str(tmp_path)])
    outcomes = run_all(files, 2)
    assert [o.path for o in outcomes] == files
    dead = outcomes[1]
    assert dead.error is not None and dead.error.startswith(
        f"{tmp_path / 'dies.test.yaml'}:1:1: error: the worker process running it ended")
