"""Helpers of the console tests: a pty null-modem that can hang up, line clients over
pyserial and Unix sockets, and a rig (daemon + console server) on a plant written here.

The daemon runs in-process on simulated I/O; its serial console is served on one pty of
a null-modem and the test talks to the other pty with pyserial, as picocom would.
"""

from __future__ import annotations

import json
import os
import re
import select
import socket
import tempfile
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import serial

from drivers.sim import SimDriver
from runtime.console.server import ConsoleServer
from runtime.console.service import ConsoleService
from runtime.controller.daemon import Daemon
from runtime.engine.plant import Plant
from runtime.language.model import ConsoleEntry
from runtime.language.plantfile import load_plant
from tests.console.schedprobe import SchedProbe

ROOT = Path(__file__).resolve().parents[2]
CHART = ROOT / "configs" / "drawer_tester" / "drawer_tester.yaml"
#: how long a test waits for something that normally takes a few scans (a failure
#: deadline, never a speed assertion)
DEADLINE_S = 10.0


#: a chart that changes every scan (a load for trace streams)
BLINK = """\
grafcet: Blink
outputs: [oLamp]
steps:
  s0: {initial: true}
  s1: {actions: [oLamp]}
transitions:
  - {from: s0, to: s1, when: "1"}
  - {from: s1, to: s0, when: "1"}
"""


def plant_yaml(port: str | None, sock: str | None, *, trusted: bool = True,
               pin_hash: str | None = None, release: bool = False, cycle: str = "10ms",
               blink: str | None = None, priority: int | None = None,
               watchdog: str = "300ms") -> str:
    """Two drawer testers on one simulated remote I/O ``rio`` (I0-I7, Q0-Q7); the stop
    buttons are NC contacts, inverted at the binding. With ``blink`` (the path of the
    BLINK chart), a third instance ``b1`` toggles rio.Q8 every scan."""
    extra = f"""\
  b1:
    grafcet: {blink}
    outputs: {{oLamp: rio.Q8}}
""" if blink else ""
    mon = []
    if port:
        mon.append(f"  serial: {{port: {port}, baudrate: 115200, trusted: {str(trusted).lower()}}}")
    if sock:
        mon.append(f"  socket: {{path: {sock}, trusted: {str(trusted).lower()}}}")
    if pin_hash:
        mon.append(f"  pin_hash: '{pin_hash}'")
    mon.append(f"  release_forces_on_disconnect: {str(release).lower()}")
    # None: the default (SCHED_FIFO 50 where permitted); 0: normal priority
    realtime = ("" if priority is None else ", realtime: false" if priority == 0
                else f", realtime: {{priority: {priority}}}")
    return f"""\
plc: {{cycle: {cycle}, watchdog: {watchdog}{realtime}}}
drivers:
  rio: {{type: sim}}
instances:
  t1:
    grafcet: {CHART}
    inputs:
      iParo: {{from: rio.I0, invert: true}}
      iMarcha: rio.I1
      iAbierto: rio.I2
      iCerrado: rio.I3
    outputs: {{oAbrir: rio.Q0, oCerrar: rio.Q1, oParado: rio.Q2, oTest: rio.Q3}}
  t2:
    grafcet: {CHART}
    inputs:
      iParo: {{from: rio.I4, invert: true}}
      iMarcha: rio.I5
      iAbierto: rio.I6
      iCerrado: rio.I7
    outputs: {{oAbrir: rio.Q4, oCerrar: rio.Q5, oParado: rio.Q6, oTest: rio.Q7}}
{extra}monitor:
""" + "\n".join(mon) + "\n"


class FlakySim(SimDriver):
    """Simulated I/O whose bus can be broken (``broken = "reason"``) and mended."""

    broken: str | None = None

    def _open(self) -> None:
        if self.broken:
            raise OSError(self.broken)

    def _read(self) -> None:
        if self.broken:
            raise OSError(self.broken)


