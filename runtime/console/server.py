"""Console transports: serial line (pyserial), Unix socket, TCP on 127.0.0.1 only.

Every socket connection is served by ONE thread with ``selectors`` (so whatever the number
of clients, a single console thread competes with the scan thread for the GIL), and each
serial port by a thread of its own. None of this runs in the scan thread: plant access goes
through Controller.call.

No client can starve the scan (docs/console.md, "Transports and limits"):
- console work (lines, streams) stops QUIET_BEFORE_S (at most half a cycle) before each
  scan is due, until it has ended (ScanWindow): the scan thread wakes to a free GIL;
- the console threads together use at most CPU_SHARE of a processor (each thread's own
  processor time, spent from the window's budget): a flood of costly requests waits;
- lines are taken one at a time per connection, round-robin;
- each session may run LINES_PER_S lines a second (bursts of BURST_LINES); a line over
  that gets ``error too many requests`` and is not run;
- the daemon shortens the interpreter's GIL switch interval (daemon.gil_switch_s: 0.5 ms,
  a tenth of a shorter cycle), so a scan waits about that long at most for a console
  thread holding the GIL.

Limits: MAX_CONNECTIONS per socket or TCP port (one more gets an error line and is
closed); a connection neither trusted nor unlocked that sends nothing for IDLE_TIMEOUT_S
is closed, and when every place is taken, the one idle longest (over EVICT_IDLE_S) makes
room. A serial port always has its own session; one that fails or hangs up (POLLHUP on the
fd, or its carrier detect line dropping) ends its session and is opened again, so the next
person on the line gets a fresh, locked session.
"""

from __future__ import annotations

import json
import logging
import re
import select
import selectors
import socket
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

from runtime.console.service import ConsoleService
from runtime.console.session import Session
from runtime.controller.paths import remove_socket, unix_listener
from runtime.controller.window import (  # noqa: F401 - the console's names for them
    CPU_BURST_S,
    CPU_SHARE,
    QUIET_BEFORE_S,
    ROUND_BUDGET_S,
    STALE_S,
    WINDOW_POLL_S,
    WINDOW_SHARE,
    CpuMeter,
    ScanWindow,
    Slot,
)
from runtime.language.model import ConsoleEntry

log = logging.getLogger(__name__)

#: how long the serving loops wait for input before polling streams and timers, seconds
POLL_S = 0.05
#: ... and at most this long while a session's command is pending (``cycle N``), seconds
PENDING_POLL_S = 0.01
#: bytes taken from a connection per read
READ_CHUNK = 1024
#: bytes received and not yet handled, per connection, before reading from it stops
IN_MAX = 8192
#: reply bytes not yet taken by the peer, per connection, before its lines wait
OUT_MAX = 65536
#: a peer that takes nothing for this long loses the output (serial) or the connection
#: (socket), seconds
SEND_TIMEOUT_S = 5.0
#: connections served at once on one socket or TCP port
MAX_CONNECTIONS = 8
#: a connection neither trusted nor unlocked is closed after this long without input, s
IDLE_TIMEOUT_S = 60.0
#: when every place is taken, such a connection idle this long makes room for a new one, s
EVICT_IDLE_S = 10.0
#: lines a session may run per second, and at once after a pause
LINES_PER_S = 50.0
BURST_LINES = 100
#: a serial port that cannot be opened is tried again after this delay, doubling up to
#: the maximum, seconds
REOPEN_MIN_S = 0.5
REOPEN_MAX_S = 10.0

_LINE_END = re.compile(rb"\r\n?|\n|\x03")


class Throttle:
    """A token bucket: ``rate`` lines a second, ``burst`` at once."""

    def __init__(self, clock: Callable[[], float] = time.monotonic,
                 rate: float = LINES_PER_S, burst: int = BURST_LINES) -> None:
        self.clock = clock
        self.rate = rate
        self.burst = float(burst)
        self.tokens = float(burst)
        self.last = clock()

    def take(self) -> bool:
        """One line may run now (a token is taken), or not."""
        now = self.clock()
        self.tokens = min(self.burst, self.tokens + (now - self.last) * self.rate)
        self.last = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False

    def next_token(self) -> float:
        """When the next token comes (clock seconds)."""
        return self.last + max(0.0, 1.0 - self.tokens) / self.rate


