"""The reload's child process (runtime/controller/reloadchild.py): it never imports from the
controller's working directory, it answers as data, it runs under a memory and a time
limit, and a child that fails is a refused load with its reason, never a load in the
controller's own process."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from bench.divergence import chain_text
from runtime.controller import reloadchild
from runtime.controller.reload import compile_apart, load_apart
from runtime.language.plantfile import load_plant
from tests.change.changekit import DRAWER_PLANT

#: what a planted module does when it is imported: leave a mark next to itself
PLANTED = "import os\nopen(os.path.join(os.path.dirname(os.path.abspath(__file__)), " \
          "'IMPORTED'), 'w').close()\n"


def plant_of(tmp: Path, chart: str) -> str:
    """A plant file running ``chart`` (a chart file's text) as instance m1 on sim I/O."""
    (tmp / "chart.yaml").write_text(chart, encoding="utf-8")
    path = tmp / "plant.yaml"
    path.write_text("drivers:\n  io: {type: sim}\ninstances:\n  m1:\n    grafcet: chart.yaml\n"
                    "    inputs: {iGo: io.I0}\n    outputs: {oMotor: io.Q0}\n", encoding="utf-8")
    return str(path)


def test_a_module_planted_in_the_working_directory_is_never_imported(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A controller started by hand from a directory others can write (/tmp): a yaml.py
    and a runtime/ package planted there stay unread by the child."""
    planted = tmp_path / "cwd"
    (planted / "runtime").mkdir(parents=True)
    (planted / "yaml.py").write_text(PLANTED, encoding="utf-8")
    (planted / "runtime" / "__init__.py").write_text(PLANTED, encoding="utf-8")
    os.chmod(planted, 0o1777)
    monkeypatch.chdir(planted)
    loaded = load_apart(DRAWER_PLANT)
    back = compile_apart(load_plant(DRAWER_PLANT))
    assert not (planted / "IMPORTED").exists()
    assert not (planted / "runtime" / "IMPORTED").exists()
    assert not isinstance(loaded, str) and not isinstance(back, str), (loaded, back)
    assert loaded[1] is not None and loaded[1].blobs, "compiled apart"
    assert back[1] is not None and back[1].blobs


def test_a_child_that_fails_is_a_refusal_with_its_reason(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """No load in the controller's process instead: a child that does not answer (here a
    Python that exits at once) leaves the reload refused, saying why."""
    monkeypatch.setattr(sys, "executable", "/bin/false")
    loaded = load_apart(DRAWER_PLANT)
    back = compile_apart(load_plant(DRAWER_PLANT))
    assert isinstance(loaded, str) and "child process failed (exit 1" in loaded, loaded
    assert isinstance(back, str) and "child process failed (exit 1" in back, back


def test_the_child_loads_under_a_memory_limit(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """Past CHILD_MEMORY_BYTES the load fails with MemoryError in the child, and the line
    names the limit; the drawer plant loads under the same limit."""
    monkeypatch.setattr(reloadchild, "CHILD_MEMORY_BYTES", 128 * 2**20)
    assert not isinstance(load_apart(DRAWER_PLANT), str)
    got = load_apart(plant_of(tmp_path, chain_text(2000)))
    assert got == ("the new program needs more than 128 MiB to load (the limit of the "
                   "reload's child process)")


def test_the_child_loads_under_a_time_limit(tmp_path: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(reloadchild, "CHILD_TIME_S", 1)
    got = load_apart(plant_of(tmp_path, chain_text(2000)))
    assert got in (
        "the new program took longer than 1 s to load (the limit of the reload's child "
        "process)",
        "the new program took more than 1 s of CPU to load (the limit of the reload's "
        "child process)")


def test_the_answer_is_frames_of_data_never_pickle(tmp_path: Path) -> None:
    """What the child writes: a JSON header, the plant as JSON records, code objects;
    nothing the controller reads is pickled."""
    import subprocess

    child = subprocess.run(reloadchild.child_command(["load", DRAWER_PLANT]),
                           capture_output=True, cwd="/", check=True,
                           stdin=subprocess.DEVNULL)
    kinds = [k for k, _ in reloadchild._frames(child.stdout)]
    assert kinds[0] == b"H" and set(kinds) == {b"H", b"J", b"C"}
    assert b"\x80\x04\x95" not in child.stdout and b"\x80\x05\x95" not in child.stdout
    answer = reloadchild._answer(child.stdout)
    assert not isinstance(answer, str), answer
    pdef = answer[0]
    assert pdef is not None and sorted(pdef.instances) == ["tester1", "tester2"]
    assert pdef.instances["tester1"].grafcet is pdef.instances["tester2"].grafcet


def test_bad_data_from_a_child_is_a_refusal(monkeypatch: pytest.MonkeyPatch) -> None:
    """A child whose output is cut short, or names a class that is not of the model."""
    import json

    header = reloadchild._frame(b"H", json.dumps({"error": None}).encode())
    cut = header + b"J\x00\x00\x10\x00[[\"o\""
    assert "cut short" in str(pytest.raises(ValueError, reloadchild._answer, cut).value)
    evil = header + reloadchild._frame(b"J", b'[["o","Popen","rm -rf /"]]')
    with pytest.raises(Exception, match="unknown record"):
        reloadchild._answer(evil)


def test_code_too_large_to_read_without_holding_up_the_scan_is_refused(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Reading a code object is one call holding the GIL: past MAX_CODE_BYTES the change
    is refused (restart to load it), never read in the controller."""
    monkeypatch.setattr(reloadchild, "MAX_CODE_BYTES", 2**20 // 1024)
    got = load_apart(DRAWER_PLANT)
    assert isinstance(got, str) and got.startswith(
        "the new program's code is too large to be loaded online ("), got
    assert got.endswith("more than 0.000976562 MiB): restart the controller to load it"), got
