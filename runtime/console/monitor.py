"""``softplc monitor PORT|SOCKET``: a live terminal view of a running controller.

The laptop side of the console: it speaks the JSON mode of the console protocol
(console.md) over a Unix socket, a 127.0.0.1 TCP port or a serial line, refreshes a view
of the plant a few times a second (state, active steps per instance, inputs and outputs
with forced marks, cycle statistics, last faults) and has a prompt for console commands.

The controller may go away under it (restarted, rebooted, unplugged, or the console
closing an idle connection): the monitor says so, keeps the last view, tries again with
back-off (RETRY_MIN_S doubling to RETRY_MAX_S), and says when the controller it finds again
is a new run of it (its start, from ``status``'s uptime, moved).

Layers, so all but the last are testable without a terminal: ``Link`` (bytes),
``ConsoleClient`` (JSON requests and replies), ``Connection`` (a client, opened again after
a loss), ``View`` (what the screen shows, as text lines), ``Monitor`` (the screen's logic:
refreshes, commands, streams, reconnection); ``run_screen`` draws it with curses from the
standard library, which is on every Linux laptop and needs nothing more for a few lines of
text and a prompt.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import re
import socket
import stat
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Protocol

from runtime.controller.alarms import alarm_lines
from runtime.errors import Loc, SoftplcError, SourceError
from runtime.language.runtimedir import expand

log = logging.getLogger(__name__)

#: how long a command may take before the controller is considered silent, seconds
REQUEST_TIMEOUT_S = 5.0
#: the same while connecting again (keys wait meanwhile: keep it short), seconds
RECONNECT_TIMEOUT_S = 2.0
#: after a loss, the first try this long after it, then each wait doubled up to the
#: maximum, seconds
RETRY_MIN_S = 0.5
RETRY_MAX_S = 5.0
#: view refresh period, seconds; slower on a serial line, where a refresh (~2.5 kB) takes
#: about 0.2 s at 115200 baud
REFRESH_S = 0.25
SERIAL_REFRESH_S = 1.0
#: the shortest refresh period, seconds: a refresh is three lines, and the console runs at
#: most 50 lines/s per session (30 here, the rest for what is typed)
MIN_REFRESH_S = 0.1
#: two starts of the controller estimated this far apart are two runs of it, seconds (each
#: estimate is exact to the time a ``status`` takes, plus the 1 ms of its rounding)
RESTART_SLACK_S = 0.25
#: reply lines kept under the view
LOG_LINES = 200

_TCP = re.compile(r"^(?:\[?[\w.:-]*\]?):(\d+)$")


class MonitorError(SoftplcError):
    """The controller cannot be reached or stopped answering.

    Examples: the socket path does not exist; the serial port is held by another
    program; no reply within REQUEST_TIMEOUT_S."""


class ConnectionLost(MonitorError):
    """The link broke while in use, or the controller stopped answering on it.

    Examples: the controller was restarted or killed (its socket closed: a broken pipe,
    a reset); a USB serial gadget went away; the console closed an idle connection; no
    reply within REQUEST_TIMEOUT_S (the link's state is unknown: it is opened again)."""


# -- links ----------------------------------------------------------------------------
class Link(Protocol):
    """A byte pipe to the console."""

    name: str

    def send(self, data: bytes) -> None: ...

    def recv(self, timeout: float) -> bytes | None:
        """Bytes that arrived within ``timeout`` s (b"" if none), None once closed."""

    def close(self) -> None: ...


class SocketLink:
    """A Unix socket or a TCP connection."""

    def __init__(self, sock: socket.socket, name: str) -> None:
        self.sock = sock
        self.name = name

    def send(self, data: bytes) -> None:
        try:
            self.sock.settimeout(REQUEST_TIMEOUT_S)
            self.sock.sendall(data)
        except (BrokenPipeError, ConnectionResetError):
            raise ConnectionLost(f"{self.name}: the controller closed the "
                                 "connection") from None
        except OSError as exc:  # a send timeout
            raise ConnectionLost(f"{self.name}: {_why(exc)}") from None

    def recv(self, timeout: float) -> bytes | None:
        try:
            self.sock.settimeout(max(timeout, 0.001))
            return self.sock.recv(65536) or None
        except TimeoutError:
            return b""
        except OSError:  # ECONNRESET
            return None

    def close(self) -> None:
        self.sock.close()


class SerialLink:
    """A serial port (pyserial)."""

    def __init__(self, port: str, baudrate: int) -> None:
        import serial

        try:
            self.port = serial.Serial(port, baudrate, timeout=0, write_timeout=REQUEST_TIMEOUT_S,
                                      exclusive=True)
        except (OSError, serial.SerialException) as exc:
            raise MonitorError(f"cannot open serial port {port}: {exc}") from None
        self.name = f"{port} at {baudrate} baud"

    def send(self, data: bytes) -> None:
        import serial

        try:
            self.port.write(data)
        except (OSError, serial.SerialException) as exc:  # unplugged, or a write timeout
            raise ConnectionLost(f"{self.name}: {_why(exc)}") from None

    def recv(self, timeout: float) -> bytes | None:
        import select

        import serial

        try:
            if not self.port.in_waiting:
                ready, _, _ = select.select([self.port.fileno()], [], [], max(timeout, 0.0))
                if not ready:
                    return b""
            return bytes(self.port.read(self.port.in_waiting or 1))
        except (OSError, serial.SerialException):
            return None  # hang-up

    def close(self) -> None:
        self.port.close()


class LinkKind(Enum):
    """What kind of console a target is."""

    SOCKET = "socket"
    TCP = "tcp"
    SERIAL = "serial"


@dataclass(frozen=True)
class Target:
    """Where the console is. The kind is decided once, from what the address is when the
    monitor starts: a socket that disappears while its controller restarts is still a
    socket to connect to again."""

    kind: LinkKind
    address: str
    baudrate: int = 115200

    @classmethod
    def parse(cls, text: str, baudrate: int = 115200) -> Target:
        """``/run/softplc/console.sock`` (Unix socket), ``HOST:PORT`` (TCP) or a serial
        device."""
        try:
            mode: int | None = os.stat(text).st_mode
        except OSError:
            mode = None
        if mode is not None and stat.S_ISSOCK(mode):
            return cls(LinkKind.SOCKET, text, baudrate)
        if mode is None and _TCP.match(text):
            return cls(LinkKind.TCP, text, baudrate)
        if mode is None:
            raise MonitorError(f"{text}: no such socket or serial port (or HOST:PORT for TCP)")
        return cls(LinkKind.SERIAL, text, baudrate)

    def open(self, timeout: float = REQUEST_TIMEOUT_S) -> Link:
        """A new link (MonitorError when it cannot be opened now)."""
        if self.kind is LinkKind.SERIAL:
            return SerialLink(self.address, self.baudrate)
        if self.kind is LinkKind.SOCKET:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                sock.connect(self.address)
            except OSError as exc:
                sock.close()
                raise MonitorError(f"cannot connect to {self.address}: {_why(exc)}") from None
            return SocketLink(sock, self.address)
        m = _TCP.match(self.address)
        assert m is not None
        host = self.address[:m.start(1) - 1].strip("[]") or "127.0.0.1"
        try:
            sock = socket.create_connection((host, int(m.group(1))), timeout=timeout)
        except OSError as exc:
            raise MonitorError(f"cannot connect to {self.address}: {_why(exc)}") from None
        return SocketLink(sock, self.address)


def open_link(target: str, baudrate: int = 115200) -> Link:
    """A link to ``target`` as ``Target.parse`` reads it."""
    return Target.parse(target, baudrate).open()


def _why(exc: Exception) -> str:
    """An OSError's text without its ``[Errno N]``."""
    return (exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)) or \
        type(exc).__name__