class Line:
    """One connection's input queue in front of its Session: whole lines are handed over
    one at a time (``step``), each paid with a token of its Throttle; the reply bytes
    wait in ``out`` for the transport. While the session's command is pending (``cycle
    N``) its lines wait; a Ctrl-C among them stops that command."""

    def __init__(self, session: Session, clock: Callable[[], float],
                 throttle: Throttle | None = None) -> None:
        self.session = session
        self.clock = clock
        #: None: every line runs (a serial line, limited by its speed)
        self.throttle = throttle
        self.inbuf = bytearray()
        self.out = bytearray()
        #: clock seconds since which the session has given no command (Session.last_command:
        #: empty lines and Ctrl-C do not count) while neither trusted nor unlocked (its
        #: idle time counts from there)
        self.idle_since = clock()
        #: monotonic seconds before which no line is handed over (0: none)
        self.held_until = 0.0
        #: bytes of a line were handed over without its end (the framer holds them)
        self._partial = False

    def receive(self, data: bytes) -> None:
        self.inbuf += data

    def ready(self) -> bool:
        """A line (or a stretch of a long line) is waiting, the peer takes replies, and
        the session is not waiting for its next token after a refused line; or the
        session's pending command can be finished (done, or a Ctrl-C came)."""
        if len(self.out) >= OUT_MAX:
            return False
        pending = self.session.pending
        if pending is not None:
            return pending.ready() or b"\x03" in self.inbuf
        return bool(self.inbuf) and (self.held_until == 0.0 or self._unheld())

    def _unheld(self) -> bool:
        if time.monotonic() < self.held_until:
            return False
        self.held_until = 0.0
        return True

    def step(self) -> None:
        """Hand the next line over (or what there is of it) and queue the reply; or the
        reply of the session's pending command (stopped first if a Ctrl-C came: the
        Ctrl-C itself stays in the input, where it then drops a half-typed line)."""
        session = self.session
        if session.pending is not None:
            if not session.pending.ready():
                session.pending.interrupt()
            self._send(session.finish())
        else:
            self._take_line()
        # only a command is activity: an empty line or a Ctrl-C does not move this
        self.idle_since = max(self.idle_since, session.last_command)

    def _take_line(self) -> None:
        m = _LINE_END.search(self.inbuf)
        if m is None:  # half a line: the framer keeps it (and drops it when overlong)
            chunk, self.inbuf = bytes(self.inbuf), bytearray()
            self._partial = True
            self._send(self.session.feed(chunk))
            return
        chunk = bytes(self.inbuf[:m.end()])
        del self.inbuf[:m.end()]
        if m.group() == b"\x03" or not (self._partial or chunk[:m.start()].strip()):
            self._partial = False  # Ctrl-C, or an empty line: nothing runs
            self._send(self.session.feed(chunk))
            return
        self._partial = False
        if self.throttle is None or self.throttle.take():
            self._send(self.session.feed(chunk))
            return
        self.session.feed(b"\x03")  # the line is dropped, as Ctrl-C would drop it
        # its next line waits for the next token: refusals come at the rate, not as fast
        # as the peer can send (each costs console time too)
        self.held_until = self.throttle.next_token()
        reason = f"too many requests (more than {LINES_PER_S:g} lines/s): line ignored"
        self._send([json.dumps({"ok": False, "error": reason}) if self.session.json
                    else f"error {reason}"])

    def poll(self, until: float) -> bool:
        """The session's streamed lines, unless the peer is behind with its replies; a
        stream's images compared only until ``until`` (monotonic seconds: the window's
        close). Whether the poll is done (False: a stream has images left for the next
        one)."""
        if len(self.out) >= OUT_MAX:
            return True  # the peer is behind: its stream's images wait in its queue
        self._send(self.session.poll(lambda: time.monotonic() < until))
        stream = self.session.stream
        return stream is None or not stream.behind

    def say(self, line: str) -> None:
        self._send([line])

    def _send(self, lines: list[str]) -> None:
        if lines:
            self.out += ("\r\n".join(lines) + "\r\n").encode("utf-8")


def peer_of(conn: socket.socket, kind: str) -> str:
    """Who is at the other end: ``uid:N`` on a Unix socket (SO_PEERCRED), ``tcp``."""
    if kind == "socket":
        try:
            cred = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED,
                                   struct.calcsize("3i"))
            return f"uid:{struct.unpack('3i', cred)[1]}"
        except OSError:
            return "uid:?"
    return "tcp"


class _Conn:
    """A socket connection served by the selector loop."""

    def __init__(self, sock: socket.socket, line: Line, address: str) -> None:
        self.sock = sock
        self.line = line
        self.address = address
        #: monotonic seconds since the peer last took bytes (or had none to take)
        self.drained = time.monotonic()
        self.events = 0


