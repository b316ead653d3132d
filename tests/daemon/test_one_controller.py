"""One controller per plant (docs/daemon.md, "One controller per plant"): a second
``softplc run`` of a running plant is refused at once naming the running PID; no process
unlinks a file or socket it did not create; retained data names its plant (its directory)
and a file of another plant is refused. Real processes, real sockets."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from runtime.controller.retain import RetainStore
from tests.daemon.daemonkit import CHART, plant_yaml

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def write_plant(directory: Path, *, retain: Path | None = None, sock: Path | None = None,
                feed: Path | None = None) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "runner.yaml").write_text(CHART, encoding="utf-8")
    extra = ""
    if sock is not None:
        extra += f"monitor:\n  socket: {{path: '{sock}', trusted: true}}\n"
    if feed is not None:
        extra += f"opcua:\n  feed: {feed}\n"
    plant = directory / "plant.yaml"
    plant.write_text(plant_yaml(retain=str(retain) if retain else None, interval="50ms",
                                extra=extra), encoding="utf-8")
    return plant


def start(plant: Path, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", str(plant), "--sim",
                             *extra], env=ENV, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)


def ask(sock: Path, line: str, timeout: float = 20.0) -> str:
    """One console request, retried until the console answers (or ``timeout``)."""
    end = time.monotonic() + timeout
    while True:
        try:
            with socket.socket(socket.AF_UNIX) as s:
                s.settimeout(5)
                s.connect(str(sock))
                s.sendall(line.encode() + b"\n")
                out = b""
                while not out.endswith(b"ok\r\n") and b"error" not in out:
                    chunk = s.recv(4096)
                    if not chunk:
                        break
                    out += chunk
            return out.decode()
        except OSError:
            if time.monotonic() > end:
                raise
            time.sleep(0.05)


def stop(proc: subprocess.Popen[str]) -> str:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        _, err = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    return err


def test_a_second_run_of_a_running_plant_is_refused_and_leaves_the_first_alone(
        tmp_path: Path) -> None:
    sock = tmp_path / "console.sock"
    plant = write_plant(tmp_path / "press", retain=tmp_path / "press.retain.json", sock=sock)
    first = start(plant)
    try:
        assert "state" in ask(sock, "status")
        second = subprocess.run([sys.executable, "-m", "runtime.cli", "run", str(plant),
                                 "--sim", "--for", "3s"], env=ENV, capture_output=True,
                                text=True, timeout=60)
        assert second.returncode == 2, second.stderr
        # at once: nothing opened, restored or bound before the refusal, its one line
        lines = second.stderr.strip().splitlines()
        assert len(lines) == 1, second.stderr
        assert "plant press is already running" in lines[0]
        assert f"PID {first.pid}" in lines[0]
        # the first one still has its console (its socket was neither taken nor removed)
        assert sock.is_socket()
        assert "state running" in ask(sock, "status", timeout=10.0)
        assert first.poll() is None
    finally:
        err = stop(first)
    assert "console listening" in err


@pytest.mark.parametrize("kind", ["console", "feed"])
def test_a_socket_path_naming_a_regular_file_never_removes_it(tmp_path: Path,
                                                              kind: str) -> None:
    victim = tmp_path / "hostname"
    victim.write_text("plc1\n", encoding="utf-8")
    plant = write_plant(tmp_path / "p", **({"sock": victim} if kind == "console" else
                                          {"feed": victim}))
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "run", str(plant), "--sim",
                        "--for", "1s"], env=ENV, capture_output=True, text=True, timeout=60)
    assert victim.read_text(encoding="utf-8") == "plc1\n"
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert lines[-1] == (f"softplc run: error: {victim} exists and is not a socket (a "
                         f"regular file): left alone; give the {kind} socket another path"), \
        r.stderr


def test_a_socket_another_process_listens_on_is_left_to_it(tmp_path: Path) -> None:
    sock = tmp_path / "console.sock"
    other = socket.socket(socket.AF_UNIX)
    other.bind(str(sock))
    other.listen(1)
    try:
        plant = write_plant(tmp_path / "p", sock=sock)
        r = subprocess.run([sys.executable, "-m", "runtime.cli", "run", str(plant), "--sim",
                            "--for", "1s"], env=ENV, capture_output=True, text=True,
                           timeout=60)
        assert r.returncode == 2, r.stderr
        assert r.stderr.strip().splitlines()[-1] == (
            f"softplc run: error: {sock}: another process listens there (PID {os.getpid()}):"
            " left alone; stop it or give the console socket another path")
        # still ours: a client reaches this listener, not a controller
        with socket.socket(socket.AF_UNIX) as c:
            c.connect(str(sock))
    finally:
        other.close()


def test_a_stale_socket_of_another_program_is_left_alone(tmp_path: Path) -> None:
    sock = tmp_path / "console.sock"
    dead = socket.socket(socket.AF_UNIX)
    dead.bind(str(sock))
    dead.close()  # a socket file nobody listens on, made by someone else
    plant = write_plant(tmp_path / "p", sock=sock)
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "run", str(plant), "--sim",
                        "--for", "1s"], env=ENV, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stderr
    assert "was not made by this plant: left alone" in r.stderr.strip().splitlines()[-1]
    assert sock.is_socket()


def test_the_sockets_a_killed_controller_left_are_replaced_by_its_next_start(
        tmp_path: Path) -> None:
    sock = tmp_path / "console.sock"
    plant = write_plant(tmp_path / "p", sock=sock, feed=tmp_path / "feed.sock")
    first = start(plant)
    try:
        ask(sock, "status")
    finally:
        first.kill()
        first.communicate()
    assert sock.is_socket() and (tmp_path / "feed.sock").is_socket()
    again = start(plant)
    try:
        assert "state running" in ask(sock, "status")
    finally:
        err = stop(again)
    assert "error" not in err.lower(), err
    # an orderly stop removes what it made
    assert not sock.exists() and not (tmp_path / "feed.sock").exists()


def test_retained_data_of_another_plant_is_refused(tmp_path: Path) -> None:
    """Two clones of one project: the same plant, the same ${RUNTIME_DIR} retain path."""
    shared = tmp_path / "shared.retain.json"
    a = write_plant(tmp_path / "clone-a" / "drawer", retain=shared)
    b = write_plant(tmp_path / "clone-b" / "drawer", retain=shared)
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "run", str(a), "--sim", "--for",
                        "0.5s"], env=ENV, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    before = shared.read_bytes()
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "run", str(b), "--sim", "--for",
                        "0.5s"], env=ENV, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert line.startswith(f"{b}:5:11: error: plc retain: {shared} holds the retained data "
                           f"of plant drawer ({a.parent}), not of this plant ({b.parent}): not "
                           "started"), line
    assert shared.read_bytes() == before  # not restored, not overwritten


def test_retained_data_of_a_moved_plant_is_taken_over(tmp_path: Path) -> None:
    retain = tmp_path / "r.retain.json"
    a = write_plant(tmp_path / "old", retain=retain)
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "run", str(a), "--sim", "--for",
                        "0.5s"], env=ENV, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    gen = RetainStore(str(retain)).load().generation
    shutil.move(str(tmp_path / "old"), str(tmp_path / "new"))
    b = tmp_path / "new" / "plant.yaml"
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "run", str(b), "--sim", "--for",
                        "0.5s"], env=ENV, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert f"retain: {retain} was saved by plant old ({a.parent}), which is no longer " \
           f"there: taken over by this plant ({b.parent})" in r.stderr
    loaded = RetainStore(str(retain)).load()
    assert loaded.generation > gen and loaded.owner == {"name": "new", "path": str(b.parent)}


def test_ready_is_sent_only_once_the_start_is_complete(tmp_path: Path,
                                                       make_daemon: object) -> None:
    """Under a real systemd (issue 25's journeys), a controller whose start then failed
    (a serial port missing, found after the first cycle) had already sent READY=1: systemd
    said `started`, and install-service with it, for a controller that exited 2 at once.
    READY=1 waits for the end of the start (the consoles and the feed listening, the drivers
    checked), however long it takes."""
    from runtime.controller.notify import Notifier
    from runtime.controller.service import serve
    from tests.daemon.test_daemon_process import NotifySocket

    notify = NotifySocket(tmp_path / "notify.sock")
    daemon, _ = make_daemon(start=False)  # type: ignore[operator]
    daemon.notifier = Notifier({"NOTIFY_SOCKET": notify.path})
    early: list[str] = []
    scans: list[int] = []

    def started() -> None:  # a start that takes a while after the first cycles
        early.extend(notify.collect(1.0))
        scans.append(daemon.scan_stats.count)

    assert serve(daemon, 2_000_000_000, started) == 0
    later = notify.drain()
    assert scans[0] > 10  # the scan ran meanwhile
    assert not any("READY=1" in m for m in early), early
    assert any("READY=1" in m for m in later), later


def test_a_file_written_before_the_owner_was_recorded_is_taken_over(tmp_path: Path) -> None:
    """Format 2 (no ``plant``): restored by whichever plant starts on it; its next save
    records the owner (format 3)."""
    import json

    from runtime.controller import retain as R

    retain = tmp_path / "r.retain.json"
    payload = {"format": R.FORMAT_2, "generation": 7, "saved_at": 1.0,
               "charts": {"m": "Runner"}, "types": {"m": {"sN": "int"}},
               "data": {"m": {"sN": 41}}}
    retain.write_text(json.dumps({**payload, "sha256": R._digest(payload)}), encoding="utf-8")
    plant = write_plant(tmp_path / "press", retain=retain, sock=tmp_path / "c.sock")
    proc = start(plant)
    try:
        assert int(ask(tmp_path / "c.sock", "get m.sN").split("m.sN=")[1].split()[0]) >= 41
    finally:
        err = stop(proc)
    assert "restored from" in err and "saved by plant" not in err, err
    loaded = RetainStore(str(retain)).load()
    assert loaded.generation > 7
    assert loaded.owner == {"name": "press", "path": str(tmp_path / "press")}
    assert json.loads(retain.read_text(encoding="utf-8"))["format"] == "softplc-retain/3"
