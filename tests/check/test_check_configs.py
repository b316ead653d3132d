"""Every file in configs/ is recognised and checks with no errors (``check`` refuses nothing
valid there); simulation scripts are checked against their plant; the drawer tester checks
clean. Timings are printed, not asserted (speed is measured, never pass/fail)."""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from runtime.checker.check import check_files, exit_status, register
from runtime.language.filekind import file_kind

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = sorted(p for p in (ROOT / "configs").glob("**/*.yaml") if "schema" not in p.parts)


def cli() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="softplc")
    register(p.add_subparsers(dest="command", required=True))
    return p


@pytest.mark.parametrize("path", CONFIGS, ids=[str(p.relative_to(ROOT)) for p in CONFIGS])
def test_config_is_recognised_and_has_no_errors(path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    assert file_kind(str(path)) in ("grafcet", "plant", "script", "scenario")
    t0 = time.perf_counter()
    res = check_files([str(path)])
    ms = (time.perf_counter() - t0) * 1000
    with capsys.disabled():
        sys.stderr.write(f"\n[check] {path.relative_to(ROOT)}: {ms:.1f} ms\n")
    assert not [r.failure for r in res if r.failure]
    errors = [str(d) for r in res for d in r.diags if d.severity == "error"]
    assert not errors, "\n".join(errors)
    # a script is checked against the plant of its directory, not skipped
    assert not [d for r in res for d in r.diags if d.code == "G400"]


def test_the_whole_configs_glob(capsys: pytest.CaptureFixture[str]) -> None:
    """``softplc check configs/*/*.yaml``: exit 0, each chart checked once."""
    files = sorted(str(p) for p in (ROOT / "configs").glob("*/*.yaml"))
    args = cli().parse_args(["check", *files])
    assert args.func(args) == 0
    out = capsys.readouterr()
    lines = out.out.splitlines()
    assert len(lines) == len(set(lines)), "a chart was reported twice"
    assert ": error" not in out.out
    assert f"check: {len(files)} file(s), 0 error(s)" in out.err


def test_drawer_tester_checks_clean(capsys: pytest.CaptureFixture[str]) -> None:
    path = str(ROOT / "configs" / "drawer_tester" / "drawer_tester.yaml")
    t0 = time.perf_counter()
    res = check_files([path])
    ms = (time.perf_counter() - t0) * 1000
    with capsys.disabled():
        sys.stderr.write(f"\n[check] {os.path.relpath(path)}: "
                         f"{sum(len(r.diags) for r in res)} diagnostics in {ms:.1f} ms\n")
    assert not [r.failure for r in res if r.failure]
    # safe, live, every step reachable: only the OR-exclusivity warnings of seed rule II.1
    # (the failure-by-time transitions overlap the normal ones, by design: file order)
    assert {d.code for r in res for d in r.diags} == {"G201"}


# -- simulation scripts ------------------------------------------------------------------
def _copy_drawer(tmp: Path) -> Path:
    for name in ("drawer_tester.yaml", "plant_sim.yaml", "story.yaml"):
        shutil.copy(ROOT / "configs" / "drawer_tester" / name, tmp / name)
    return tmp / "story.yaml"


def test_script_is_checked_against_the_plant_of_its_directory(tmp_path: Path) -> None:
    story = _copy_drawer(tmp_path)
    assert check_files([str(story)]) and exit_status(check_files([str(story)])) == 0
    text = story.read_text(encoding="utf-8")
    story.write_text(text.replace("tester1.iMarcha: 1}", "tester1.iMarca: 1}", 1),
                     encoding="utf-8")
    line = next(n for n, x in enumerate(story.read_text().splitlines(), 1) if "iMarca:" in x)
    (res,) = check_files([str(story)])
    assert exit_status([res]) == 2  # a file that does not load
    assert res.failure is not None
    assert res.failure.startswith(f"{story}:{line}:")
    assert "'tester1.iMarca' is not an input or chart flag of tester1" in res.failure
    assert "(did you mean 'iMarcha'?)" in res.failure
    assert res.failure.endswith("(checked against " + str(tmp_path / "plant_sim.yaml") + ")")


def test_script_with_no_plant_or_several_plants(tmp_path: Path,
                                                write: Callable[[str, str], str]) -> None:
    story = tmp_path / "story.yaml"
    shutil.copy(ROOT / "configs" / "drawer_tester" / "story.yaml", story)
    (res,) = check_files([str(story)])
    assert [(d.severity, d.code) for d in res.diags] == [("note", "G400")]
    assert "no plant file in its directory" in res.diags[0].message
    assert exit_status([res]) == 0
    _copy_drawer(tmp_path)
    shutil.copy(tmp_path / "plant_sim.yaml", tmp_path / "plant_b.yaml")
    (res,) = check_files([str(story)])
    assert [d.code for d in res.diags] == ["G400"]
    assert "several plant files in its directory (plant_b.yaml, plant_sim.yaml)" in (
        res.diags[0].message)
    # the plant named on the command line, or with --plant, decides
    results = check_files([str(tmp_path / "plant_b.yaml"), str(story)])
    assert not [d for r in results for d in r.diags if d.code == "G400"]
    other = tmp_path / "elsewhere"
    other.mkdir()
    shutil.copy(story, other / "story.yaml")
    args = cli().parse_args(["check", "-q", "--plant", str(tmp_path / "plant_sim.yaml"),
                             str(other / "story.yaml")])
    assert args.func(args) == 0


def test_a_file_of_another_kind_is_refused(write: Callable[[str, str], str]) -> None:
    (res,) = check_files([write("x.yaml", "foo: 1\n")])
    assert res.failure is not None and "expected a grafcet file" in res.failure
    assert "or a simulation script" in res.failure


def test_script_without_length_is_accepted_with_a_note(tmp_path: Path) -> None:
    """``softplc simulate PLANT --script S --cycles N`` runs a script with neither
    ``duration:`` nor ``cycles:``, so check accepts it (a note says it needs --cycles), and
    still checks every name it sets."""
    story = _copy_drawer(tmp_path)
    story.write_text("set:\n  - {at: 0ms, tester1.iMarcha: 1}\n", encoding="utf-8")
    (res,) = check_files([str(story)])
    assert res.failure is None, res.failure
    assert [(d.severity, d.code, d.line) for d in res.diags] == [("note", "G401", 1)]
    assert "softplc simulate PLANT --script S --cycles N" in res.diags[0].message
    assert exit_status([res]) == 0
    story.write_text("set:\n  - {at: 0ms, tester1.iMarca: 1}\n", encoding="utf-8")
    (res,) = check_files([str(story)])
    assert res.failure is not None and "'tester1.iMarca' is not an input" in res.failure
