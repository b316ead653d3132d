"""Retain saves on a failing disk: a full tmpfs (one 4 kB page left), ``os.write``
failing with ENOSPC/EIO or writing short. A failed save never touches the previous good
generations, is logged once when saving starts failing and once when it recovers, shows in
``status`` and is retried at the next interval."""

from __future__ import annotations

import errno
import json
import logging
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest

from runtime.controller.retain import RetainStore, RetainWriter
from tests.daemon.daemonkit import MakeDaemon, wait_until

ROOT = Path(__file__).resolve().parents[2]


def _big(n: int) -> dict[str, Any]:
    """A snapshot of about 6 kB: more than the one page left on the full file system."""
    return {"m": {f"sCounter{i:03d}": n * 1000 + i for i in range(200)}}


FULL_TMPFS = textwrap.dedent("""\
    import errno, json, os, subprocess, sys
    sys.path.insert(0, sys.argv[1])
    from runtime.controller.retain import RetainStore
    from tests.daemon.test_retain_disk import _big
    mnt = sys.argv[2]
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k,mode=0700", "tmpfs", mnt],
                   check=True)
    path = os.path.join(mnt, "retain.json")
    store = RetainStore(path)
    store.save(_big(1))
    store.save(_big(2))
    def fill_to_one_page(n):
        # something else (a log) fills the disk: one 4 kB page is left
        filler = os.path.join(mnt, f"filler{n}")
        fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
        try:
            while os.write(fd, b"x" * 4096) == 4096:
                pass
        except OSError as exc:
            assert exc.errno == errno.ENOSPC
        os.close(fd)
        size = os.path.getsize(filler)
        os.truncate(filler, max(0, size - size % 4096 - 4096))
    errors = []
    for n in (3, 4, 5):
        fill_to_one_page(n)
        try:
            store.save(_big(n))
        except OSError as exc:
            errors.append(exc.errno)
    loaded = RetainStore(path).load()
    print(json.dumps({"errors": errors, "generation": loaded.generation,
                      "first": loaded.data.get("m", {}).get("sCounter000"),
                      "problems": loaded.problems,
                      "leftovers": sorted(f for f in os.listdir(mnt)
                                          if not f.startswith("filler"))}))
""")


def test_a_full_tmpfs_keeps_the_last_good_generation(tmp_path: Path) -> None:
    if shutil.which("unshare") is None:
        pytest.skip("unshare(1) is not installed")
    probe = subprocess.run(["unshare", "-rm", "true"], capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"unshare -rm not permitted here: {probe.stderr.decode().strip()}")
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    script = tmp_path / "full.py"
    script.write_text(FULL_TMPFS)
    out = subprocess.run(["unshare", "-rm", sys.executable, str(script), str(ROOT), str(mnt)],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["errors"] == [errno.ENOSPC] * 3  # every save said it failed
    assert result["generation"] == 2 and result["first"] == 2000  # the last good one
    assert result["problems"] == []  # neither generation was touched
    assert "retain.json.tmp" not in result["leftovers"]  # the torn attempt is removed


class _FailingWrite:
    """``os.write`` replaced (every caller in the process, for the test's duration): each
    call raises ``error``, or writes at most ``short`` bytes and returns that short count."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, *, short: int | None = None,
                 error: int | None = None) -> None:
        self.real = os.write
        self.short, self.error = short, error
        self.calls = 0
        monkeypatch.setattr(os, "write", self)

    def __call__(self, fd: int, data: bytes) -> int:
        self.calls += 1
        if self.error is not None:
            raise OSError(self.error, os.strerror(self.error))
        if self.short is not None:
            return self.real(fd, bytes(data[:self.short]))
        return self.real(fd, data)


def _two_good_generations(path: Path) -> RetainStore:
    store = RetainStore(str(path))
    store.save({"m": {"sN": 1}})
    store.save({"m": {"sN": 2}})
    return store


@pytest.mark.parametrize("error", [errno.ENOSPC, errno.EIO])
def test_a_failing_write_keeps_both_generations(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                error: int) -> None:
    path = tmp_path / "r.json"
    store = _two_good_generations(path)
    before = (path.read_bytes(), (tmp_path / "r.json.prev").read_bytes())
    _FailingWrite(monkeypatch, error=error)
    with pytest.raises(OSError) as info:
        store.save({"m": {"sN": 3}})
    assert info.value.errno == error
    monkeypatch.undo()
    assert (path.read_bytes(), (tmp_path / "r.json.prev").read_bytes()) == before
    assert not (tmp_path / "r.json.tmp").exists()
    assert store.save({"m": {"sN": 4}}) == 3  # numbering goes on from the last good one
    assert RetainStore(str(path)).load().data == {"m": {"sN": 4}}


def test_short_writes_are_completed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "r.json"
    store = _two_good_generations(path)
    fake = _FailingWrite(monkeypatch, short=7)  # a pipe-like write: 7 bytes at a time
    store.save({"m": {"sN": 3}})
    monkeypatch.undo()
    assert fake.calls > 10
    loaded = RetainStore(str(path)).load()
    assert loaded.data == {"m": {"sN": 3}} and loaded.problems == []


def test_a_write_that_makes_no_progress_fails(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "r.json"
    store = _two_good_generations(path)
    before = path.read_bytes()
    _FailingWrite(monkeypatch, short=0)
    with pytest.raises(OSError):
        store.save({"m": {"sN": 3}})
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert RetainStore(str(path)).load().data == {"m": {"sN": 2}}


def test_the_writer_logs_once_when_failing_and_once_when_recovered(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "r.json"
    _two_good_generations(path)
    store = RetainStore(str(path))
    store.load()
    writer = RetainWriter(store)
    caplog.set_level(logging.INFO, logger="runtime.controller.retain")
    try:
        fake = _FailingWrite(monkeypatch, error=errno.ENOSPC)
        for n in range(5):
            writer.submit({"m": {"sN": 10 + n}})
            assert writer.flush()
        assert fake.calls >= 5
        assert writer.failing_since is not None and "No space" in str(writer.last_error)
        monkeypatch.undo()
        writer.submit({"m": {"sN": 20}})
        assert writer.flush()
        assert writer.failing_since is None and writer.last_error is None
    finally:
        writer.close()
    lines = [r for r in caplog.records if r.name == "runtime.controller.retain"]
    assert [(r.levelname, "not written" in r.message) for r in lines] == [
        ("ERROR", True), ("WARNING", False)]
    assert RetainStore(str(path)).load().data == {"m": {"sN": 20}}


def test_the_daemon_retries_a_failed_save_and_shows_it_in_status(
        make_daemon: MakeDaemon, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "retain.json"
    daemon, drv = make_daemon(retain=str(path), interval="50ms")
    assert daemon.status()["retain"]["state"] == "ok"
    fake = _FailingWrite(monkeypatch, error=errno.EIO)
    drv.inputs["I0"] = 1  # sN counts
    wait_until(lambda: daemon.status()["retain"]["state"] == "failing", what="failing")
    drv.inputs["I0"] = 0  # sN stops changing: the failed save must be retried anyway
    calls = fake.calls
    wait_until(lambda: fake.calls >= calls + 3, what="three retries")
    status = daemon.status()["retain"]
    assert "Input/output error" in status["text"] and status["since"] is not None
    monkeypatch.undo()
    wait_until(lambda: daemon.status()["retain"]["state"] == "ok", what="saving again")
    sn = daemon.plant.get("m.sN")
    wait_until(lambda: RetainStore(str(path)).load().data.get("m", {}).get("sN") == sn,
               what="the value on disk")


FULL_RUNS = textwrap.dedent("""\
    import errno, os, subprocess, sys
    root, mnt, plant = sys.argv[1:4]
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k,mode=0700", "tmpfs", mnt],
                   check=True)
    def run(seconds):
        return subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--sim", "--for",
                               seconds, plant], cwd=root, capture_output=True, text=True,
                              timeout=120).stderr
    first = run("1s")
    filler = os.path.join(mnt, "filler")
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
    try:
        while os.write(fd, b"x" * 4096) == 4096:
            pass
    except OSError as exc:
        assert exc.errno == errno.ENOSPC
    os.close(fd)
    size = os.path.getsize(filler)
    os.truncate(filler, size - size % 4096 - 4096)  # one page left
    second = run("1s")
    os.unlink(filler)
    third = run("0.3s")
    sys.stdout.write("\\n=====\\n".join((first, second, third)))
