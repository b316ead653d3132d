"""The retain file records each variable's type and each instance's chart: at start, a
retyped variable is not reused (warning, init value), a renamed or removed one is reported
by name, another chart's values are not reused, and the file as it was is kept as
``PATH.orphan`` (never overwritten). Files of format 1 (no types) still load."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from runtime.controller import retain as R
from runtime.controller.retain import RetainStore
from tests.daemon.daemonkit import CHART, MakeDaemon


def _chart(memory: str, name: str = "Runner") -> str:
    """The daemon tests' chart with ``memory`` lines added and named ``name``."""
    return CHART.replace("memory:\n", "memory:\n" + memory).replace("grafcet: Runner",
                                                                      f"grafcet: {name}")


def _restart_with(tmp_path: Path, make_daemon: MakeDaemon, memory: str, name: str = "Runner",
                  ) -> None:
    """Run once with ``memory`` as it was, then stop (saving); the caller rewrites the chart."""
    (tmp_path / "runner.yaml").write_text(_chart(memory, name))
    daemon, _ = make_daemon(retain=str(tmp_path / "retain.json"))
    daemon.stop("the chart is being changed")


def _warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_a_retyped_variable_is_not_reused(make_daemon: MakeDaemon, tmp_path: Path,
                                          caplog: pytest.LogCaptureFixture) -> None:
    _restart_with(tmp_path, make_daemon, "  sT: {init: 5s, retain: true}\n")
    saved = (tmp_path / "retain.json").read_bytes()
    assert json.loads(saved)["types"]["m"] == {"sN": "int", "sT": "time"}
    (tmp_path / "runner.yaml").write_text(_chart("  sT: {init: 7, retain: true}\n"))
    daemon, _ = make_daemon(retain=str(tmp_path / "retain.json"))
    assert daemon.plant.get("m.sT") == 7  # the init value, not 5000000000
    assert "retain: m.sT: was time, now int: init value" in _warnings(caplog)
    assert (tmp_path / "retain.json.orphan").read_bytes() == saved
    daemon.stop("test")
    # the next start reuses what this run saved, without a word, and keeps the orphan
    caplog.clear()
    again, _ = make_daemon(retain=str(tmp_path / "retain.json"))
    assert again.plant.get("m.sT") == 7 and _warnings(caplog) == []
    assert (tmp_path / "retain.json.orphan").read_bytes() == saved


def test_a_renamed_variable_is_reported_by_name(make_daemon: MakeDaemon, tmp_path: Path,
                                                caplog: pytest.LogCaptureFixture) -> None:
    _restart_with(tmp_path, make_daemon, "  sCount: {init: 41, retain: true}\n")
    (tmp_path / "runner.yaml").write_text(_chart("  sTotal: {init: 3, retain: true}\n"))
    (tmp_path / "retain.json.orphan").write_text("an older orphan")
    daemon, _ = make_daemon(retain=str(tmp_path / "retain.json"))
    assert daemon.plant.get("m.sTotal") == 3
    assert any(w.startswith("retain: m.sCount: no retained variable of that name")
               for w in _warnings(caplog)), _warnings(caplog)
    assert (tmp_path / "retain.json.orphan").read_text() == "an older orphan"
    kept = json.loads((tmp_path / "retain.json.orphan.2").read_text())
    assert kept["data"]["m"]["sCount"] == 41


def test_another_chart_in_an_instance_reuses_nothing(make_daemon: MakeDaemon, tmp_path: Path,
                                                     caplog: pytest.LogCaptureFixture) -> None:
    _restart_with(tmp_path, make_daemon, "  sK: {init: 9, retain: true}\n")
    (tmp_path / "runner.yaml").write_text(_chart("  sK: {init: 1, retain: true}\n", "Mixer"))
    daemon, _ = make_daemon(retain=str(tmp_path / "retain.json"))
    assert daemon.plant.get("m.sK") == 1
    assert "retain: m now runs chart Mixer, was Runner: sK, sN not reused" in _warnings(caplog)
    assert (tmp_path / "retain.json.orphan").exists()


def test_nothing_dropped_keeps_no_orphan(make_daemon: MakeDaemon, tmp_path: Path) -> None:
    _restart_with(tmp_path, make_daemon, "  sR: {init: 2.5, retain: true}\n")
    daemon, _ = make_daemon(retain=str(tmp_path / "retain.json"))
    assert daemon.plant.get("m.sR") == 2.5
    assert not (tmp_path / "retain.json.orphan").exists()


def test_a_format_1_file_still_loads(make_daemon: MakeDaemon, tmp_path: Path,
                                     caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / "runner.yaml").write_text(_chart("  sT: {init: 1s, retain: true}\n"
                                                 "  sB: {init: false, retain: true}\n"))
    payload = {"format": R.FORMAT_1, "generation": 4, "saved_at": 1.0,
               "data": {"m": {"sN": 12, "sT": 3_000_000_000, "sB": "abc"}}}
    (tmp_path / "retain.json").write_text(json.dumps({**payload,
                                                      "sha256": R._digest(payload)}))
    daemon, _ = make_daemon(retain=str(tmp_path / "retain.json"))
    assert daemon.plant.get("m.sN") == 12 and daemon.plant.get("m.sT") == 3_000_000_000
    assert daemon.plant.get("m.sB") is False  # text for a bool: init value
    assert 'retain: m.sB: "abc" does not fit bool: init value' in _warnings(caplog)
    daemon.stop("test")
    now = json.loads((tmp_path / "retain.json").read_text())
    assert now["format"] == R.FORMAT and now["generation"] == 5
    assert now["types"]["m"] == {"sN": "int", "sT": "time", "sB": "bool"}


def test_a_real_that_is_not_finite_is_kept(tmp_path: Path) -> None:
    store = RetainStore(str(tmp_path / "r.json"),
                        R.RetainedVars({"m": "Runner"}, {"m": {"sR": "real"}}))
    store.save({"m": {"sR": float("-inf")}})
    assert RetainStore(str(tmp_path / "r.json")).load().data == {"m": {"sR": float("-inf")}}


def test_values_are_saved_as_their_declared_type(tmp_path: Path) -> None:
    layout = R.RetainedVars({"m": "Runner"}, {"m": {"sB": "bool", "sI": "int", "sR": "real"}})
    store = RetainStore(str(tmp_path / "r.json"), layout)
    store.save({"m": {"sB": 1, "sI": 10 ** 30, "sR": 2}})  # ints have no fixed width
    loaded = RetainStore(str(tmp_path / "r.json")).load()
    assert loaded.data == {"m": {"sB": True, "sI": 10 ** 30, "sR": 2.0}}
    assert isinstance(loaded.data["m"]["sR"], float)
    before = (tmp_path / "r.json").read_bytes()
    with pytest.raises(ValueError, match=r"m.sI: 'abc' is not of type int: not saved"):
        store.save({"m": {"sB": True, "sI": "abc", "sR": 1.0}})
    assert (tmp_path / "r.json").read_bytes() == before