# -- the protocol's JSON mode ------------------------------------------------------------
class ConsoleClient:
    """Requests and replies in the console's JSON mode; streamed objects (watch, trace)
    are kept in ``streamed``."""

    def __init__(self, link: Link, clock: Callable[[], float] = time.monotonic) -> None:
        self.link = link
        self.clock = clock
        self._buf = b""
        self._pending: deque[dict[str, Any]] = deque()
        self.streamed: deque[dict[str, Any]] = deque(maxlen=LOG_LINES)
        #: an ``error ...`` text line after the last JSON line (what the console says as
        #: it closes a connection: idle timeout, too many sessions)
        self.last_error = ""

    def start(self, timeout: float = REQUEST_TIMEOUT_S) -> None:
        """Take over the console: drop a half-typed line and any stream (Ctrl-C), then
        switch this session to JSON."""
        self.link.send(b"\x03")
        reply = self.request("json on", timeout)
        if not reply.get("ok"):
            raise MonitorError(f"the console refused 'json on': {reply.get('error')}")

    def close(self) -> None:
        """Give the line back in text mode (a serial session outlives this client)."""
        try:
            self.link.send(b"\x03json off\r\n")
            end = self.clock() + 1.0  # read its text-mode "ok": leave the line clean
            while b"ok\r\n" not in self._buf and self.clock() < end:
                self._read(0.05)
        except (OSError, MonitorError):
            pass
        self.link.close()

    def abandon(self) -> None:
        """Close a link that broke (nothing is sent on it)."""
        try:
            self.link.close()
        except OSError:
            pass

    def send_line(self, line: str) -> None:
        """Send a line without waiting (an empty line stops a stream; it gets no reply)."""
        self.link.send(line.encode("utf-8") + b"\r\n")

    def request(self, line: str, timeout: float = REQUEST_TIMEOUT_S) -> dict[str, Any]:
        """Send one command; its reply object ({"ok": true, ...} or {"ok": false,
        "error": ...})."""
        self.send_line(line)
        end = self.clock() + timeout
        while True:
            self._parse()
            while self._pending:
                obj = self._pending.popleft()
                if "ok" in obj:
                    return obj
                self.streamed.append(obj)
            left = end - self.clock()
            if left <= 0:
                raise ConnectionLost(f"no reply to '{line}' within {timeout:g} s")
            self._read(min(left, 0.1))

    def poll_streams(self, timeout: float = 0.0) -> list[dict[str, Any]]:
        """Streamed objects that arrived (waiting up to ``timeout`` s for the first)."""
        if not self._pending:
            self._read(timeout)
            self._parse()
        out = [*self.streamed, *(obj for obj in self._pending if "ok" not in obj)]
        self.streamed.clear()
        self._pending.clear()
        return out

    def _read(self, timeout: float) -> None:
        data = self.link.recv(timeout)
        if data is None:
            self._parse()
            why = f" ({self.last_error})" if self.last_error else ""
            raise ConnectionLost(f"{self.link.name}: the controller closed the "
                                 f"connection{why}")
        self._buf += data

    def _parse(self) -> None:
        """Complete JSON lines of the buffer to ``_pending``; anything else (what a text
        mode session left on the line) is skipped."""
        *lines, self._buf = self._buf.split(b"\n")
        for raw in lines:
            text = raw.decode("utf-8", "replace").strip()
            try:
                obj = json.loads(text or "null")
            except ValueError:
                if text.startswith("error "):
                    self.last_error = text
                continue
            self.last_error = ""  # only what came after the last reply says why
            if isinstance(obj, dict):
                self._pending.append(obj)


