"""Retained data that should be there and is not: both generations bad, or every file gone
while a previous run recorded (``PATH.saved``) that it saved some. The controller starts
with init values only after an ERROR line and with ``status`` showing it; with
``retain_required: true`` it refuses to start (one line, exit status 2)."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.controller.retain import RetainStore
from runtime.errors import SourceError
from tests.daemon.daemonkit import MakeDaemon

ROOT = Path(__file__).resolve().parents[2]


def _saved_twice(path: Path) -> None:
    store = RetainStore(str(path))
    store.save({"m": {"sN": 1}})
    store.save({"m": {"sN": 2}})


def _errors(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]


def test_both_generations_bad_start_with_an_error_and_a_flag(
        make_daemon: MakeDaemon, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "retain.json"
    _saved_twice(path)
    torn = {}
    for name in ("retain.json", "retain.json.prev"):
        torn[name] = (tmp_path / name).read_bytes()[:30]
        (tmp_path / name).write_bytes(torn[name])
    daemon, _ = make_daemon(retain=str(path))
    assert daemon.plant.get("m.sN") == 0
    # kept aside for whoever wants to repair them by hand
    assert (tmp_path / "retain.json.orphan").read_bytes() == torn["retain.json"]
    assert (tmp_path / "retain.json.orphan.2").read_bytes() == torn["retain.json.prev"]
    assert any(e.startswith("retained data LOST (no good generation: ") for e in
               _errors(caplog)), _errors(caplog)
    status = daemon.status()["retain"]
    assert status["state"] == "lost" and "started without retained data" in status["text"]
    from runtime.console.service import ConsoleService

    lines = ConsoleService(daemon).session("operator").handle(b"status")
    assert any(line.startswith("retain lost: started without retained data: no good "
                               "generation: ") for line in lines), lines


def test_every_file_gone_after_a_save_is_lost_data(make_daemon: MakeDaemon, tmp_path: Path,
                                                   caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "retain.json"
    _saved_twice(path)
    os.unlink(path)
    os.unlink(str(path) + ".prev")
    daemon, _ = make_daemon(retain=str(path))
    assert any("retain.json.saved records that retained data was saved here" in e
               for e in _errors(caplog)), _errors(caplog)
    assert daemon.status()["retain"]["state"] == "lost"


def test_a_first_start_is_no_loss(make_daemon: MakeDaemon, tmp_path: Path,
                                  caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "retain.json"
    daemon, _ = make_daemon(retain=str(path), extra="")
    assert _errors(caplog) == []
    assert daemon.status()["retain"]["state"] == "ok"
    daemon.stop("test")
    assert (tmp_path / "retain.json.saved").exists()  # from now on, a loss is noticed


def _plant(tmp_path: Path, required: str) -> Path:
    from tests.daemon.daemonkit import CHART, plant_yaml

    (tmp_path / "runner.yaml").write_text(CHART)
    text = plant_yaml(retain=str(tmp_path / "retain.json")).replace(
        "plc:\n", f"plc:\n  retain_required: {required}\n")
    (tmp_path / "plant.yaml").write_text(text)
    return tmp_path / "plant.yaml"


def test_retain_required_refuses_to_start_without_its_data(tmp_path: Path) -> None:
    _plant(tmp_path, "true")
    _saved_twice(tmp_path / "retain.json")
    (tmp_path / "retain.json").write_text("{torn")
    (tmp_path / "retain.json.prev").unlink()
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--sim", "--for", "5s",
                           str(tmp_path / "plant.yaml")], cwd=ROOT, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.splitlines()
    assert lines == [f"{tmp_path / 'plant.yaml'}:2:20: error: retained data required but lost "
                     f"(no good generation: {tmp_path / 'retain.json'}: not JSON: Expecting "
                     "property name enclosed in double quotes at line 1): not started"], \
        proc.stderr
    assert (tmp_path / "retain.json").read_text() == "{torn"  # left for the operator


def test_retain_required_starts_when_the_data_is_there(tmp_path: Path) -> None:
    from runtime.controller.daemon import Daemon
    from runtime.language.plantfile import load_plant

    _plant(tmp_path, "true")
    _saved_twice(tmp_path / "retain.json")
    daemon = Daemon(load_plant(str(tmp_path / "plant.yaml")), sim=True, manage_gc=False)
    daemon.start()
    try:
        assert daemon.plant.get("m.sN") == 2
    finally:
        daemon.stop("test")


def test_retain_required_needs_a_retain_file(tmp_path: Path) -> None:
    from runtime.language.plantfile import load_plant

    path = _plant(tmp_path, "true")
    path.write_text(path.read_text().replace(f"  retain: {tmp_path / 'retain.json'}\n", ""))
    with pytest.raises(SourceError, match="retain_required needs a retain file"):
        load_plant(str(path))
