"""The reload's child process (runtime/controller/reloadchild.py): it never imports from the
controller's working directory, it answers as data, it runs under a memory and a time
limit, and a child that fails is a refused load with its reason, never a load in the
controller's own process."""

from __future__ import annotations

import io
import logging
import os
import re
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings

from bench.divergence import chain_text
from runtime.controller import reloadchild
from runtime.controller.reload import compile_apart, load_apart
from runtime.language import modeldata
from runtime.language.plantfile import load_plant
from tests.change.changekit import DRAWER_PLANT
from tests.language.plantgen import plant_docs, write
from tests.language.test_modeldata import same

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


# -- what crosses, and what an operator reads when it does not ------------------------------
#: what an operator never reads in a refusal: a Python exception, a module path, a traceback
INTERNAL = re.compile(r"Traceback|\b[A-Z]\w*(Error|Exception)\b|\bruntime\.\w+\.|File \"")


def test_a_plant_with_an_io_list_crosses_to_the_child_and_back(tmp_path: Path) -> None:
    """Issue: ``softplc reload`` of a plant whose I/O list has a ``unit:`` was refused,
    ``the reload's child process failed (exit 1: runtime.language.modeldata.ModelDataError:
    Unit is not part of the model: it cannot cross as data)``. Both ways: the child's load
    (reload) and the child's compile of a plant handed to it (reload --back)."""
    (tmp_path / "c.yaml").write_text(
        "grafcet: C\ninputs: [iGo, {iLevel: int}]\noutputs: [oRun, {oSpeed: real}]\n"
        "steps:\n  s0: {initial: true}\n  s1: {actions: [oRun]}\ntransitions:\n"
        "  - {from: s0, to: s1, when: iGo}\n  - {from: s1, to: s0, when: iLevel > 5}\n"
        "post:\n  - oSpeed := iLevel * 0.5\n", encoding="utf-8")
    plant = tmp_path / "plant.yaml"
    plant.write_text(
        "drivers:\n  io: {type: sim}\ninstances:\n  m:\n    grafcet: c.yaml\n"
        "    inputs:\n      iGo: io.I0\n      iLevel: {from: io.IR0, unit: mm, range: [0, 100],"
        " description: level LT1}\n"
        "    outputs:\n      oRun: io.Q0\n      oSpeed: {from: io.HR0, unit: rpm}\n",
        encoding="utf-8")
    pdef = load_plant(str(plant))
    loaded = load_apart(str(plant))
    assert not isinstance(loaded, str), loaded
    same(pdef, loaded[0])
    back = compile_apart(pdef)
    assert not isinstance(back, str), back
    assert back[1].blobs


@pytest.fixture(scope="module")
def gen_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("gen")


@settings(max_examples=8, deadline=None, suppress_health_check=list(HealthCheck))
@given(docs=plant_docs())
def test_every_generated_plant_crosses_to_the_child_and_back(
        gen_dir: Path, monkeypatch: pytest.MonkeyPatch,
        docs: tuple[dict[str, Any], dict[str, Any]]) -> None:
    """Property, through the real child process (a few examples: a child is a Python
    start): what the child loads is what the controller would load, field for field."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(gen_dir))
    path = str(write(gen_dir, docs))
    loaded = load_apart(path)
    assert not isinstance(loaded, str), loaded
    same(load_plant(path), loaded[0])
    assert not isinstance(compile_apart(loaded[0]), str)


def test_a_child_that_fails_inside_is_said_in_the_operators_terms(
        caplog: pytest.LogCaptureFixture) -> None:
    """A child that ends with a traceback: the line says the reload was refused by an
    internal error whose report is in the controller's log, and the log has the report;
    the exception's own text is never the operator's line."""
    stderr = (b"Traceback (most recent call last):\n  File \"/x/runtime/language/modeldata.py\""
              b", line 107, in record\nruntime.language.modeldata.ModelDataError: Unit is not "
              b"part of the model: it cannot cross as data\n")
    with caplog.at_level(logging.ERROR, "runtime.controller.reloadchild"):
        line = reloadchild._failed(1, stderr)
    assert not INTERNAL.search(line), line
    assert line == ("the reload's child process failed (exit 1): an internal error of "
                    "softplc, its report in the controller's log"), line
    assert "ModelDataError: Unit is not part of the model" in caplog.text


def test_an_internal_error_in_the_child_is_a_line_in_the_operators_terms(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """The child's own work (load, compile, hand over) failing with an exception that is
    no load or compile error: its header says so in one line, the traceback goes to its
    standard error (which the controller logs)."""
    def broken(obj: Any) -> Any:
        raise modeldata.ModelDataError("Unit is not part of the model")
    monkeypatch.setattr(reloadchild.modeldata, "dump", broken)
    frames = reloadchild._safe_work("load", [DRAWER_PLANT], io.BytesIO())
    answer = reloadchild._answer(b"".join(frames))
    assert isinstance(answer, str) and not INTERNAL.search(answer), answer
    assert answer == ("the new program could not be prepared in the reload's child process: "
                      "an internal error of softplc, its report in the controller's log")
    assert "ModelDataError: Unit is not part of the model" in capsys.readouterr().err