# -- the connection, kept ------------------------------------------------------------------
class Connection:
    """The monitor's client of one controller: opened, and after a loss opened again
    with back-off (RETRY_MIN_S after the loss, then each wait doubled up to RETRY_MAX_S).

    ``clock`` (monotonic seconds) only schedules the tries."""

    def __init__(self, target: Target, clock: Callable[[], float] = time.monotonic) -> None:
        self.target = target
        self.clock = clock
        self.client: ConsoleClient | None = None
        #: why there is no client: the loss, then the last failed try ("" while connected)
        self.reason = ""
        #: failed tries since the loss
        self.attempts = 0
        #: when the next try is due (clock seconds)
        self.next_try = 0.0
        self._wait = RETRY_MIN_S

    def connect(self, timeout: float = REQUEST_TIMEOUT_S) -> ConsoleClient:
        """Open the link and take over the console (MonitorError if that fails)."""
        client = ConsoleClient(self.target.open(timeout))
        try:
            client.start(timeout)
        except MonitorError:
            client.abandon()
            raise
        self.client, self.reason, self.attempts = client, "", 0
        return client

    def lost(self, reason: str) -> None:
        """The client broke: drop it; the first try comes RETRY_MIN_S from now."""
        if self.client is not None:
            self.client.abandon()
            self.client = None
        self.reason, self.attempts = reason, 0
        self._wait = RETRY_MIN_S
        self.next_try = self.clock() + self._wait

    def retry(self) -> ConsoleClient | None:
        """The new client, when a try is due and succeeds; None otherwise."""
        if self.client is not None or self.clock() < self.next_try:
            return None
        try:
            return self.connect(RECONNECT_TIMEOUT_S)
        except MonitorError as exc:
            self.attempts += 1
            self.reason = str(exc)
            self._wait = min(self._wait * 2, RETRY_MAX_S)
            self.next_try = self.clock() + self._wait
            return None

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None


