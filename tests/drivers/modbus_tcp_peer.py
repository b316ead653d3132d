"""A Modbus TCP device or gateway for the tests: pymodbus' TCP server with one device per
unit, in its own thread and event loop, and a TCP relay in front of it that breaks the
connection on demand.

``ModbusTcpPeer``: values read and set from the test (``get``/``set`` as the RTU peer's),
exception replies on demand (``fail``), units that stop answering (``silent``: their
replies are never sent) and units the gateway cannot reach (``absent``: answered with
exception 0x0B, gateway target device failed to respond, as a Modbus TCP to RTU gateway
answers for a slave that is not on its line).

``Relay``: the driver connects to it, it connects to the peer; ``cut`` drops every reply
(a cable pulled without the connection noticing), ``reset_next_reply(n)`` sends the first
``n`` bytes of the next reply and resets the connection (RST), ``delay_next_reply(s)``
holds the next reply back, ``refuse()`` closes its listening socket (connection refused)
and every connection, ``listen()`` opens it again on the same port.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import select
import socket
import struct
import threading
import time
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

#: items in each table of every unit
SIZE = 256

logging.getLogger("pymodbus").setLevel(logging.CRITICAL)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class ModbusTcpPeer:
    """pymodbus TCP server for ``units`` (and ``absent`` ones) on 127.0.0.1, in a thread."""

    START_TIMEOUT_S = 5.0

    def __init__(self, units: tuple[int, ...] = (1,), absent: tuple[int, ...] = ()) -> None:
        self.units = units
        self.absent = absent
        self.port = free_port()
        #: unit -> exception code the unit answers every request with
        self.fail: dict[int, ExcCodes] = {}
        #: units whose replies are never sent
        self.silent: set[int] = set()
        #: (unit, function code, address, count) of every request served
        self.served: list[tuple[int, int, int, int]] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: ModbusTcpServer | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None

    async def _action(self, unit: int, function_code: int, start_address: int, address: int,
                      count: int, registers: list[int], set_values: Any) -> ExcCodes | None:
        self.served.append((unit, function_code, address, count))
        if unit in self.absent:
            return ExcCodes.GATEWAY_NO_RESPONSE
        return self.fail.get(unit)

    def _trace(self, sending: bool, packet: bytes) -> bytes:
        if sending and len(packet) > 6 and packet[6] in self.silent:
            return b""
        return packet

    def _devices(self) -> list[SimDevice]:
        def bits() -> list[SimData]:
            return [SimData(0, count=SIZE, values=False, datatype=DataType.BITS)]

        def regs() -> list[SimData]:
            return [SimData(0, count=SIZE, values=0, datatype=DataType.REGISTERS)]

        return [SimDevice(u, simdata=(bits(), bits(), regs(), regs()),
                          action=functools.partial(self._action, u))
                for u in (*self.units, *self.absent)]

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        try:
            self._server = ModbusTcpServer(self._devices(), address=("127.0.0.1", self.port),
                                           trace_packet=self._trace)
            await self._server.serve_forever(background=True)
        except BaseException as exc:  # reported by start()
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        await self._server.serving

    def start(self) -> ModbusTcpPeer:
        self._thread = threading.Thread(target=asyncio.run, args=(self._main(),),
                                        name=f"modbus-tcp-peer {self.port}", daemon=True)
        self._thread.start()
        if not self._ready.wait(self.START_TIMEOUT_S):
            raise RuntimeError("modbus tcp peer did not start")
        if self._error is not None:
            raise RuntimeError(f"modbus tcp peer failed: {self._error!r}")
        return self

    def stop(self) -> None:
        if self._thread is None:
            return
        if self._loop is not None and self._server is not None:
            fut = asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop)
            fut.result(self.START_TIMEOUT_S)
        self._thread.join(self.START_TIMEOUT_S)
        self._thread = None

    def _call(self, coro: Any) -> Any:
        assert self._loop is not None
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(self.START_TIMEOUT_S)

    def get(self, unit: int, function_code: int, address: int, count: int = 1) -> list[int]:
        """Values of a table as the unit holds them (1 coils, 2 inputs, 3 HR, 4 IR)."""
        assert self._server is not None
        values = self._call(self._server.context.async_getValues(unit, function_code,
                                                                 address, count))
        return [int(v) for v in values]

    def set(self, unit: int, function_code: int, address: int, values: list[int]) -> None:
        """Set values in a table of the unit, as its own inputs would."""
        assert self._server is not None
        vals: list[Any] = [bool(v) for v in values] if function_code in (1, 2) else values
        self._call(self._server.context.async_setValues(unit, function_code, address, vals))

    def __enter__(self) -> ModbusTcpPeer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


class Relay:
    """A TCP relay from ``port`` (a free one) to 127.0.0.1:``target``, breaking on demand."""

    def __init__(self, target: int) -> None:
        self.target = target
        self.port = free_port()
        self.cut = False
        #: connections accepted so far
        self.connections = 0
        #: what the clients sent, chunk by chunk (a master's request is one chunk)
        self.requests: list[bytes] = []
        self._reset_at: int | None = None
        self._delay_s = 0.0
        self._lock = threading.Lock()
        self._pairs: list[tuple[socket.socket, socket.socket]] = []
        self._listener: socket.socket | None = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.listen()

    def listen(self) -> None:
        """Accept connections (again) on ``port``."""
        srv = socket.socket()
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        srv.bind(("127.0.0.1", self.port))
        srv.listen(16)
        self._listener = srv
        self._accepting = threading.Event()
        t = threading.Thread(target=self._accept, args=(srv, self._accepting), daemon=True,
                             name=f"relay-accept {self.port}")
        t.start()
        self._acceptor = t
        self._threads.append(t)

    def refuse(self) -> None:
        """Close the listening socket (a connection is refused, not reset: the accepting
        thread has ended first) and every connection."""
        srv, self._listener = self._listener, None
        if srv is not None:
            self._accepting.set()
            self._acceptor.join(2.0)
            srv.close()
        self.drop_all()

    def drop_all(self) -> None:
        with self._lock:
            pairs, self._pairs = self._pairs, []
        for a, b in pairs:
            for s in (a, b):
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                s.close()

    def reset_next_reply(self, after: int) -> None:
        """The next reply: its first ``after`` bytes, then a reset of the connection."""
        self._reset_at = after

    def delay_next_reply(self, seconds: float) -> None:
        self._delay_s = seconds

    def _accept(self, srv: socket.socket, ended: threading.Event) -> None:
        while not self._stop.is_set() and not ended.is_set():
            try:
                r, _, _ = select.select([srv], [], [], 0.05)
                if not r:
                    continue
                client, _ = srv.accept()
            except (OSError, ValueError):
                return  # closed by refuse() or close()
            try:
                upstream = socket.create_connection(("127.0.0.1", self.target), timeout=2)
            except OSError:
                client.close()
                continue
            self.connections += 1
            with self._lock:
                self._pairs.append((client, upstream))
            for src, dst, replies in ((client, upstream, False), (upstream, client, True)):
                t = threading.Thread(target=self._pump, args=(src, dst, replies), daemon=True,
                                     name=f"relay-pump {self.port}")
                t.start()
                self._threads.append(t)

    def _pump(self, src: socket.socket, dst: socket.socket, replies: bool) -> None:
        try:
            while not self._stop.is_set():
                r, _, _ = select.select([src], [], [], 0.05)
                if not r:
                    continue
                data = src.recv(4096)
                if not data:
                    break
                if not replies:
                    self.requests.append(data)
                    dst.sendall(data)
                    continue
                if self.cut:
                    continue
                if self._delay_s:
                    delay, self._delay_s = self._delay_s, 0.0
                    time.sleep(delay)
                if self._reset_at is not None:
                    n, self._reset_at = self._reset_at, None
                    dst.sendall(data[:n])
                    time.sleep(0.02)  # the bytes go out before the reset
                    dst.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER,
                                   struct.pack("ii", 1, 0))
                    dst.close()
                    src.close()
                    return
                dst.sendall(data)
        except (OSError, ValueError):
            pass
        for s in (src, dst):
            try:
                s.close()
            except OSError:
                pass

    def close(self) -> None:
        self._stop.set()
        self.refuse()
        for t in self._threads:
            t.join(2.0)