class _Listener:
    def __init__(self, sock: socket.socket, entry: ConsoleEntry, address: str) -> None:
        self.sock = sock
        self.entry = entry
        self.address = address


class ConsoleServer:
    """Serves the console on every configured entry until ``stop()``."""

    def __init__(self, service: ConsoleService, entries: list[ConsoleEntry]) -> None:
        self.service = service
        self.entries = entries
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._listeners: list[_Listener] = []
        self._socket_paths: list[str] = []
        self._lock = threading.Lock()
        self._conns: list[_Conn] = []
        #: the connections a tick has still to poll (``_tick``)
        self._unpolled: list[_Conn] = []
        self._selector: selectors.BaseSelector | None = None
        ctl = service.controller
        self.window = ScanWindow(ctl.plant.cycle_ns / 1e9, due=ctl.next_scan_due)
        #: where the console is served: serial ports, socket paths, 127.0.0.1:PORT
        self.addresses: list[str] = []
        #: the sessions open now
        self.sessions: list[Session] = []

    @property
    def clock(self) -> Callable[[], float]:
        """Monotonic seconds for idle times and rates: the service's (tests step it)."""
        return self.service.clock

    def start(self) -> None:
        """Open every listener (errors raised here) and start the serving threads."""
        if self.entries:
            self.service.controller.add_listener(self.window.on_scan)
            self.service.pause = self.window.pause
        for e in self.entries:
            if e.kind == "serial":
                self.addresses.append(e.address)
                self._spawn(self._serve_serial, e, name=f"console-serial-{e.address}")
            else:
                srv = self._listen(e)
                self._listeners.append(_Listener(srv, e, self.addresses[-1]))
        if self._listeners:
            sel = selectors.DefaultSelector()
            for lst in self._listeners:
                sel.register(lst.sock, selectors.EVENT_READ, lst)
            self._selector = sel
            self._spawn(self._serve_sockets, sel, name="console-sockets")

    def _spawn(self, fn: Callable[..., None], *args: object, name: str) -> None:
        t = threading.Thread(target=fn, args=args, name=name, daemon=True)
        with self._lock:
            self._threads.append(t)
        t.start()

    def _listen(self, e: ConsoleEntry) -> socket.socket:
        if e.kind == "socket":
            path = e.address
            srv = unix_listener(path)
            self._socket_paths.append(path)
            self.addresses.append(path)
        else:
            host, port = e.address.rsplit(":", 1)
            if host != "127.0.0.1":  # console.md: TCP is bound to 127.0.0.1 only
                raise ValueError(f"the TCP console binds to 127.0.0.1 only, not {host}")
            srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            srv.bind((host, int(port)))
            self.addresses.append(f"{host}:{srv.getsockname()[1]}")
        srv.listen(MAX_CONNECTIONS)
        srv.setblocking(False)
        log.info("console listening on %s%s", self.addresses[-1],
                 " (trusted)" if e.trusted else "")
        return srv

    def idle_s(self, session: Session) -> float | None:
        """How long a socket session has been idle while neither trusted nor unlocked
        (clock seconds, as the server last saw it); None if no socket serves it."""
        for c in list(self._conns):
            if c.line.session is session:
                return self.clock() - c.line.idle_since
        return None

    def _opened(self, session: Session) -> None:
        with self._lock:
            self.sessions.append(session)

    def _closed(self, session: Session, reason: str) -> None:
        """End ``session``: closed (its streams and forces), then out of ``sessions``."""
        try:
            session.close(reason)
        finally:
            with self._lock:
                self.sessions.remove(session)
        log.info("console session %s closed: %s", session.name, reason)

    # -- sockets: one thread, one selector ---------------------------------------------
    def _serve_sockets(self, sel: selectors.BaseSelector) -> None:
        """Everything happens inside the windows (ScanWindow.slot): reading, lines,
        replies, timers. Between them the thread sleeps with the GIL free, woken by the
        end of the next scan, never by a client: bytes that arrive meanwhile wait in the
        kernel. Only a server with nothing to do waits for input across windows, and
        then waits for a window before it reads it."""
        meter = self.window.meter()
        due = [0.0]  # monotonic seconds of the next tick (streams, timers, idle limits)
        try:
            while not self._stop.is_set():
                self._serve_window(sel, self.window.slot(), meter, due)
                for c in list(self._conns):
                    self._flush(c)
                meter.charge()
                if not any(c.line.inbuf or c.line.out or c.line.session.pending
                           or c.line.session.stream for c in self._conns):
                    self._set_events(sel)
                    sel.select(max(0.0, min(POLL_S, due[0] - time.monotonic())))
        finally:
            for c in list(self._conns):
                self._drop(c, "server stopping")
            sel.close()

    def _serve_window(self, sel: selectors.BaseSelector, slot: Slot, meter: CpuMeter,
                      due: list[float]) -> None:
        """Input, lines, replies and the tick in ``slot``: until it closes, the processor
        budget is spent, or (past ``slot.settles``) nothing is left to do."""
        first = True
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= slot.closes:
                return
            busy = first or any(c.line.ready() for c in self._conns)
            self._set_events(sel)
            wait = _wait_in(slot, now, due[0], busy,
                            any(c.line.session.pending for c in self._conns))
            if wait is None:
                return  # nothing to do, and no more waiting in this window
            first = False
            for key, _ in sel.select(wait):
                if isinstance(key.data, _Listener):
                    self._accept(sel, key.data)
                else:
                    self._io(key.data)
            if not meter.charge():
                return  # the budget is spent: ScanWindow.slot waits for it
            # the lines first: streams that always have images to compare never keep a
            # command waiting
            self._work(min(slot.closes, time.monotonic() + ROUND_BUDGET_S), meter)
            if time.monotonic() >= due[0] and meter.charge():
                # the streams' work ends with the window; what is left comes first in
                # the next one (the tick stays due)
                if self._tick(min(slot.closes, time.monotonic() + ROUND_BUDGET_S)):
                    due[0] = time.monotonic() + POLL_S
            for c in list(self._conns):
                self._flush(c)

    def _set_events(self, sel: selectors.BaseSelector) -> None:
        for c in self._conns:
            ev = (selectors.EVENT_READ if len(c.line.inbuf) < IN_MAX else 0) | (
                selectors.EVENT_WRITE if c.line.out else 0)
            if ev != c.events:
                if c.events and ev:
                    sel.modify(c.sock, ev, c)
                elif ev:
                    sel.register(c.sock, ev, c)
                else:
                    sel.unregister(c.sock)
                c.events = ev

    def _work(self, until: float, meter: CpuMeter) -> None:
        """Lines handed over round-robin, one per connection, until ``until`` (monotonic
        seconds) or the window's processor budget is spent. The connection served goes
        to the end of the order, so the next line (in this round or the next) comes from
        the one served least recently: a line that waits for a scan boundary uses up a
        round, and restarting each round from the first connection starved the last
        ones."""
        conns = self._conns
        while True:
            c = next((c for c in conns if c.line.ready()), None)
            if c is None:
                return
            conns.remove(c)
            conns.append(c)
            c.line.step()
            if not meter.charge() or time.monotonic() >= until:
                return

    def _tick(self, until: float) -> bool:
        """Streams polled, and idle connections closed (POLL_S apart), until ``until``
        (monotonic seconds): the connections not polled by then are polled first by the
        next tick, so that every stream is served however long each takes. Whether every
        connection was polled to its end."""
        now = self.clock()
        if not self._unpolled:
            self._unpolled = list(self._conns)
        while self._unpolled:
            if time.monotonic() >= until:
                return False
            c = self._unpolled.pop(0)
            if c not in self._conns:
                continue  # dropped since the tick began
            done = c.line.poll(until)
            if not done:
                self._unpolled.append(c)  # its stream goes on after the others
            s = c.line.session
            if s.trusted or s.unlocked:
                c.line.idle_since = now  # locked again later: idle from then on
            elif now - c.line.idle_since >= IDLE_TIMEOUT_S:
                self._idle_out(c, now)
            elif c.line.out and time.monotonic() - c.drained > SEND_TIMEOUT_S:
                log.warning("console %s: the peer took nothing for %.0f s", c.address,
                            SEND_TIMEOUT_S)
                self._drop(c, "peer disconnected")
            if not done:
                return False  # the window's time is spent
        return True

    def _idle_out(self, c: _Conn, now: float) -> None:
        c.line.out.clear()
        c.line.say(f"error idle timeout ({now - c.line.idle_since:.0f} s without input, "
                   "not unlocked)")
        self._flush(c)
        self._drop(c, "idle timeout")

    def _accept(self, sel: selectors.BaseSelector, lst: _Listener) -> None:
        try:
            conn, _ = lst.sock.accept()
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            log.warning("console %s: accept failed: %s", lst.address, exc)
            return
        here = [c for c in self._conns if c.address == lst.address]
        if len(here) >= MAX_CONNECTIONS:
            now = self.clock()
            idle = [c for c in here if not (c.line.session.trusted or c.line.session.unlocked)
                    and now - c.line.idle_since >= EVICT_IDLE_S]
            if not idle:
                log.warning("console %s: connection refused, %d sessions already",
                            lst.address, MAX_CONNECTIONS)
                try:
                    conn.send(f"error too many console sessions ({MAX_CONNECTIONS})\r\n"
                              .encode())
                except OSError:
                    pass
                conn.close()
                return
            self._idle_out(min(idle, key=lambda c: c.line.idle_since), now)
        conn.setblocking(False)
        e = lst.entry
        session = self.service.session(f"{e.kind}:{lst.address}", trusted=e.trusted,
                                       peer=peer_of(conn, e.kind))
        # real time: a test's stepped clock does not refill the bucket
        c = _Conn(conn, Line(session, self.clock, Throttle()), lst.address)
        self._conns.append(c)
        self._opened(session)
        log.info("console session on %s opened (%s)", lst.address, session.peer)

    def _io(self, c: _Conn) -> None:
        if c not in self._conns:
            return  # dropped earlier in this round
        if len(c.line.inbuf) < IN_MAX:
            try:
                data = c.sock.recv(READ_CHUNK)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                log.info("console session on %s ended: %s", c.address, exc)
                self._drop(c, "peer disconnected")
                return
            if not data:
                self._drop(c, "peer disconnected")
                return
            c.line.receive(data)

    def _flush(self, c: _Conn) -> None:
        out = c.line.out
        if not out:
            c.drained = time.monotonic()
            return
        try:
            sent = c.sock.send(out)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._drop(c, "peer disconnected")
            return
        if sent:
            del out[:sent]
            c.drained = time.monotonic()

    def _drop(self, c: _Conn, reason: str) -> None:
        if c not in self._conns:
            return
        self._conns.remove(c)
        if c.events and self._selector is not None:
            try:
                self._selector.unregister(c.sock)
            except (KeyError, ValueError):
                pass
        try:
            if c.line.out:
                c.sock.send(c.line.out)  # what fits: the last replies, a reason
        except OSError:
            pass
        c.sock.close()
        try:
            self._closed(c.line.session, reason)
        except Exception:  # noqa: BLE001 - one session's close must not stop the others
            log.exception("console session on %s: close failed", c.address)

    # -- serial: a thread per port ------------------------------------------------------
    def _serve_serial(self, e: ConsoleEntry) -> None:
        import serial  # pyserial

        delay = REOPEN_MIN_S
        while not self._stop.is_set():
            try:
                port = serial.Serial(e.address, e.baudrate, timeout=0,
                                     write_timeout=SEND_TIMEOUT_S, exclusive=True)
            except (OSError, ValueError, serial.SerialException) as exc:
                if delay == REOPEN_MIN_S:
                    log.error("console serial port %s: %s (trying again)", e.address, exc)
                self._stop.wait(delay)
                delay = min(2 * delay, REOPEN_MAX_S)
                continue
            delay = REOPEN_MIN_S
            log.info("console on serial %s at %d baud%s", e.address, e.baudrate,
                     " (trusted)" if e.trusted else "")
            session = self.service.session(f"serial:{e.address}", trusted=e.trusted,
                                           peer=f"serial:{e.address}")
            self._opened(session)
            reason = "server stopping"
            try:
                reason = self._pump_serial(port, Line(session, self.clock), e.address)
            except (OSError, serial.SerialException) as exc:
                log.warning("console serial %s: %s: session ended", e.address, exc)
                reason = "hang-up"
            finally:
                try:
                    self._closed(session, reason)
                finally:
                    port.close()
            if reason == "hang-up":
                self._stop.wait(REOPEN_MIN_S)

    def _pump_serial(self, port: Any, line: Line, address: str) -> str:
        """Serve one open port until it hangs up (returns "hang-up") or the server stops;
        inside the windows only, as the sockets are (``_serve_sockets``)."""
        poller = select.poll()
        poller.register(port.fileno(), select.POLLIN)
        state = _SerialState(carrier=_carrier(port))  # None: no modem lines (pty, gadget)
        meter = self.window.meter()
        while not self._stop.is_set():
            slot = self.window.slot()
            first = True
            while not self._stop.is_set():
                now = time.monotonic()
                if now >= slot.closes or not meter.charge():
                    break
                wait = _wait_in(slot, now, state.due, first or line.ready(),
                                line.session.pending is not None)
                if wait is None:
                    break  # nothing to do, and no more waiting in this window
                first = False
                if self._serial_io(port, poller, line, state, wait, address, slot.closes):
                    return "hang-up"
                if line.ready():
                    line.step()
                self._serial_write(port, line, address)
            meter.charge()
            if not (line.inbuf or line.out or line.session.pending or line.session.stream):
                # nothing to do: wait for input across windows (then for a window)
                for _, ev in poller.poll(max(0.0, min(POLL_S, state.due - time.monotonic()))
                                         * 1000):
                    if ev & (select.POLLHUP | select.POLLERR | select.POLLNVAL):
                        log.warning("console serial %s: hang-up", address)
                        return "hang-up"
        return "server stopping"

    def _serial_io(self, port: Any, poller: select.poll, line: Line, state: _SerialState,
                   wait: float, address: str, closes: float) -> bool:
        """Read what came (up to ``wait`` seconds), and poll the session (its stream until
        ``closes``, the window's close: what is left keeps the poll due) and the carrier
        when due; whether the line hung up."""
        reading = len(line.inbuf) < IN_MAX  # full: the bytes wait in the port
        if reading != state.reading:
            state.reading = reading
            poller.modify(port.fileno(), select.POLLIN if reading else 0)
        for _, ev in poller.poll(wait * 1000):
            if ev & (select.POLLHUP | select.POLLERR | select.POLLNVAL):
                log.warning("console serial %s: hang-up", address)
                return True
            if ev & select.POLLIN:
                data = bytes(port.read(min(max(port.in_waiting, 1), READ_CHUNK)))
                if data:
                    line.receive(data)
        if time.monotonic() >= state.due:
            if line.poll(closes):
                state.due = time.monotonic() + POLL_S
            if state.carrier is not None:
                cd = _carrier(port)
                if state.carrier and cd is False:
                    log.warning("console serial %s: carrier lost (hang-up)", address)
                    return True
                state.carrier = state.carrier or bool(cd)
        return False

    @staticmethod
    def _serial_write(port: Any, line: Line, address: str) -> None:
        import serial  # pyserial

        if line.out:
            data, line.out = bytes(line.out), bytearray()
            try:
                port.write(data)
            except serial.SerialTimeoutException:
                log.warning("console serial %s: nobody reads the line, output dropped",
                            address)

    def stop(self) -> None:
        """Stop serving: every session closed (its streams and, if configured, its
        forces released), threads joined, socket files removed. Idempotent."""
        self._stop.set()
        self.service.controller.remove_listener(self.window.on_scan)
        self.window.close()
        with self._lock:
            threads = list(self._threads)
        for t in threads:
            t.join(timeout=SEND_TIMEOUT_S + 1.0)
            if t.is_alive():
                log.error("console thread %s did not stop", t.name)
        for lst in self._listeners:
            lst.sock.close()
        self._listeners.clear()
        for path in self._socket_paths:
            remove_socket(path)  # only if still the one it bound
        self._socket_paths.clear()


def _wait_in(slot: Slot, now: float, tick: float, busy: bool, pending: bool
             ) -> float | None:
    """How long a serving loop may wait for input at ``now`` in ``slot`` (seconds): not
    at all while it has work (``busy``) or its tick is due (monotonic ``tick``); up to
    the tick, POLL_S (PENDING_POLL_S while a command is pending) and ``slot.settles``
    otherwise; None once the slot has settled: the rest waits for the next window."""
    if busy or now >= tick:
        return 0.0
    limit = min(slot.settles, tick)
    if now >= limit:
        return None
    return min(limit - now, PENDING_POLL_S if pending else POLL_S)


class _SerialState:
    """What the serving loop of one serial port keeps between two windows."""

    def __init__(self, carrier: bool | None) -> None:
        #: the carrier detect line as last seen (None: the port has no modem lines)
        self.carrier = carrier
        #: monotonic seconds of the next poll of the session and the carrier
        self.due = 0.0
        #: whether the port's input is being read (not while IN_MAX bytes wait)
        self.reading = True


def _carrier(port: Any) -> bool | None:
    """The port's carrier detect line, or None if it has no modem lines."""
    try:
        return bool(port.cd)
    except (OSError, ValueError, AttributeError):
        return None
