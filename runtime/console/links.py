"""The monitor's links to a console: a Unix socket, a TCP port or a serial line.

``Target`` is where the console is (its kind decided once, from what the address is);
``Target.open`` gives a ``Link``, a byte pipe to it. The errors of reaching the controller,
``MonitorError`` and ``ConnectionLost``, live here, at the bottom of the monitor's layers:
the links raise them, the client (``client.py``) and the screen (``monitor.py``) too.
"""

from __future__ import annotations

import os
import re
import socket
import stat
from dataclasses import dataclass
from enum import Enum
from typing import Protocol

from runtime.errors import Loc, SoftplcError, SourceError
from runtime.language.runtimedir import PLACEHOLDER, SERVICE_RUNTIME, runtime_dir

#: how long a command may take before the controller is considered silent, seconds
REQUEST_TIMEOUT_S = 5.0

_TCP = re.compile(r"^(?:\[?[\w.:-]*\]?):(\d+)$")
#: at most this many sockets of the runtime directory named when the one asked is not there
SOCKETS_NAMED = 5


class MonitorError(SoftplcError):
    """The controller cannot be reached or stopped answering.

    Examples: the socket path does not exist; the serial port is held by another
    program; no reply within REQUEST_TIMEOUT_S."""


def console_of(target: str) -> str:
    """The console address ``target`` names (``softplc monitor``, ``softplc reload``): a
    plant file's console, found the way every process of a plant finds its controller
    (``runtimedir.locate``: SourceError if the plant does not load or has no console), or
    ``target`` itself (a socket, HOST:PORT, a serial port). ``${RUNTIME_DIR}`` is each
    plant's own directory: it is expanded only where systemd set it (``$RUNTIME_DIRECTORY``),
    else refused naming the plant file as the way (SourceError at ``SOCKET|PORT``)."""
    from runtime.language.plantfile import load_plant
    from runtime.language.runtimedir import PLACEHOLDER, expand, locate

    try:
        st: os.stat_result | None = os.stat(target)
    except OSError:
        st = None
    if st is not None and stat.S_ISREG(st.st_mode):
        pdef = load_plant(target)
        console = locate(pdef).console
        if console is None:
            raise SourceError(Loc(pdef.path, 1, 1), "the plant has no console to reach it "
                                                    "by: add monitor: socket: (or tcp:)")
        return console
    loc = Loc("SOCKET|PORT", 1, 1)
    if "${" in target.replace(PLACEHOLDER, "") or PLACEHOLDER not in target:
        return expand(target, loc)  # as it is, or an unknown placeholder refused
    if not os.path.isabs(os.environ.get("RUNTIME_DIRECTORY", "").split(":")[0]):
        raise SourceError(loc, f"{PLACEHOLDER} is each plant's own directory: name the "
                               "plant file instead (it finds the plant's console), or the "
                               "socket's path as the controller printed it")
    return expand(target, loc)


class ConnectionLost(MonitorError):
    """The link broke while in use, or the controller stopped answering on it.

    Examples: the controller was restarted or killed (its socket closed: a broken pipe,
    a reset); a USB serial gadget went away; the console closed an idle connection; no
    reply within REQUEST_TIMEOUT_S (the link's state is unknown: it is opened again)."""



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
            raise MonitorError(f"{text}: no such socket or serial port (or HOST:PORT for "
                               f"TCP){_where_to_look(text)}")
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


def _is_socket(path: str) -> bool:
    try:
        return stat.S_ISSOCK(os.stat(path).st_mode)
    except OSError:
        return False


def _where_to_look(text: str) -> str:
    """Where a controller's console socket would be, for a path that is not there: the
    ``${RUNTIME_DIR}`` of each plant run by hand (a directory of its own under
    ``runtime_dir()``: the socket of that name in one of them, or the sockets there), or an
    installed plant's runtime directory holding a socket of that name."""
    if text.startswith("/dev/"):
        return ""  # a serial port
    rdir = runtime_dir()
    name = os.path.basename(text)
    mine = os.path.abspath(text)
    plants: list[str] = []
    for parent in (rdir, SERVICE_RUNTIME):
        try:
            plants += sorted(os.path.join(parent, d) for d in os.listdir(parent))
        except OSError:
            pass
    found = [p for p in (os.path.join(d, name) for d in plants) if p != mine and _is_socket(p)]
    where = (f"; a controller started by hand makes its console socket in {PLACEHOLDER}, "
             f"its plant's own directory under {rdir} (its log says 'console listening on "
             "PATH'; or name the plant file)")
    if found:
        return f"{where}: did you mean {found[0]}?"
    there = [os.path.relpath(os.path.join(d, e), rdir) for d in plants if d.startswith(rdir)
             for e in _entries(d) if _is_socket(os.path.join(d, e))]
    if not there:
        return f"{where}: no socket there now"
    more = f" and {len(there) - SOCKETS_NAMED} more" if len(there) > SOCKETS_NAMED else ""
    return f"{where}: sockets there: {', '.join(there[:SOCKETS_NAMED])}{more}"


def _entries(directory: str) -> list[str]:
    try:
        return sorted(os.listdir(directory))
    except OSError:
        return []


def _why(exc: Exception) -> str:
    """An OSError's text without its ``[Errno N]``."""
    return (exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)) or \
        type(exc).__name__
