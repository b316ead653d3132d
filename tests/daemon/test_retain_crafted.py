"""Crafted retain files are refused with one line each, never a traceback, never a hang:
text where a number is expected, Infinity/NaN, deep nesting, a FIFO, a symbolic link, a
huge file. The retain path itself is checked when the plant is loaded."""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path
from typing import Any

import pytest

from runtime.controller import retain as R
from runtime.controller.retain import RetainStore
from runtime.errors import SourceError
from runtime.language.plantfile import load_plant
from tests.daemon.daemonkit import CHART, MakeDaemon


def _signed(data: Any, **fields: Any) -> str:
    """A retain file with a right checksum, as an attacker could write it: every value
    declared an int of chart Runner unless ``fields`` say otherwise."""
    types = {i: {n: "int" for n in v} for i, v in data.items() if isinstance(v, dict)}
    payload = {"format": R.FORMAT, "generation": 1, "saved_at": 1.0,
               "plant": {"name": "", "path": ""},  # as a store that names no plant saves it
               "charts": {i: "Runner" for i in data}, "types": types, "data": data, **fields}
    return json.dumps({**payload, "sha256": R._digest(payload)})


INF = float("inf")


CRAFTED = {
    "text for a number": _signed({"m": {"sN": "abc"}}),
    "Infinity": _signed({"m": {"sN": INF}}),
    "NaN generation": _signed({"m": {"sN": 1}}, generation=float("nan")),
    "huge number": _signed({"m": {"sN": INF}}).replace("Infinity", "1e999"),
    "text for saved_at": _signed({"m": {"sN": 1}}, saved_at="yesterday"),
    "deep nesting": '{"data": ' + "[" * 5_000 + "]" * 5_000 + "}",
    "a list for an instance": _signed({"m": [1, 2]}),
    "nested values": _signed({"m": {"sN": {"a": [1]}}}),
    "a bool generation": _signed({"m": {"sN": 1}}, generation=True),
    "a bool for an int": _signed({"m": {"sN": True}}),
    "a real for an int": _signed({"m": {"sN": 1.5}}),
    "5000 digits": _signed({"m": {"sN": 1}}).replace('"sN": 1', '"sN": ' + "9" * 5000),
    "an unknown type": _signed({"m": {"sN": 1}}, types={"m": {"sN": "complex"}}),
    "no chart": _signed({"m": {"sN": 1}}, charts={}),
}


@pytest.mark.parametrize("name", list(CRAFTED))
def test_a_crafted_file_is_refused_with_one_line(tmp_path: Path, name: str) -> None:
    path = tmp_path / "r.json"
    store = RetainStore(str(path))
    store.save({"m": {"sN": 5}})  # the good previous generation
    os.replace(path, str(path) + ".prev")
    path.write_text(CRAFTED[name])
    loaded = RetainStore(str(path)).load()
    assert loaded.data == {"m": {"sN": 5}}, name  # the good one, not the crafted one
    refused = [p for p in loaded.problems if p.startswith(str(path) + ":")]
    assert len(refused) == 1 and "\n" not in refused[0], loaded.problems


def test_infinity_for_a_retained_int_does_not_stop_the_daemon(make_daemon: MakeDaemon,
                                                                tmp_path: Path) -> None:
    path = tmp_path / "retain.json"
    path.write_text(_signed({"m": {"sN": INF}}))
    daemon, _ = make_daemon(retain=str(path))
    assert daemon.plant.get("m.sN") == 0
    assert daemon.status()["retain"]["state"] == "lost"


def test_a_fifo_does_not_block_the_load(tmp_path: Path) -> None:
    path = tmp_path / "r.json"
    os.mkfifo(path)
    result: list[R.Loaded] = []
    t = threading.Thread(target=lambda: result.append(RetainStore(str(path)).load()),
                         daemon=True)
    t.start()
    t.join(10.0)
    if t.is_alive():  # unblock it before failing
        os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
        t.join(10.0)
        pytest.fail("loading a FIFO blocked")
    assert result[0].source is None
    assert any("not a regular file" in p for p in result[0].problems)


