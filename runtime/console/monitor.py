"""``softplc monitor PORT|SOCKET``: a live terminal view of a running controller.

The laptop side of the console: it speaks the JSON mode of the console protocol
(console.md) over a Unix socket, a 127.0.0.1 TCP port or a serial line, refreshes a view
of the plant a few times a second (state, active steps per instance, inputs and outputs
with forced marks, cycle statistics, last faults) and has a prompt for console commands.

Three layers, so the first two are testable without a terminal: ``Link`` (bytes),
``ConsoleClient`` (JSON requests and replies), ``View`` (what the screen shows, as text
lines); ``run_screen`` draws the view with curses from the standard library, which is
on every Linux laptop and needs nothing more for a few lines of text and a prompt.
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
from typing import Any, Protocol

from runtime.errors import SoftplcError

log = logging.getLogger(__name__)

#: how long a command may take before the controller is considered silent, seconds
REQUEST_TIMEOUT_S = 5.0
#: view refresh period, seconds; slower on a serial line, where a refresh (~2.5 kB) takes
#: about 0.2 s at 115200 baud
REFRESH_S = 0.25
SERIAL_REFRESH_S = 1.0
#: reply lines kept under the view
LOG_LINES = 200

_TCP = re.compile(r"^(?:\[?[\w.:-]*\]?):(\d+)$")


class MonitorError(SoftplcError):
    """The controller cannot be reached or stopped answering.

    Examples: the socket path does not exist; the serial port is held by another
    program; no reply within REQUEST_TIMEOUT_S."""


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
        self.sock.settimeout(REQUEST_TIMEOUT_S)
        self.sock.sendall(data)

    def recv(self, timeout: float) -> bytes | None:
        self.sock.settimeout(max(timeout, 0.001))
        try:
            return self.sock.recv(65536) or None
        except TimeoutError:
            return b""

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
        self.port.write(data)

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


def open_link(target: str, baudrate: int = 115200) -> Link:
    """``/run/softplc/console.sock`` (Unix socket), ``HOST:PORT`` (TCP) or a serial device."""
    try:
        mode = os.stat(target).st_mode
    except OSError:
        mode = None
    if mode is not None and stat.S_ISSOCK(mode):
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.connect(target)
        except OSError as exc:
            sock.close()
            raise MonitorError(f"cannot connect to {target}: {exc}") from None
        return SocketLink(sock, target)
    m = _TCP.match(target)
    if mode is None and m:
        host = target[:m.start(1) - 1].strip("[]") or "127.0.0.1"
        try:
            sock = socket.create_connection((host, int(m.group(1))), timeout=REQUEST_TIMEOUT_S)
        except OSError as exc:
            raise MonitorError(f"cannot connect to {target}: {exc}") from None
        return SocketLink(sock, target)
    if mode is None:
        raise MonitorError(f"{target}: no such socket or serial port (or HOST:PORT for TCP)")
    return SerialLink(target, baudrate)


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

    def start(self) -> None:
        """Take over the console: drop a half-typed line and any stream (Ctrl-C), then
        switch this session to JSON."""
        self.link.send(b"\x03")
        reply = self.request("json on")
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
                raise MonitorError(f"no reply to '{line}' within {timeout:g} s")
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
            raise MonitorError(f"{self.link.name}: the controller closed the connection")
        self._buf += data

    def _parse(self) -> None:
        """Complete JSON lines of the buffer to ``_pending``; anything else (what a text
        mode session left on the line) is skipped."""
        *lines, self._buf = self._buf.split(b"\n")
        for raw in lines:
            try:
                obj = json.loads(raw.decode("utf-8", "replace").strip() or "null")
            except ValueError:
                continue
            if isinstance(obj, dict):
                self._pending.append(obj)


# -- the view -----------------------------------------------------------------------------
@dataclass
class View:
    """What the screen shows, from the replies to ``status``, ``stats`` and ``get``."""

    target: str = ""
    status: dict[str, Any] = field(default_factory=dict)
    stats: dict[str, Any] = field(default_factory=dict)
    values: dict[str, Any] = field(default_factory=dict)
    roles: dict[str, str] = field(default_factory=dict)
    forced_names: set[str] = field(default_factory=set)
    log: deque[str] = field(default_factory=lambda: deque(maxlen=LOG_LINES))
    problem: str = ""
    updated: float = 0.0

    def refresh(self, client: ConsoleClient) -> None:
        """Ask for everything the view shows (three commands, three scan boundaries)."""
        st = client.request("status")
        sx = client.request("stats")
        if not st.get("ok") or not sx.get("ok"):
            self.problem = str(st.get("error") or sx.get("error"))
            return
        self.status, self.stats = st, sx["stats"]
        instances = list(st.get("steps", {}))
        if instances:
            got = client.request("get " + " ".join(instances))
            if got.get("ok"):
                self.values, self.roles = got["values"], got.get("roles", {})
                self.forced_names = set(got.get("forced", ()))
        self.problem = ""
        self.updated = time.time()

    def command(self, client: ConsoleClient, line: str) -> dict[str, Any]:
        """A command typed at the prompt; its reply goes to the log."""
        self.log.append(f"> {line}")
        reply = client.request(line)
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
        for inst, steps in st.get("steps", {}).items():
            out.append("")
            out.append(f"{inst}  {' '.join(steps) or '(no active step)'}")
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
        for f in st.get("faults", [])[-3:]:
            when = time.strftime("%H:%M:%S", time.localtime(f["time"]))
            out.append(f"fault {when} {f['reason']}")
        if self.problem:
            out.append(f"!! {self.problem}")
        return [x[:width] for x in out]

    def _cell(self, name: str) -> str:
        short = name.split(".", 1)[1]
        mark = "*" if name in self.forced_names else " "
        return f"{short}={self.values.get(name, '?')}{mark}"


def _wrap(head: str, cells: list[str], width: int) -> list[str]:
    out, cur = [], head
    for c in cells:
        if len(cur) + len(c) + 2 > width and cur.strip():
            out.append(cur)
            cur = " " * len(head)
        cur += c + "  "
    out.append(cur.rstrip())
    return out


# -- the screen ------------------------------------------------------------------------------
def run_screen(client: ConsoleClient, view: View, refresh_s: float = REFRESH_S) -> int:
    """The live view and its prompt until ``quit`` (or Ctrl-C)."""
    import curses

    def main(scr: Any) -> int:
        curses.curs_set(1)
        scr.timeout(50)
        scr.keypad(True)
        line = ""
        streaming = False
        next_refresh = 0.0
        while True:
            now = time.monotonic()
            try:
                if streaming:
                    view.stream(client.poll_streams(0.0))
                elif now >= next_refresh:
                    view.refresh(client)
                    next_refresh = now + refresh_s
            except MonitorError as exc:
                view.problem = str(exc)
                next_refresh = now + 1.0
            _draw(scr, view, line, streaming)
            try:
                ch = scr.get_wch()
            except curses.error:
                continue
            if ch in ("\n", "\r", curses.KEY_ENTER):
                cmd, line = line.strip(), ""
                if cmd in ("quit", "exit"):
                    return 0
                try:
                    if streaming:
                        streaming = False
                        if not cmd:
                            client.send_line("")  # stops the stream; no reply
                            view.log.append("(stream stopped)")
                            continue
                    if cmd:
                        reply = view.command(client, cmd)
                        words = cmd.split()
                        streaming = bool(reply.get("ok")) and (
                            words[0] == "watch" or words[:2] == ["trace", "on"])
                        next_refresh = 0.0
                except MonitorError as exc:
                    view.problem = str(exc)
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
    rows += list(view.log)[-room_for_log:] if room_for_log else []
    for y, text in enumerate(rows[:h - 1]):
        try:
            scr.addnstr(y, 0, text, w - 1)
        except curses.error:
            pass
    hint = "(streaming: Enter stops) " if streaming else ""
    prompt = f"{hint}> {line}"
    try:
        scr.addnstr(h - 1, 0, prompt, w - 1)
        scr.move(h - 1, min(len(prompt), w - 1))
    except curses.error:
        pass
    scr.refresh()


# -- command line ------------------------------------------------------------------------
def cmd_monitor(args: argparse.Namespace) -> int:
    try:
        link = open_link(args.target, args.baudrate)
        client = ConsoleClient(link)
        try:
            client.start()
            view = View(target=args.target)
            if args.once:
                view.refresh(client)
                sys.stdout.write("\n".join(view.lines(args.width)) + "\n")
                return 0 if not view.problem else 1
            interval = args.interval
            if interval is None:
                interval = SERIAL_REFRESH_S if isinstance(link, SerialLink) else REFRESH_S
            return run_screen(client, view, interval)
        finally:
            client.close()
    except MonitorError as exc:
        sys.stderr.write(f"softplc monitor: error: {exc}\n")
        return 1


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    m = sub.add_parser("monitor", help="live view of a running controller, with a command "
                                       "prompt",
                       description="Watch a running controller through its console: a Unix "
                                   "socket path, HOST:PORT (TCP), or a serial port. Type "
                                   "console commands at the prompt; 'quit' leaves.")
    m.add_argument("target", metavar="PORT|SOCKET",
                   help="/run/softplc/console.sock, 127.0.0.1:5020 or /dev/ttyUSB0")
    m.add_argument("--baudrate", type=int, default=115200, help="serial speed (115200)")
    m.add_argument("--interval", type=float, metavar="S",
                   help=f"refresh period in seconds ({REFRESH_S}; {SERIAL_REFRESH_S} on a "
                        "serial line)")
    m.add_argument("--once", action="store_true",
                   help="print the view once as text and exit (scripts, dumb terminals)")
    m.add_argument("--width", type=int, default=100, help="line width for --once")
    m.set_defaults(func=cmd_monitor)