class NullModem:
    """Two pseudo-terminals joined by a copying thread, like ``socat pty pty``.

    The daemon opens ``daemon_port``, the test's pyserial ``peer_port``. ``hangup()``
    closes the daemon side's master: the daemon's port then reports a hang-up, as a USB
    gadget port does when the cable is pulled."""

    def __init__(self) -> None:
        self._ma, self._sa = os.openpty()
        self._mb, self._sb = os.openpty()
        for fd in (self._sa, self._sb):
            tty.setraw(fd)
        for fd in (self._ma, self._mb):
            os.set_blocking(fd, False)
        self.daemon_port = os.ttyname(self._sa)
        self.peer_port = os.ttyname(self._sb)
        self._hung_up = False
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name="test-null-modem",
                                        daemon=True)
        self._thread.start()
        # our own slave descriptors are not needed: the ports are opened by path
        os.close(self._sa)
        os.close(self._sb)

    def _run(self) -> None:
        while True:
            fds = [self._mb, self._stop_r] + ([] if self._hung_up else [self._ma])
            ready, _, _ = select.select(fds, [], [], 0.1)
            if self._stop_r in ready:
                return
            for src, dst in ((self._ma, self._mb), (self._mb, self._ma)):
                if src not in ready or (self._hung_up and self._ma in (src, dst)):
                    continue
                try:
                    data = os.read(src, 65536)
                except OSError:  # the other side is not open (yet): the master keeps
                    # reporting that at once, so wait a little instead of spinning a core
                    select.select([self._stop_r], [], [], 0.02)
                    continue
                view = memoryview(data)
                end = time.monotonic() + 1.0
                while view and time.monotonic() < end:
                    try:
                        view = view[os.write(dst, view):]
                    except BlockingIOError:
                        select.select([], [dst], [], 0.05)
                    except OSError:
                        break  # nobody there: lost, as on a real line

    def hangup(self) -> None:
        self._hung_up = True
        time.sleep(0.15)  # let the copying thread leave the old select
        os.close(self._ma)

    def close(self) -> None:
        os.write(self._stop_w, b"x")
        self._thread.join()
        for fd in (*(() if self._hung_up else (self._ma,)), self._mb, self._stop_r,
                   self._stop_w):
            try:
                os.close(fd)
            except OSError:
                pass


def is_final(line: str) -> bool:
    """The last line of a reply (text or JSON mode)."""
    if line.startswith("{"):
        try:
            return "ok" in json.loads(line)
        except ValueError:
            return False
    return line == "ok" or line.startswith("ok ") or line.startswith("error")


class LineClient:
    """A console client over bytes: ``cmd(line)`` -> the reply's lines."""

    def __init__(self, send: Callable[[bytes], object], recv: Callable[[float], bytes | None],
                 close: Callable[[], None]) -> None:
        self._send = send
        self._recv = recv
        self._close = close
        self._buf = b""
        self.closed = False

    def send(self, data: bytes | str) -> None:
        self._send(data.encode() if isinstance(data, str) else data)

    def line(self, timeout: float = DEADLINE_S) -> str:
        """The next line (without CR LF); TimeoutError if none comes."""
        end = time.monotonic() + timeout
        while b"\n" not in self._buf:
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no line within {timeout} s; got {self._buf[:200]!r}")
            data = self._recv(min(left, 0.1))
            if data is None:
                raise EOFError("the console closed the connection")
            self._buf += data
        raw, self._buf = self._buf.split(b"\n", 1)
        return raw.rstrip(b"\r").decode("utf-8")

    def reply(self, timeout: float = DEADLINE_S) -> list[str]:
        """Lines up to and including the final ok/error line."""
        out = []
        while True:
            out.append(self.line(timeout))
            if is_final(out[-1]):
                return out

    def cmd(self, line: str | bytes, end: bytes = b"\r\n") -> list[str]:
        self.send((line.encode() if isinstance(line, str) else line) + end)
        return self.reply()

    def ok(self, line: str) -> list[str]:
        """``cmd`` that must succeed: the reply without its ``ok``."""
        out = self.cmd(line)
        assert out[-1] == "ok", f"{line!r} -> {out}"
        return out[:-1]

    def error(self, line: str | bytes, end: bytes = b"\r\n") -> str:
        """``cmd`` that must fail: its reason."""
        out = self.cmd(line, end)
        assert out[-1].startswith("error "), f"{line!r} -> {out}"
        return out[-1][len("error "):]

    def jcmd(self, line: str) -> dict[str, Any]:
        """A command in JSON mode: the reply object (every line must be one object)."""
        out = self.cmd(line)
        objs = [json.loads(x) for x in out]
        return dict(objs[-1])

    def until(self, pred: Callable[[str], bool], timeout: float = DEADLINE_S) -> list[str]:
        """Lines up to the first one for which ``pred`` is true."""
        out = []
        end = time.monotonic() + timeout
        while True:
            out.append(self.line(max(end - time.monotonic(), 0.01)))
            if pred(out[-1]):
                return out

    def pending(self, wait: float = 0.0) -> bytes:
        """Whatever has arrived (after waiting ``wait`` s)."""
        end = time.monotonic() + wait
        while True:
            data = self._recv(max(end - time.monotonic(), 0.0))
            if data:
                self._buf += data
            if time.monotonic() >= end:
                break
        out, self._buf = self._buf, b""
        return out

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._close()