def test_a_symlink_is_never_followed_when_loading(tmp_path: Path) -> None:
    elsewhere = tmp_path / "elsewhere.json"
    RetainStore(str(elsewhere)).save({"m": {"sN": 666}})
    path = tmp_path / "r.json"
    path.symlink_to(elsewhere)
    (tmp_path / "r.json.prev").symlink_to("/dev/zero")  # would never end
    loaded = RetainStore(str(path)).load()
    assert loaded.source is None and loaded.data == {}
    assert sum("symbolic link" in p for p in loaded.problems) == 2, loaded.problems


def test_a_symlink_is_never_followed_when_saving(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    path = tmp_path / "r.json"
    (tmp_path / "r.json.tmp").symlink_to(victim)  # planted before the save
    RetainStore(str(path)).save({"m": {"sN": 1}})
    assert victim.read_text() == "precious"
    assert not path.is_symlink()
    assert RetainStore(str(path)).load().data == {"m": {"sN": 1}}


def test_a_huge_file_is_refused_unread(tmp_path: Path) -> None:
    path = tmp_path / "r.json"
    with open(path, "w") as f:  # valid, but padded past the size limit
        f.write(" " * (R.MAX_FILE_BYTES + 1) + _signed({"m": {"sN": 1}}))
    loaded = RetainStore(str(path)).load()
    assert loaded.source is None
    assert any("larger than" in p for p in loaded.problems), loaded.problems


def test_saving_over_a_directory_never_renames_it(tmp_path: Path) -> None:
    plant_dir = tmp_path / "plant"
    plant_dir.mkdir()
    (plant_dir / "plant.yaml").write_text("x")
    with pytest.raises(OSError):
        RetainStore(str(plant_dir)).save({"m": {"sN": 1}})
    assert (plant_dir / "plant.yaml").exists()
    assert not (tmp_path / "plant.prev").exists()


@pytest.mark.parametrize("value", ["''", ".", "sub", "sub/", "~"])
def test_a_retain_path_that_cannot_be_a_file_is_a_load_error(tmp_path: Path,
                                                               value: str) -> None:
    (tmp_path / "sub").mkdir()
    (tmp_path / "runner.yaml").write_text(CHART)
    plant = tmp_path / "plant.yaml"
    plant.write_text(f"plc:\n  cycle: 10ms\n  retain: {value}\n"
                     "drivers:\n  io: {type: sim}\ninstances:\n  m:\n    grafcet: runner.yaml\n"
                     "    inputs: {iGo: io.I0}\n    outputs: {oRun: io.Q0, oLamp: io.Q1}\n")
    if value == "~":  # YAML null: no retain file, fine
        assert load_plant(str(plant)).retain_path is None
        return
    with pytest.raises(SourceError) as info:
        load_plant(str(plant))
    assert str(info.value).startswith(f"{plant}:3:11: error: plc retain")


def test_generations_cross_the_top_without_losing_data(tmp_path: Path) -> None:
    """A file at generation 2**63-1 loads; before, the next saves wrote 2**63 and 2**63+1,
    which load refused: after two runs the data was lost. Generations now stop at the top
    (GENERATION_MAX) and the newest file, PATH, is loaded among equals."""
    path = tmp_path / "r.json"
    top = R.GENERATION_MAX
    for start in (top - 1, top):
        path.write_text(_signed({"m": {"sN": 0}}, generation=start))
        saved = []
        for run in range(1, 4):  # each run: a start that loads, then one save
            store = RetainStore(str(path))
            loaded = store.load()
            assert loaded.data == {"m": {"sN": run - 1}}, (start, run, loaded.problems)
            assert loaded.problems == [] and loaded.lost is None, loaded.problems
            saved.append(store.save({"m": {"sN": run}}))
        assert RetainStore(str(path)).load().data == {"m": {"sN": 3}}
        assert saved == [min(start + run, top) for run in (1, 2, 3)]
        for f in tmp_path.iterdir():
            f.unlink()