# -- the view -----------------------------------------------------------------------------
def reply_timeout(line: str, cycle_ms: float | None) -> float:
    """How long the reply to a typed command may take, seconds: REQUEST_TIMEOUT_S, and
    for ``cycle N`` as long again as the console waits for its scans (2 s plus twice
    their duration): a reply given up for lost makes the monitor connect again, and the
    end of the session that stepped halts the controller."""
    words = line.split()
    if not words or words[0].lower() != "cycle" or not cycle_ms:
        return REQUEST_TIMEOUT_S
    n = int(words[1]) if len(words) > 1 and words[1].isdigit() else 1
    return REQUEST_TIMEOUT_S + 2.0 + 2 * n * cycle_ms / 1000


@dataclass
class View:
    """What the screen shows, from the replies to ``status``, ``stats`` and ``get``."""

    target: str = ""
    status: dict[str, Any] = field(default_factory=dict)
    stats: dict[str, Any] = field(default_factory=dict)
    values: dict[str, Any] = field(default_factory=dict)
    roles: dict[str, str] = field(default_factory=dict)
    #: the I/O list of the names shown: name -> unit symbol
    units: dict[str, str] = field(default_factory=dict)
    forced_names: set[str] = field(default_factory=set)
    log: deque[str] = field(default_factory=lambda: deque(maxlen=LOG_LINES))
    problem: str = ""
    updated: float = 0.0
    #: refreshes done
    refreshes: int = 0
    #: the connection is lost: why, and when the next try is (None: connected)
    offline: str | None = None
    #: when the controller started (monotonic seconds, earliest and latest: ``status``
    #: gives its uptime, sampled between sending it and its reply), and its scan count
    started: tuple[float, float] | None = None
    scans: int = 0
    clock: Callable[[], float] = time.monotonic

    def refresh(self, client: ConsoleClient) -> None:
        """Ask for everything the view shows (three commands, three scan boundaries)."""
        sent = self.clock()
        st = client.request("status")
        replied = self.clock()
        sx = client.request("stats")
        if not st.get("ok") or not sx.get("ok"):
            self.problem = str(st.get("error") or sx.get("error"))
            return
        self._note_start(st, sent, replied)
        self.status, self.stats = st, sx["stats"]
        instances = list(st.get("steps", {}))
        if instances:
            got = client.request("get " + " ".join(instances))
            if got.get("ok"):
                self.values, self.roles = got["values"], got.get("roles", {})
                self.forced_names = set(got.get("forced", ()))
                self.units = {n: m["symbol"] for n, m in got.get("meanings", {}).items()
                              if "symbol" in m and self.roles.get(n) != "step time"}
        self.problem = ""
        self.updated = time.time()
        self.refreshes += 1

    def _note_start(self, st: dict[str, Any], sent: float, replied: float) -> None:
        """Say so when the controller is a new run of it: its start moved (the scan
        count going down is the same sign, for a restart sooner than RESTART_SLACK_S)."""
        up, scans = float(st.get("uptime_s", 0.0)), int(st.get("scans", 0))
        if up <= 0.0:
            return  # not scanning yet: nothing to compare
        lo, hi = sent - up, replied - up
        was = self.started
        if was is not None and (scans < self.scans or lo > was[1] + RESTART_SLACK_S
                                or hi < was[0] - RESTART_SLACK_S):
            self.log.append(f"{_now()} controller restarted: up {up:.1f} s, {scans} scans "
                            f"(was {self.scans} scans)")
            self.values, self.roles, self.forced_names = {}, {}, set()
        elif was is not None and was[1] - was[0] < hi - lo:
            lo, hi = was  # the same run: keep the closer estimate
        self.started, self.scans = (lo, hi), scans

    def lost(self, reason: str) -> None:
        """The connection broke (the view keeps what it last showed)."""
        self.log.append(f"{_now()} connection lost: {reason}")
        self.offline = reason

    def connected(self, target: str) -> None:
        self.log.append(f"{_now()} connected again to {target}")
        self.offline = None
        self.problem = ""

    def command(self, client: ConsoleClient, line: str) -> dict[str, Any]:
        """A command typed at the prompt; its reply goes to the log."""
        self.log.append(f"> {line}")
        reply = client.request(line, reply_timeout(line, self.status.get("cycle_ms")))
        if reply.get("ok"):
            self.log.extend(reply.get("text", []))
            self.log.append("ok")
        else:
            self.log.append(f"error {reply.get('error')}")
        return reply

    def stream(self, objs: list[dict[str, Any]]) -> None:
        for obj in objs:
            kind = "watch" if "watch" in obj else "trace" if "trace" in obj else "?"
            values = obj.get(kind, {})
            head = kind + (f" {obj['scan']}" if "scan" in obj else "")
            self.log.append(head + ": " + "  ".join(f"{k}={v}" for k, v in values.items()))

    def lines(self, width: int = 100) -> list[str]:
        """The view as text lines (the top of the screen)."""
        st, sx = self.status, self.stats
        out = []
        state = str(st.get("state", "?")).upper()
        if st.get("fault"):
            state += f" ({st['fault']})"
        if self.offline is not None:
            seen = time.strftime("%H:%M:%S", time.localtime(self.updated)) if self.updated \
                else "never"
            out.append(f"softplc monitor {self.target}   connection lost")
            out.append(f"{self.offline}; q or Ctrl-C leaves. Last seen {seen}: "
                       f"state {state}")
        else:
            out.append(f"softplc monitor {self.target}   state {state}")
        if st:
            out.append(f"cycle {st.get('cycle_ms', 0):g} ms   scans {st.get('scans', 0)}   "
                       f"uptime {st.get('uptime_s', 0):.1f} s   "
                       f"overruns {sx.get('overruns', 0)}")
        # what holds the charts or the outputs (a pause, an instance's SFCPause...),
        # but the condition the state line names already
        out += [f"inhibit  {x}" for x in st.get("inhibits", [])
                if not x.startswith(f"{st.get('state')}: ")]
        for key, label in (("scan_us", "scan    "), ("lateness_us", "lateness")):
            s = sx.get(key)
            if s:
                out.append(f"{label} us  last {s['last']:.0f}  mean {s['mean']:.0f}  "
                           f"p99 {s['p99']:.0f}  max {s['max']:.0f}")
        drivers = sx.get("drivers", {})
        if drivers:
            out.append("drivers  " + "  ".join(
                f"{n} {d['health']}" + (f" ({d['reason']})" if d.get("reason") else "")
                for n, d in drivers.items()))
        said = st.get("descriptions", {})
        for inst, steps in st.get("steps", {}).items():
            out.append("")
            out.append(f"{inst}  {' '.join(steps) or '(no active step)'}")
            # what the plant file says of the instance and its active steps
            about = [said[inst]] if inst in said else []
            about += [f"{s}: {said[f'{inst}.{s}']}" for s in steps if f"{inst}.{s}" in said]
            if about:
                out.append("  " + "; ".join(about))
            for role, label in (("input", "in "), ("output", "out"), ("memory", "mem")):
                cells = [self._cell(n) for n, r in self.roles.items()
                         if r == role and n.startswith(inst + ".")]
                if cells:
                    out += _wrap(f"  {label} ", cells, width)
        for inst, step in st.get("errors", {}).items():
            out.append(f"SFCError {inst}: step {step}")
        forced = st.get("forced", {})
        out.append("")
        out.append("forced   " + (", ".join(f"{k}={v}" for k, v in forced.items())
                                  if forced else "-") + "      (* = forced)")
        out += alarm_lines(st.get("alarms", []))
        for f in st.get("faults", [])[-3:]:
            when = time.strftime("%H:%M:%S", time.localtime(f["time"]))
            out.append(f"fault {when} {f['reason']}")
        if self.problem:
            out.append(f"!! {self.problem}")
        return [row for x in out for row in fold(x, width)]

    def _cell(self, name: str) -> str:
        short = name.split(".", 1)[1]
        mark = "*" if name in self.forced_names else " "
        unit = self.units.get(name, "")
        return f"{short}={self.values.get(name, '?')}{unit}{mark}"