def serial_client(port: str) -> LineClient:
    s = serial.Serial(port, 115200, timeout=0)

    def recv(timeout: float) -> bytes | None:
        if not s.in_waiting:
            select.select([s.fileno()], [], [], timeout)
        return bytes(s.read(s.in_waiting or 1))
    return LineClient(s.write, recv, s.close)


def socket_client(path: str) -> LineClient:
    c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    c.connect(path)
    return _sock_client(c)


def tcp_client(address: str) -> LineClient:
    host, port = address.rsplit(":", 1)
    return _sock_client(socket.create_connection((host, int(port))))


def _sock_client(c: socket.socket) -> LineClient:
    def recv(timeout: float) -> bytes | None:
        c.settimeout(max(timeout, 0.001))
        try:
            return c.recv(65536) or None
        except TimeoutError:
            return b""
    return LineClient(c.sendall, recv, c.close)


class FakeClock:
    """Monotonic seconds that a test moves by hand (PIN lock-out, half-line timeout)."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@dataclass
class Rig:
    """A running daemon with its console on a pty (``modem``) and a Unix socket."""

    daemon: Daemon
    driver: FlakySim
    service: ConsoleService
    server: ConsoleServer
    modem: NullModem | None
    socket_path: str | None
    tmp: str
    clients: list[LineClient] = field(default_factory=list)

    @property
    def plant(self) -> Plant:
        return self.daemon.plant

    def serial(self) -> LineClient:
        """The pyserial end of the null-modem (once the daemon's port is open)."""
        assert self.modem is not None
        wait_for(lambda: any(s.name.startswith("serial:") for s in self.server.sessions),
                 "the serial console to open")
        c = serial_client(self.modem.peer_port)
        self.clients.append(c)
        return c

    @property
    def tcp_address(self) -> str:
        """127.0.0.1:PORT of the TCP console (``make_rig(tcp=True)``)."""
        return next(a for a in self.server.addresses if a.startswith("127.0.0.1:"))

    def connect(self) -> LineClient:
        assert self.socket_path is not None
        c = socket_client(self.socket_path)
        self.clients.append(c)
        return c

    def state(self) -> str:
        return str(self.daemon.status()["state"])

    def read(self, name: str) -> Any:
        """A value read at a scan boundary (what the console would see)."""
        return self.daemon.call(lambda: self.plant.get(name))

    def set_input(self, point: str, value: int) -> None:
        self.daemon.call(lambda: self.driver.set_input(point, value))

    def steps(self, inst: str) -> list[str]:
        return list(self.daemon.call(lambda: self.plant.instances[inst].active_steps()))

    def close(self) -> None:
        for c in self.clients:
            c.close()
        self.server.stop()
        self.daemon.stop("end of test")
        if self.modem is not None:
            self.modem.close()
        for name in os.listdir(self.tmp):
            os.unlink(os.path.join(self.tmp, name))
        os.rmdir(self.tmp)


def wait_for(cond: Callable[[], Any], what: str, timeout: float = DEADLINE_S) -> Any:
    """Poll ``cond`` until true; AssertionError naming ``what`` after ``timeout`` s."""
    end = time.monotonic() + timeout
    while True:
        got = cond()
        if got:
            return got
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


def make_rig(*, serial_port: bool = True, unix_socket: bool = True, trusted: bool = True,
             pin_hash: str | None = None, release: bool = False, cycle: str = "10ms",
             clock: Callable[[], float] = time.monotonic, released_stop: bool = True,
             serial_path: str | None = None, blink: bool = False,
             manage_gc: bool = True, priority: int | None = None, tcp: bool = False,
             probe: SchedProbe | None = None, watchdog: str = "300ms") -> Rig:
    """Write the plant, start the daemon and its console; the stop button released
    (rio.I0 = rio.I4 = 1, NC contacts) so the testers can start.

    The serial console is on a NullModem, or on ``serial_path`` (a pty another process
    owns) when given. ``manage_gc`` (default) runs the collector as the daemon does in
    production (disabled, then run in the scan's idle time): left to the interpreter, a
    full collection of the test process's heap holds the GIL wherever it falls (0.2-0.8 s
    late in a suite), a freeze fault at the rig's watchdog.
    ``tcp=True`` adds a TCP console on an ephemeral port (``Rig.tcp_address``), served
    by the same server as the socket, as a plant's ``monitor: tcp:`` is. ``probe``
    records each wake-up of the scan thread (schedprobe.py); ``watchdog``: the plant's."""
    tmp = tempfile.mkdtemp(prefix="sc", dir="/tmp")  # short: Unix socket paths <= 107
    modem = NullModem() if serial_port and serial_path is None else None
    port = modem.daemon_port if modem else serial_path
    sock = os.path.join(tmp, "c.sock") if unix_socket else None
    path = os.path.join(tmp, "plant.yaml")
    blink_path = None
    if blink:
        blink_path = os.path.join(tmp, "blink.yaml")
        Path(blink_path).write_text(BLINK, encoding="utf-8")
    Path(path).write_text(plant_yaml(port, sock, trusted=trusted, pin_hash=pin_hash,
                                     release=release, cycle=cycle, blink=blink_path,
                                     priority=priority, watchdog=watchdog),
                          encoding="utf-8")
    pdef = load_plant(path)
    drv = FlakySim("rio", {"on_fault": "stop"})
    daemon = Daemon(pdef, plant=Plant(pdef, drivers={"rio": drv}), manage_gc=manage_gc)
    if probe is not None:
        daemon.scheduler.sleep_until = probe.wrap(daemon.scheduler.sleep_until)
    if released_stop:
        drv.set_input("I0", 1)
        drv.set_input("I4", 1)
    daemon.start()
    service = ConsoleService(daemon, pdef.pin_hash, pdef.release_forces_on_disconnect,
                             clock=clock)
    entries = [*pdef.consoles, *([ConsoleEntry("tcp", "127.0.0.1:0")] if tcp else [])]
    server = ConsoleServer(service, entries)
    server.start()
    return Rig(daemon, drv, service, server, modem, sock, tmp)


class TermScreen:
    """Just enough of an xterm to read what curses drew: cursor moves, erases, inserts and
    deletes, scroll region (``text()`` is the screen as lines)."""

    _CSI = re.compile(r"\x1b\[([?>]?)([0-9;]*)([@A-Za-z])")

    def __init__(self, rows: int, cols: int) -> None:
        self.rows, self.cols = rows, cols
        self.grid = [[" "] * cols for _ in range(rows)]
        self.y = self.x = 0
        self.top, self.bottom = 0, rows - 1
        self.saved = (0, 0)
        self._pending = ""

    def feed(self, data: bytes) -> None:
        s = self._pending + data.decode("utf-8", "replace")
        self._pending = ""
        i = 0
        while i < len(s):
            c = s[i]
            if c == "\x1b":
                m = self._CSI.match(s, i)
                if m:
                    self._csi(m.group(1), m.group(2), m.group(3))
                    i = m.end()
                    continue
                if i + 1 >= len(s) or (s[i + 1] in "()" and i + 2 >= len(s)) or (
                        s[i + 1] == "[" and not m):
                    if len(s) - i < 32:
                        self._pending = s[i:]
                        return
                nxt = s[i + 1] if i + 1 < len(s) else ""
                if nxt == "7":
                    self.saved = (self.y, self.x)
                elif nxt == "8":
                    self.y, self.x = self.saved
                elif nxt == "M":
                    if self.y == self.top:
                        self._scroll(-1)
                    else:
                        self.y = max(0, self.y - 1)
                i += 3 if nxt in "()" else 2
                continue
            if c == "\r":
                self.x = 0
            elif c == "\n":
                if self.y == self.bottom:
                    self._scroll(1)
                else:
                    self.y = min(self.rows - 1, self.y + 1)
            elif c == "\b":
                self.x = max(0, self.x - 1)
            elif c == "\t":
                self.x = min(self.cols - 1, (self.x // 8 + 1) * 8)
            elif c >= " ":
                if self.x >= self.cols:
                    self.x = self.cols - 1
                self.grid[self.y][self.x] = c
                self.x += 1
            i += 1

    def _scroll(self, n: int) -> None:
        region = self.grid[self.top:self.bottom + 1]
        blank = [[" "] * self.cols for _ in range(abs(n))]
        region = region[n:] + blank if n > 0 else blank + region[:n]
        self.grid[self.top:self.bottom + 1] = region

    def _csi(self, private: str, params: str, cmd: str) -> None:
        if private:
            if params == "1049" and cmd in "hl":
                self.grid = [[" "] * self.cols for _ in range(self.rows)]
            return
        args = [int(p) if p else 0 for p in params.split(";")] if params else []
        n = max(args[0], 1) if args else 1
        row = self.grid[self.y]
        if cmd in "Hf":
            self.y = min(max((args[0] if args else 1), 1), self.rows) - 1
            self.x = min(max((args[1] if len(args) > 1 else 1), 1), self.cols) - 1
        elif cmd == "A":
            self.y = max(0, self.y - n)
        elif cmd in "Be":
            self.y = min(self.rows - 1, self.y + n)
        elif cmd in "Ca":
            self.x = min(self.cols - 1, self.x + n)
        elif cmd == "D":
            self.x = max(0, self.x - n)
        elif cmd in "G`":
            self.x = min(n, self.cols) - 1
        elif cmd == "d":
            self.y = min(n, self.rows) - 1
        elif cmd == "K":
            mode = args[0] if args else 0
            lo, hi = {0: (self.x, self.cols), 1: (0, self.x + 1), 2: (0, self.cols)}[mode]
            row[lo:hi] = [" "] * (hi - lo)
        elif cmd == "J":
            mode = args[0] if args else 0
            if mode == 0:
                row[self.x:] = [" "] * (self.cols - self.x)
                rows = range(self.y + 1, self.rows)
            elif mode == 1:
                row[:self.x + 1] = [" "] * (self.x + 1)
                rows = range(0, self.y)
            else:
                rows = range(self.rows)
            for r in rows:
                self.grid[r] = [" "] * self.cols
        elif cmd == "X":
            row[self.x:self.x + n] = [" "] * len(row[self.x:self.x + n])
        elif cmd == "@":
            row[self.x:self.x] = [" "] * n
            del row[self.cols:]
        elif cmd == "P":
            del row[self.x:self.x + n]
            row.extend([" "] * (self.cols - len(row)))
        elif cmd in "LM":
            saved = self.top
            self.top = self.y
            self._scroll(-n if cmd == "L" else n)
            self.top = saved
        elif cmd == "r":
            self.top = (args[0] if args and args[0] else 1) - 1
            self.bottom = (args[1] if len(args) > 1 and args[1] else self.rows) - 1
            self.y = self.x = 0
        elif cmd in "ST":
            self._scroll(n if cmd == "S" else -n)

    def text(self) -> str:
        return "\n".join("".join(r).rstrip() for r in self.grid)
