"""Retained memory: atomic generations with a checksum, fall-back to the previous one when
a file is torn or corrupt, restore at start, saved only when changed and at most once per
interval, and on shutdown."""

from __future__ import annotations

import json
import os
from pathlib import Path

from runtime.controller.retain import RetainStore, RetainWriter
from tests.daemon.daemonkit import MakeDaemon, wait_until


def test_save_and_load_generations(tmp_path: Path) -> None:
    store = RetainStore(str(tmp_path / "r.json"))
    assert store.load().source is None
    assert store.save({"m": {"sN": 1}}) == 1
    assert store.save({"m": {"sN": 2}}) == 2
    loaded = RetainStore(str(tmp_path / "r.json")).load()
    assert loaded.data == {"m": {"sN": 2}} and loaded.generation == 2
    assert loaded.problems == []
    prev = json.loads((tmp_path / "r.json.prev").read_text())
    assert prev["generation"] == 1 and prev["data"] == {"m": {"sN": 1}}


def test_a_corrupt_file_falls_back_to_the_previous_generation(tmp_path: Path) -> None:
    path = tmp_path / "r.json"
    store = RetainStore(str(path))
    store.save({"m": {"sN": 10}})
    store.save({"m": {"sN": 11}})
    text = path.read_text()
    path.write_text(text.replace('"sN": 11', '"sN": 99'))  # a flipped value
    loaded = RetainStore(str(path)).load()
    assert loaded.data == {"m": {"sN": 10}} and loaded.generation == 1
    assert any("checksum mismatch" in p for p in loaded.problems)
    assert any("restored generation 1 from" in p for p in loaded.problems)


def test_a_truncated_file_falls_back_and_the_next_save_goes_on(tmp_path: Path) -> None:
    path = tmp_path / "r.json"
    store = RetainStore(str(path))
    for n in range(3):
        store.save({"m": {"sN": n}})
    path.write_bytes(path.read_bytes()[:25])  # power cut in the middle of a write
    again = RetainStore(str(path))
    loaded = again.load()
    assert loaded.data == {"m": {"sN": 1}}
    assert again.save({"m": {"sN": 5}}) == 3  # generation numbers go on from the good one
    assert RetainStore(str(path)).load().data == {"m": {"sN": 5}}


def test_power_cut_between_the_renames(tmp_path: Path) -> None:
    path = tmp_path / "r.json"
    store = RetainStore(str(path))
    store.save({"m": {"sN": 1}})
    store.save({"m": {"sN": 2}})
    os.replace(path, str(path) + ".prev")  # the first rename happened, the second did not
    loaded = RetainStore(str(path)).load()
    assert loaded.data == {"m": {"sN": 2}}


def test_garbage_everywhere_loads_nothing_and_says_why(tmp_path: Path) -> None:
    path = tmp_path / "r.json"
    path.write_text("{not json")
    (tmp_path / "r.json.prev").write_text(json.dumps({"format": "other"}))
    loaded = RetainStore(str(path)).load()
    assert loaded.data == {} and loaded.source is None
    assert len(loaded.problems) == 2


def test_writer_saves_the_latest_snapshot_off_the_caller_thread(tmp_path: Path) -> None:
    store = RetainStore(str(tmp_path / "r.json"))
    w = RetainWriter(store)
    for n in range(50):
        w.submit({"m": {"sN": n}})
    assert w.flush()
    w.close()
    assert RetainStore(str(tmp_path / "r.json")).load().data == {"m": {"sN": 49}}
    assert 1 <= w.saves <= 50


def test_writer_reports_a_disk_error_and_goes_on(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    w = RetainWriter(RetainStore(str(blocker / "r.json")))  # a file where a dir should be
    w.submit({"m": {"sN": 1}})
    w.flush()
    assert w.last_error is not None
    w.close()


def test_daemon_restores_at_start_and_saves_at_stop(make_daemon: MakeDaemon,
                                                     tmp_path: Path) -> None:
    (tmp_path / "var").mkdir()  # the store creates no directory (the daemon does)
    path = str(tmp_path / "var" / "retain.json")
    RetainStore(path).save({"m": {"sN": 1000, "sDiv": 7}})  # sDiv is not retained
    daemon, drv = make_daemon(retain=path)
    assert daemon.plant.get("m.sN") == 1000
    assert daemon.plant.get("m.sDiv") == 1
    drv.inputs["I0"] = 1  # gsRun counts every scan
    wait_until(lambda: daemon.plant.get("m.sN") > 1010)
    daemon.stop("test")
    final = RetainStore(path).load()
    assert final.data["m"]["sN"] == daemon.plant.get("m.sN")


def test_saves_only_when_changed_and_at_most_once_per_interval(make_daemon: MakeDaemon,
                                                                tmp_path: Path) -> None:
    path = str(tmp_path / "retain.json")
    daemon, drv = make_daemon(retain=path, interval="100ms")
    writer = daemon._retain_writer
    assert writer is not None
    n0 = daemon.scan_stats.count
    wait_until(lambda: daemon.scan_stats.count > n0 + 40)  # 400 ms, sN never changes
    assert writer.saves == 0
    drv.inputs["I0"] = 1  # now sN changes every 10 ms scan
    wait_until(lambda: writer.saves >= 3, what="three saves")
    t0 = daemon.scan_stats.count
    saves0 = writer.saves
    wait_until(lambda: daemon.scan_stats.count > t0 + 50)  # 50 cycles = 500 ms
    # at most one per 100 ms interval (10 cycles), never one per scan
    assert writer.saves - saves0 <= (daemon.scan_stats.count - t0) // 10 + 1