""")


def test_a_controller_on_a_full_disk_says_so_once_and_keeps_its_data(tmp_path: Path) -> None:
    """The attack as an operator meets it: three runs of ``softplc run``, the second on a
    disk left with one page."""
    if shutil.which("unshare") is None:
        pytest.skip("unshare(1) is not installed")
    probe = subprocess.run(["unshare", "-rm", "true"], capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"unshare -rm not permitted here: {probe.stderr.decode().strip()}")
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    memory = "".join(f"  sCounter{i:03d}: {{init: 0, retain: true}}\n" for i in range(200))
    counts = "".join(f"    - sCounter{i:03d} := sCounter{i:03d} + 1\n" for i in range(200))
    (tmp_path / "count.yaml").write_text(
        "grafcet: Count\ninputs: [iGo]\noutputs: [oRun]\nmemory:\n" + memory +
        "steps:\n  gsRun: {initial: true, actions: [oRun]}\ntransitions: []\npost:\n" + counts)
    (tmp_path / "plant.yaml").write_text(
        f"plc:\n  cycle: 10ms\n  watchdog: 500ms\n  retain: {mnt}/retain.json\n"
        "  retain_interval: 100ms\ndrivers:\n  io: {type: sim}\ninstances:\n  m:\n"
        f"    grafcet: {tmp_path}/count.yaml\n    inputs: {{iGo: io.I0}}\n"
        "    outputs: {oRun: io.Q0}\n")
    script = tmp_path / "runs.py"
    script.write_text(FULL_RUNS)
    out = subprocess.run(["unshare", "-rm", sys.executable, str(script), str(ROOT), str(mnt),
                          str(tmp_path / "plant.yaml")], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    first, second, third = out.stdout.split("\n=====\n")
    assert "ERROR" not in first and "retained data restored" not in first, first
    errors = [line for line in second.splitlines() if "ERROR" in line]
    assert len(errors) == 2, second  # saving fails (once), and the stop could not save
    assert "not written: [Errno 28] No space left on device" in errors[0]
    assert "retained data not saved at the stop" in errors[1]
    def restored(log: str) -> str:
        found = [line for line in log.splitlines() if "retained data restored" in line]
        assert len(found) == 1 and "LOST" not in log and "passed over" not in log, log
        return found[0].rsplit("(", 1)[1]  # "generation N)"

    assert restored(third) == restored(second)  # what the first run saved, untouched
