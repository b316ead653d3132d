"""Every side process (``softplc opcua``, ``mqtt``, ``web``) finds its controller's feed
the same way and says so:

- a feed path that is something other than a socket (a regular file: the controller
  refuses to serve there) is one line naming the plant's ``feed:``, exit status 2, at once,
  the file untouched (``softplc mqtt`` and ``softplc web`` ran on silently, retrying
  forever, while ``softplc opcua`` refused: issue 25's start check was the OPC UA
  server's only);
- no controller yet (the socket is not there): one line saying which path it waits on
  (the three processes said nothing at INFO until a controller came), and it waits."""

from __future__ import annotations

import os
import select
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.opcua.kit import plant_head

ROOT = Path(__file__).resolve().parents[1]

#: the side sections, each naming its feed at line 14 of the plant (after plant_head's 12)
SECTIONS = {
    "mqtt": "mqtt:\n  feed: {feed}\n  brokers: [mqtt://127.0.0.1:1]\n  group_id: G\n"
            "  edge_node_id: e\n",
    "web": "web:\n  feed: {feed}\n  listen: 127.0.0.1:0\n",
    "opcua": "opcua:\n  feed: {feed}\n  endpoint: opc.tcp://127.0.0.1:{port}\n"
             "  security: {{policies: [None]}}\n",
}


def write(tmp: Path, side: str) -> Path:
    plant = tmp / "plant.yaml"
    with socket.socket() as probe:  # a free port for the OPC UA server
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    plant.write_text(plant_head(tmp) + SECTIONS[side].format(feed=tmp / "feed.sock",
                                                             port=port), encoding="utf-8")
    return plant


def side(cmd: str, plant: Path, tmp: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_RUNTIME_DIR": str(tmp)}
    env.pop("JOURNAL_STREAM", None)
    return subprocess.Popen([sys.executable, "-m", "runtime.cli", cmd, str(plant)],
                            cwd=str(tmp), env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


@pytest.mark.parametrize("cmd", ["mqtt", "web", "opcua"])
def test_a_feed_path_that_is_no_socket_is_one_line_at_once(tmp_path: Path, cmd: str) -> None:
    plant = write(tmp_path, cmd)
    (tmp_path / "feed.sock").write_text("not a socket\n", encoding="utf-8")
    p = side(cmd, plant, tmp_path)
    try:
        out, _ = p.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        p.kill()
        out, _ = p.communicate()
        raise AssertionError(f"softplc {cmd} ran on with a feed that is no socket: {out}"
                             ) from None
    assert p.returncode == 2, out
    assert out.splitlines() == [
        f"{plant}:14:9: error: {cmd} feed: {tmp_path}/feed.sock is not a socket (a regular "
        f"file): the controller serves its feed there; give {cmd}: feed another path"], out
    assert (tmp_path / "feed.sock").read_text(encoding="utf-8") == "not a socket\n"


@pytest.mark.parametrize("cmd", ["mqtt", "web", "opcua"])
def test_no_controller_yet_is_said_once_and_waited_for(tmp_path: Path, cmd: str) -> None:
    plant = write(tmp_path, cmd)
    p = side(cmd, plant, tmp_path)
    want = (f"waiting for the controller's feed {tmp_path}/feed.sock (not there: is the "
            "controller running?)")
    seen: list[str] = []
    try:
        assert p.stdout is not None
        end = time.monotonic() + 60
        while time.monotonic() < end:
            ready, _, _ = select.select([p.stdout], [], [], max(0.0, end - time.monotonic()))
            if not ready:
                break
            line = p.stdout.readline()
            if not line:
                break
            seen.append(line.rstrip("\n"))
            if want in line:
                break
        assert any(want in s for s in seen), seen
        assert p.poll() is None, seen  # it waits
    finally:
        p.send_signal(signal.SIGTERM)
        try:
            rest, _ = p.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            p.kill()
            rest, _ = p.communicate()
    seen += rest.splitlines()
    assert sum(want in s for s in seen) == 1, seen  # said once, not at every retry
    assert not any("Traceback" in s for s in seen), seen


@pytest.mark.parametrize("cmd", ["mqtt", "web", "opcua"])
def test_the_feed_of_another_plant_is_refused_in_one_line(tmp_path: Path, cmd: str) -> None:
    """Issue: ``softplc web`` of a second plant attached to the first plant's feed and
    showed "live / running" over its own chart, every value "?". The feed says whose it is
    (the plant's name and directory, as its lock and retained data do); a side process
    given another plant's refuses it: one line, exit status 2, nothing served from it."""
    feed = tmp_path / "shared-feed.sock"
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    (a / "plant.yaml").write_text(plant_head(a) + f"web:\n  feed: {feed}\n  listen: "
                                  "127.0.0.1:0\n", encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_RUNTIME_DIR": str(tmp_path)}
    env.pop("JOURNAL_STREAM", None)
    ctl = subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", str(a / "plant.yaml"),
                            "--sim"], cwd=str(tmp_path), env=env, stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + 60
        while not feed.is_socket():
            assert ctl.poll() is None and time.monotonic() < end, "the controller's feed"
            time.sleep(0.05)
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        plant = b / "plant.yaml"
        plant.write_text(plant_head(b) + SECTIONS[cmd].format(feed=feed, port=port),
                         encoding="utf-8")
        p = side(cmd, plant, b)
        try:
            out, _ = p.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            p.kill()
            out, _ = p.communicate()
            raise AssertionError(f"softplc {cmd} followed another plant's feed: {out}"
                                 ) from None
    finally:
        ctl.send_signal(signal.SIGTERM)
        ctl.communicate(timeout=30)
    want = (f"{plant}:14:9: error: {cmd} feed: {feed} is the feed of plant a ({a}), not of "
            f"this plant b ({b}): not followed; give {cmd}: feed a path of its own (or "
            "leave it out: the default is the plant's own)")
    assert p.returncode == 2, out
    lines = out.splitlines()
    assert lines[-1] == want, out
    assert sum("error" in x.lower() for x in lines) == 1, out
    assert not any("Traceback" in x for x in lines), out
