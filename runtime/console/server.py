"""Console transports: serial line (pyserial), Unix socket, TCP on 127.0.0.1 only.

One thread per connection (and one per serial port); each feeds bytes to its Session,
writes back the replies and polls the session's streams. None of this runs in the scan
thread: plant access goes through Controller.call. A serial port that fails or hangs up
(a USB gadget unplugged) ends its session and is opened again, so the console comes back
when the cable does.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
from collections.abc import Callable

from runtime.console.service import ConsoleService
from runtime.console.session import Session
from runtime.language.model import ConsoleEntry

log = logging.getLogger(__name__)

#: how long a read waits before the session's streams are polled, seconds
POLL_S = 0.05
#: bytes taken from the line per read: keeps each burst of console work short
READ_CHUNK = 1024
#: a peer that takes nothing for this long loses the output (serial) or the connection
#: (socket), seconds
SEND_TIMEOUT_S = 5.0
#: connections served at once on one socket or TCP port
MAX_CONNECTIONS = 8
#: a serial port that cannot be opened is tried again after this delay, doubling up to
#: the maximum, seconds
REOPEN_MIN_S = 0.5
REOPEN_MAX_S = 10.0


class ConsoleServer:
    """Serves the console on every configured entry until ``stop()``."""

    def __init__(self, service: ConsoleService, entries: list[ConsoleEntry]) -> None:
        self.service = service
        self.entries = entries
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._listeners: list[socket.socket] = []
        self._socket_paths: list[str] = []
        self._lock = threading.Lock()
        self._active: dict[str, int] = {}
        #: where the console is served: serial ports, socket paths, 127.0.0.1:PORT
        self.addresses: list[str] = []
        #: the sessions open now
        self.sessions: list[Session] = []

    def start(self) -> None:
        """Open every listener (errors raised here) and start the serving threads."""
        for e in self.entries:
            if e.kind == "serial":
                self.addresses.append(e.address)
                self._spawn(self._serve_serial, e, name=f"console-serial-{e.address}")
            else:
                srv = self._listen(e)
                self._listeners.append(srv)
                self._spawn(self._accept_loop, srv, e, self.addresses[-1],
                            name=f"console-{e.kind}")

    def _spawn(self, fn: Callable[..., None], *args: object, name: str) -> None:
        t = threading.Thread(target=fn, args=args, name=name, daemon=True)
        with self._lock:
            self._threads = [x for x in self._threads if x.is_alive()]
            self._threads.append(t)
        t.start()

    def _listen(self, e: ConsoleEntry) -> socket.socket:
        if e.kind == "socket":
            path = e.address
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            if os.path.exists(path):
                os.unlink(path)  # left by a previous run
            srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            srv.bind(path)
            os.chmod(path, 0o660)
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
        srv.settimeout(POLL_S * 4)
        log.info("console listening on %s%s", self.addresses[-1],
                 " (trusted)" if e.trusted else "")
        return srv

    # -- the common loop ------------------------------------------------------------
    def _pump(self, session: Session, recv: Callable[[], bytes | None],
              send: Callable[[bytes], None], address: str | None = None) -> None:
        """Bytes in -> replies out, streams polled between reads, until the peer leaves
        (``recv`` returns None) or the server stops. The session is closed at the end, and
        its place on ``address`` freed at the same moment it leaves ``sessions``."""
        with self._lock:
            self.sessions.append(session)
        try:
            while not self._stop.is_set():
                data = recv()
                if data is None:
                    return
                out = session.feed(data) if data else []
                out += session.poll()
                if out:
                    send(("\r\n".join(out) + "\r\n").encode("utf-8"))
        finally:
            try:
                session.close()
            finally:
                with self._lock:
                    self.sessions.remove(session)
                    if address is not None:
                        self._active[address] -= 1

    # -- sockets ------------------------------------------------------------------------
    def _accept_loop(self, srv: socket.socket, e: ConsoleEntry, address: str) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = srv.accept()
            except TimeoutError:
                continue
            except OSError:
                return  # closed by stop()
            with self._lock:
                busy = self._active.get(address, 0) >= MAX_CONNECTIONS
                if not busy:
                    self._active[address] = self._active.get(address, 0) + 1
            if busy:
                log.warning("console %s: connection refused, %d sessions already", address,
                            MAX_CONNECTIONS)
                try:
                    conn.sendall(f"error too many console sessions ({MAX_CONNECTIONS})\r\n"
                                 .encode())
                except OSError:
                    pass
                conn.close()
                continue
            session = self.service.session(f"{e.kind}:{address}", trusted=e.trusted)
            self._spawn(self._serve_socket, conn, session, address, name="console-conn")

    def _serve_socket(self, conn: socket.socket, session: Session, address: str) -> None:
        log.info("console session on %s opened", address)
        conn.settimeout(POLL_S)

        def recv() -> bytes | None:
            try:
                return conn.recv(READ_CHUNK) or None
            except TimeoutError:
                return b""

        def send(data: bytes) -> None:
            conn.settimeout(SEND_TIMEOUT_S)
            conn.sendall(data)
            conn.settimeout(POLL_S)
        try:
            self._pump(session, recv, send, address)
        except OSError as exc:
            log.info("console session on %s ended: %s", address, exc)
        finally:
            conn.close()
            log.info("console session on %s closed", address)

    # -- serial -------------------------------------------------------------------------
    def _serve_serial(self, e: ConsoleEntry) -> None:
        import serial  # pyserial

        delay = REOPEN_MIN_S
        while not self._stop.is_set():
            try:
                port = serial.Serial(e.address, e.baudrate, timeout=POLL_S,
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
            session = self.service.session(f"serial:{e.address}", trusted=e.trusted)

            def recv(port: serial.Serial = port) -> bytes | None:
                return bytes(port.read(min(max(port.in_waiting, 1), READ_CHUNK)))

            def send(data: bytes, port: serial.Serial = port) -> None:
                try:
                    port.write(data)
                except serial.SerialTimeoutException:
                    log.warning("console serial %s: nobody reads the line, output dropped",
                                e.address)
            try:
                self._pump(session, recv, send)
            except (OSError, serial.SerialException) as exc:
                log.warning("console serial %s: %s (hang-up?): session ended", e.address, exc)
                self._stop.wait(REOPEN_MIN_S)
            finally:
                port.close()

    def stop(self) -> None:
        """Stop serving: every session closed (its streams and, if configured, its
        forces released), threads joined, socket files removed. Idempotent."""
        self._stop.set()
        for srv in self._listeners:
            srv.close()
        self._listeners.clear()
        for _ in range(2):  # an accept loop may have spawned a session while stopping
            with self._lock:
                threads = list(self._threads)
            for t in threads:
                t.join(timeout=SEND_TIMEOUT_S + 1.0)
                if t.is_alive():
                    log.error("console thread %s did not stop", t.name)
        for path in self._socket_paths:
            if os.path.exists(path):
                os.unlink(path)
        self._socket_paths.clear()