def _now() -> str:
    return time.strftime("%H:%M:%S")


def fold(text: str, width: int, indent: str = "  ") -> list[str]:
    """``text`` in rows of at most ``width`` characters (at least 20): broken at the last
    space of a row when it is in the row's second half, else at the width; each further
    row begins with ``indent``."""
    width = max(width, 20)
    out, head, rest = [], "", text
    while len(head) + len(rest) > width:
        room = width - len(head)
        cut = rest.rfind(" ", room // 2, room + 1)
        if cut > 0:
            out.append(head + rest[:cut].rstrip())
            rest = rest[cut + 1:]
        else:
            out.append(head + rest[:room])
            rest = rest[room:]
        head = indent
    out.append(head + rest)
    return out


def _wrap(head: str, cells: list[str], width: int) -> list[str]:
    out, cur = [], head
    for c in cells:
        if len(cur) + len(c) + 2 > width and cur.strip():
            out.append(cur)
            cur = " " * len(head)
        cur += c + "  "
    out.append(cur.rstrip())
    return out


# -- the screen's logic ------------------------------------------------------------------
#: what typed alone on the prompt leaves the monitor
QUIT = ("q", "quit", "exit")


class Monitor:
    """What the screen does, without the screen: keeps the view fresh, runs what is typed,
    shows streams, and survives the loss of the controller (``Connection``)."""

    def __init__(self, target: Target, view: View, refresh_s: float = REFRESH_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.connection = Connection(target, clock)
        self.view = view
        self.refresh_s = refresh_s
        self.clock = clock
        #: a ``watch`` or ``trace on`` is streaming: no refresh until it stops
        self.streaming = False
        #: an ``unlock`` worked in this session (a new session is locked again)
        self.unlocked = False
        self._next_refresh = 0.0

    def connect(self) -> None:
        """The first connection (MonitorError when the controller cannot be reached)."""
        self.connection.connect()

    def tick(self) -> None:
        """One round: a try to connect again when due, else a refresh or the streams."""
        conn = self.connection
        client = conn.client
        if client is None:
            client = conn.retry()
            if client is None:
                self.view.offline = self._offline()
                return
            self.view.connected(conn.target.address)
            if self.unlocked:
                self.view.log.append("(a new session: locked again, type unlock PIN)")
                self.unlocked = False
            self._next_refresh = 0.0
        now = self.clock()
        try:
            if self.streaming:
                self.view.stream(client.poll_streams(0.0))
            elif now >= self._next_refresh:
                self._next_refresh = now + self.refresh_s
                self.view.refresh(client)
        except MonitorError as exc:
            self._lost(exc)

    def enter(self, line: str) -> bool:
        """A line typed at the prompt; False: leave."""
        cmd = line.strip()
        if cmd in QUIT:
            return False
        client = self.connection.client
        if client is None:
            if cmd:
                self.view.log += [f"> {cmd}", "(not connected: not sent)"]
            return True
        try:
            if self.streaming:
                self.streaming = False
                if not cmd:
                    client.send_line("")  # stops the stream; no reply
                    self.view.log.append("(stream stopped)")
                    return True
            if cmd:
                reply = self.view.command(client, cmd)
                words = cmd.split()
                ok = bool(reply.get("ok"))
                self.streaming = ok and (words[0] == "watch" or words[:2] == ["trace", "on"])
                if ok and words[0] in ("unlock", "lock"):
                    self.unlocked = words[0] == "unlock"
                self._next_refresh = 0.0
        except MonitorError as exc:
            self._lost(exc)
        return True

    def _lost(self, exc: MonitorError) -> None:
        if self.streaming:
            self.view.log.append("(stream ended)")
            self.streaming = False
        self.view.lost(str(exc))
        self.connection.lost(str(exc))
        self.view.offline = self._offline()

    def _offline(self) -> str:
        conn = self.connection
        wait = max(conn.next_try - self.clock(), 0.0)
        tried = f"try {conn.attempts}: {conn.reason}; " if conn.attempts else ""
        return f"{tried}trying again in {wait:.1f} s"

    def close(self) -> None:
        self.connection.close()


# -- the screen ------------------------------------------------------------------------------
def run_screen(mon: Monitor) -> int:
    """The live view and its prompt until ``q``/``quit`` (or Ctrl-C); ``q`` alone leaves
    at once while the controller is away."""
    import curses

    def main(scr: Any) -> int:
        curses.curs_set(1)
        scr.timeout(50)
        scr.keypad(True)
        line = ""
        while True:
            mon.tick()
            _draw(scr, mon.view, line, mon.streaming)
            try:
                ch = scr.get_wch()
            except curses.error:
                continue
            if ch == "\x03" or (ch in ("q", "Q") and not line
                                 and mon.connection.client is None):
                return 0
            if ch in ("\n", "\r", curses.KEY_ENTER):
                cmd, line = line, ""
                if not mon.enter(cmd):
                    return 0
            elif ch in (curses.KEY_BACKSPACE, "\b", "\x7f"):
                line = line[:-1]
            elif ch == "\x15":
                line = ""
            elif ch == curses.KEY_RESIZE:
                scr.clear()
            elif isinstance(ch, str) and ch.isprintable():
                line += ch

    try:
        return int(curses.wrapper(main))
    except KeyboardInterrupt:
        return 0


def _draw(scr: Any, view: View, line: str, streaming: bool) -> None:
    import curses

    h, w = scr.getmaxyx()
    scr.erase()
    top = view.lines(max(w - 1, 20))
    room_for_log = max(h - len(top) - 3, 0)
    rows = top[:max(h - 3, 0)]
    rows.append("-" * (w - 1) + "")
    if room_for_log:
        # the newest replies, each folded to the width: as many as fit
        log: list[str] = []
        for entry in reversed(view.log):
            log[:0] = fold(entry, max(w - 1, 20))
            if len(log) >= room_for_log:
                break
        rows += log[-room_for_log:]
    for y, text in enumerate(rows[:h - 1]):
        try:
            scr.addnstr(y, 0, text, w - 1)
        except curses.error:
            pass
    hint = "(streaming: Enter stops) " if streaming else ""
    prompt = f"{hint}> {line}"
    if len(prompt) > w - 1:  # a long line being typed: its end, where the cursor is
        prompt = prompt[len(prompt) - (w - 1):]
    try:
        scr.addnstr(h - 1, 0, prompt, w - 1)
        scr.move(h - 1, min(len(prompt), w - 1))
    except curses.error:
        pass
    scr.refresh()


# -- command line ------------------------------------------------------------------------
def cmd_monitor(args: argparse.Namespace) -> int:
    try:
        address = expand(args.target, Loc("PORT|SOCKET", 1, 1))
    except SourceError as exc:
        sys.stderr.write(f"softplc monitor: error: {exc.message}\n")
        return 2
    interval = args.interval
    if interval is not None and interval < MIN_REFRESH_S:
        sys.stderr.write(f"softplc monitor: error: --interval {interval:g} is under "
                         f"{MIN_REFRESH_S:g} s (the console runs at most 50 lines/s)\n")
        return 2
    try:
        target = Target.parse(address, args.baudrate)
        view = View(target=address)
        if args.once:
            client = ConsoleClient(target.open())
            try:
                client.start()
                view.refresh(client)
            finally:
                client.close()
            sys.stdout.write("\n".join(view.lines(args.width)) + "\n")
            return 0 if not view.problem else 1
        if interval is None:
            interval = SERIAL_REFRESH_S if target.kind is LinkKind.SERIAL else REFRESH_S
        mon = Monitor(target, view, interval)
        mon.connect()
        try:
            return run_screen(mon)
        finally:
            mon.close()
    except MonitorError as exc:
        sys.stderr.write(f"softplc monitor: error: {exc}\n")
        return 1


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    m = sub.add_parser("monitor", help="live view of a running controller, with a command "
                                       "prompt",
                       description="Watch a running controller through its console: a Unix "
                                   "socket path, HOST:PORT (TCP), or a serial port. Type "
                                   "console commands at the prompt; 'q' leaves. If the "
                                   "controller goes away, the monitor waits for it and "
                                   "connects again.")
    m.add_argument("target", metavar="PORT|SOCKET",
                   help="/run/softplc/console.sock, '${RUNTIME_DIR}/drawer.sock' (quoted), "
                        "127.0.0.1:5020 or /dev/ttyUSB0")
    m.add_argument("--baudrate", type=int, default=115200, help="serial speed (115200)")
    m.add_argument("--interval", type=float, metavar="S",
                   help=f"refresh period in seconds ({REFRESH_S}; {SERIAL_REFRESH_S} on a "
                        f"serial line; at least {MIN_REFRESH_S})")
    m.add_argument("--once", action="store_true",
                   help="print the view once as text and exit (scripts, dumb terminals)")
    m.add_argument("--width", type=int, default=100, help="line width for --once")
    m.set_defaults(func=cmd_monitor)
