"""Test parts for ``softplc modbus``: the drawer tester of configs/ with a ``modbus:``
section on a free port of 127.0.0.1, the controller and the server as two real processes,
a console line, and Modbus clients that are not ours (pymodbus' client, Debian's mbpoll)."""

from __future__ import annotations

import re
import shutil
import socket
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tests.opcua.feedkit import FeedReader, wait_until
from tests.web.kit import Proc, rundir_of, start, stop

ROOT = Path(__file__).resolve().parents[2]
#: the feed's sample in the tests, ms (5 scans of 10 ms)
SAMPLE_MS = 50
MBPOLL = shutil.which("mbpoll")


def start_server(tmp: Path, *args: str, nice: int = 0, nofile: int | None = None) -> Proc:
    """``softplc modbus ARGS`` (at niceness ``nice``: its unit runs it at 10; the tests at
    the machine's own, so that the other jobs of a shared test machine do not starve it);
    ``nofile``: its open-file limit (RLIMIT_NOFILE), as its unit's ``LimitNOFILE=``."""
    return start(tmp, "modbus", *args, nofile=nofile, nice=nice)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def write_plant(tmp: Path, modbus: str = "", port: int | None = None,
                plc: str = "", sample_ms: int = SAMPLE_MS) -> tuple[Path, int]:
    """The drawer tester (two instances on sim I/O), a console socket, and a ``modbus:``
    section listening on a free port with tester1.sParo and tester1.sCierres writable,
    then ``modbus`` (more keys of the section). In the directory ``tmp/p``: the plant's
    name is its runtime directory's (``${RUNTIME_DIR}`` is ``tmp/softplc/p-HASH``), short
    enough for its sockets below a test's tmp path. (plant path, port)."""
    port = free_port() if port is None else port
    tmp = tmp / "p"
    tmp.mkdir(exist_ok=True)
    shutil.copy(ROOT / "configs/drawer_tester/drawer_tester.yaml", tmp / "drawer_tester.yaml")
    text = (ROOT / "configs/drawer_tester/plant_sim.yaml").read_text(encoding="utf-8")
    text = text[:text.index("\nmonitor:")] + "\n"
    text = text.replace("watchdog: 100ms", f"watchdog: 5s{plc}").replace(
        "retain: ${RUNTIME_DIR}/drawer_tester_sim.retain.json", "retain: null")
    text += ("monitor:\n  socket: {path: '${RUNTIME_DIR}/console.sock', trusted: true}\n"
             f"modbus:\n  listen: 127.0.0.1:{port}\n  sample: {sample_ms}ms\n"
             "  writable: [tester1.sParo, tester1.sCierres]\n")
    text += modbus
    plant = tmp / "plant.yaml"
    plant.write_text(text, encoding="utf-8")
    return plant, port


@dataclass
class Rig:
    """The controller and its Modbus server, running."""

    tmp: Path
    plant: Path
    port: int
    ctl: Proc
    server: Proc
    feed: FeedReader

    @property
    def rundir(self) -> Path:
        """The plant's ``${RUNTIME_DIR}`` (its own, below the test's XDG_RUNTIME_DIR)."""
        return rundir_of(self.tmp, self.plant)

    def console(self, *lines: str) -> list[str]:
        """The replies of a fresh console session to ``lines``."""
        out = []
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.connect(str(self.rundir / "console.sock"))
            f = s.makefile("rw", encoding="utf-8", newline="\n")
            for line in lines:
                f.write(line + "\n")
                f.flush()
                while True:
                    reply = f.readline()
                    assert reply, "the console closed the session"
                    out.append(reply.rstrip("\r\n"))
                    if reply.startswith(("ok", "error")):
                        break
        return out

    def get(self, name: str) -> str:
        """``get NAME`` through the console: its value as the console shows it."""
        text = " ".join(self.console(f"get {name}"))
        m = re.search(re.escape(name) + r"=(\S+)", text)
        assert m, text
        return m.group(1)

    def status(self) -> dict[str, Any]:
        return self.feed.statuses[-1] if self.feed.statuses else {}


def served(port: int) -> bool:
    """The server on ``port`` has answered one read with values (not exception 11)."""
    from pymodbus.client import ModbusTcpClient

    c = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
    try:
        if not c.connect():
            return False
        rr = c.read_discrete_inputs(0, count=1, device_id=1)
        return not rr.isError()
    except Exception:  # noqa: BLE001 - not up yet
        return False
    finally:
        c.close()


@contextmanager
def rig(tmp: Path, modbus: str = "", plc: str = "", server_args: tuple[str, ...] = (),
        wait_served: bool = True, nice: int = 0, sample_ms: int = SAMPLE_MS,
        nofile: int | None = None) -> Iterator[Rig]:
    """The controller (``softplc run --sim``) and ``softplc modbus`` (at niceness
    ``nice``, its open-file limit ``nofile`` if given), until the block ends; once the
    server serves values (``wait_served``), else once it listens."""
    plant, port = write_plant(tmp, modbus, plc=plc, sample_ms=sample_ms)
    ctl = start(tmp, "run", str(plant), "--sim")
    server = None
    feed = None
    try:
        feed_path = rundir_of(tmp, plant) / "feed.sock"
        wait_until(lambda: feed_path.exists() or ctl.popen.poll() is not None, 30.0,
                   "the feed socket")
        assert ctl.popen.poll() is None, ctl.log()
        server = start_server(tmp, str(plant), *server_args, nice=nice, nofile=nofile)
        feed = FeedReader(str(feed_path))
        r = Rig(tmp, plant, port, ctl, server, feed)
        if wait_served:
            wait_until(lambda: served(port) or server.popen.poll() is not None, 30.0,
                       "the Modbus server serving values")
        else:
            wait_until(lambda: "Modbus/TCP server on" in server.log()
                       or server.popen.poll() is not None, 30.0, "the Modbus server")
        assert server.popen.poll() is None, server.log()
        yield r
    finally:
        if feed is not None:
            feed.close()
        stop(server, ctl)


def mbpoll(port: int, *args: str) -> subprocess.CompletedProcess[str]:
    """Debian's mbpoll, one poll (``-1``) of 127.0.0.1:``port``: ``args`` as its manual
    gives them (``-t 3 -r 1 -c 4``...)."""
    assert MBPOLL is not None
    return subprocess.run([MBPOLL, "-m", "tcp", "-p", str(port), "-1", "-o", "2", *args,
                           "127.0.0.1"], capture_output=True, text=True, timeout=30,
                          check=False)


def mbpoll_write(port: int, *args: str) -> subprocess.CompletedProcess[str]:
    """mbpoll writing: ``args`` (``-t 0 -r 9``) then the values."""
    assert MBPOLL is not None
    *opts, value = args
    return subprocess.run([MBPOLL, "-m", "tcp", "-p", str(port), "-o", "2", *opts,
                           "127.0.0.1", value], capture_output=True, text=True, timeout=30,
                          check=False)


def mbpoll_values(out: str) -> dict[int, str]:
    """``[ref]: value`` lines of mbpoll's output -> {ref: value}."""
    return {int(m.group(1)): m.group(2) for m in re.finditer(r"^\[(\d+)\]:\s+(\S+)", out,
                                                             re.M)}
