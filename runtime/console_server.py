"""Console transports: serial line (pyserial), Unix socket, TCP on 127.0.0.1 only.

One thread per connection; each feeds bytes to its Session and polls its streams. None of
this runs in the scan thread: plant access goes through Controller.call.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
from collections.abc import Callable

from runtime.console import ConsoleService, Session
from runtime.model import ConsoleEntry

log = logging.getLogger(__name__)

#: how long a read waits before the session's streams are polled, seconds
POLL_S = 0.05


class ConsoleServer:
    """Serves the console on every configured entry until ``stop()``."""

    def __init__(self, service: ConsoleService, entries: list[ConsoleEntry]) -> None:
        self.service = service
        self.entries = entries
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._listeners: list[socket.socket] = []
        self.addresses: list[str] = []

    def start(self) -> None:
        for e in self.entries:
            if e.kind == "serial":
                self._spawn(self._serve_serial, e, name=f"console-serial-{e.address}")
            else:
                srv = self._listen(e)
                self._listeners.append(srv)
                self._spawn(self._accept_loop, srv, e, name=f"console-{e.kind}")

    def _spawn(self, fn: Callable[..., None], *args: object, name: str) -> None:
        t = threading.Thread(target=fn, args=args, name=name, daemon=True)
        t.start()
        self._threads.append(t)

    def _listen(self, e: ConsoleEntry) -> socket.socket:
        if e.kind == "socket":
            path = e.address
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            if os.path.exists(path):
                os.unlink(path)
            srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            srv.bind(path)
            os.chmod(path, 0o660)
            self.addresses.append(path)
        else:
            host, port = e.address.rsplit(":", 1)
            if host != "127.0.0.1":  # console.md: TCP is bound to 127.0.0.1 only
                raise ValueError("the TCP console binds to 127.0.0.1 only")
            srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            srv.bind((host, int(port)))
            self.addresses.append(f"{host}:{srv.getsockname()[1]}")
        srv.listen(4)
        srv.settimeout(POLL_S * 4)
        log.info("console listening on %s", self.addresses[-1])
        return srv

    def _accept_loop(self, srv: socket.socket, e: ConsoleEntry) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = srv.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            session = self.service.session(f"{e.kind}:{e.address}", trusted=e.trusted)
            self._spawn(self._serve_socket, conn, session, name="console-conn")

    def _serve_socket(self, conn: socket.socket, session: Session) -> None:
        conn.settimeout(POLL_S)
        try:
            while not self._stop.is_set():
                try:
                    data = conn.recv(4096)
                    if not data:
                        break
                    out = session.feed(data)
                except TimeoutError:
                    out = []
                out += session.poll()
                if out:
                    conn.sendall(("\r\n".join(out) + "\r\n").encode())
        except OSError as exc:
            log.info("console connection ended: %s", exc)
        finally:
            session.close()
            conn.close()

    def _serve_serial(self, e: ConsoleEntry) -> None:
        import serial  # pyserial

        session = self.service.session(f"serial:{e.address}", trusted=e.trusted)
        try:
            port = serial.Serial(e.address, e.baudrate, timeout=POLL_S)
        except (OSError, serial.SerialException) as exc:
            log.error("console serial port %s: %s", e.address, exc)
            return
        self.addresses.append(e.address)
        log.info("console on serial %s at %d baud", e.address, e.baudrate)
        try:
            while not self._stop.is_set():
                data = port.read(port.in_waiting or 1)
                out = session.feed(data) if data else []
                out += session.poll()
                if out:
                    port.write(("\r\n".join(out) + "\r\n").encode())
        except (OSError, serial.SerialException) as exc:
            log.error("console serial port %s: %s", e.address, exc)
        finally:
            session.close()
            port.close()

    def stop(self) -> None:
        self._stop.set()
        for srv in self._listeners:
            srv.close()
        for t in self._threads:
            t.join(timeout=1.0)
        for e in self.entries:
            if e.kind == "socket" and os.path.exists(e.address):
                os.unlink(e.address)
