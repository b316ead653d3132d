"""A Modbus RTU slave line for the tests: pymodbus' serial server with one device per unit.

In-process (``ModbusPeer``: its own thread and event loop, values read and set from the
test, exception replies on demand) or as a separate process that a test can kill::

    python modbus_peer.py --port /dev/pts/7 --units 1,2 --set 1:2:0:1,0,1 --set 2:4:0:1234

(``--set UNIT:FC:ADDRESS:V1,V2,...``, FC 2 discrete inputs, 4 input registers, 1 coils,
3 holding registers.) The process prints ``ready`` once it listens.
"""

from __future__ import annotations

import argparse
import asyncio
import functools
import logging
import sys
import threading
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType
from pymodbus.server import ModbusSerialServer
from pymodbus.simulator import DataType, SimData, SimDevice

#: items in each table of every unit
SIZE = 64

logging.getLogger("pymodbus").setLevel(logging.CRITICAL)


class ModbusPeer:
    """pymodbus RTU server for ``units`` on ``port``, running in a thread."""

    #: seconds to wait for the server to listen / to stop
    START_TIMEOUT_S = 5.0

    def __init__(self, port: str, units: tuple[int, ...] = (1,), baudrate: int = 115200,
                 parity: str = "N") -> None:
        self.port = port
        self.units = units
        self.baudrate = baudrate
        self.parity = parity
        #: unit -> exception code the unit answers every request with
        self.fail: dict[int, ExcCodes] = {}
        #: (unit, function code, address, count) of every request served
        self.served: list[tuple[int, int, int, int]] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: ModbusSerialServer | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None

    async def _action(self, unit: int, function_code: int, start_address: int, address: int,
                      count: int, registers: list[int], set_values: Any) -> ExcCodes | None:
        self.served.append((unit, function_code, address, count))
        return self.fail.get(unit)

    def _trace(self, sending: bool, packet: bytes) -> bytes:
        # A unit that is not on the line stays silent, as on a real RS-485 multi-drop line
        # (pymodbus' SimDevice server answers it with exception 4; ignore_missing_devices
        # only works with the old datastore).
        if sending and packet and packet[0] not in self.units:
            return b""
        return packet

    def _devices(self) -> list[SimDevice]:
        def bits() -> list[SimData]:
            return [SimData(0, count=SIZE, values=False, datatype=DataType.BITS)]

        def regs() -> list[SimData]:
            return [SimData(0, count=SIZE, values=0, datatype=DataType.REGISTERS)]

        return [SimDevice(u, simdata=(bits(), bits(), regs(), regs()),
                          action=functools.partial(self._action, u)) for u in self.units]

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        try:
            self._server = ModbusSerialServer(self._devices(), framer=FramerType.RTU,
                                              port=self.port, baudrate=self.baudrate,
                                              parity=self.parity, reconnect_delay=0.1,
                                              trace_packet=self._trace)
            await self._server.serve_forever(background=True)
        except BaseException as exc:  # reported by start()
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        await self._server.serving

    def start(self) -> ModbusPeer:
        self._thread = threading.Thread(target=asyncio.run, args=(self._main(),),
                                        name=f"modbus-peer {self.port}", daemon=True)
        self._thread.start()
        if not self._ready.wait(self.START_TIMEOUT_S):
            raise RuntimeError("modbus peer did not start")
        if self._error is not None:
            raise RuntimeError(f"modbus peer failed: {self._error!r}")
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
        core = self._server.context
        values = self._call(core.async_getValues(unit, function_code, address, count))
        return [int(v) for v in values]

    def set(self, unit: int, function_code: int, address: int, values: list[int]) -> None:
        """Set values in a table of the unit, as its own inputs would."""
        assert self._server is not None
        core = self._server.context
        if function_code in (1, 2):
            self._call(core.async_setValues(unit, function_code, address,
                                            [bool(v) for v in values]))
        else:
            self._call(core.async_setValues(unit, function_code, address, list(values)))

    def __enter__(self) -> ModbusPeer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--port", required=True)
    ap.add_argument("--units", default="1")
    ap.add_argument("--baudrate", type=int, default=115200)
    ap.add_argument("--set", action="append", default=[])
    args = ap.parse_args(argv)
    units = tuple(int(u) for u in args.units.split(","))
    peer = ModbusPeer(args.port, units, args.baudrate).start()
    for spec in args.set:
        unit, fc, address, values = spec.split(":")
        peer.set(int(unit), int(fc), int(address), [int(v) for v in values.split(",")])
    announce_and_serve(peer)


def announce_and_serve(peer: ModbusPeer) -> None:
    """Print ``ready`` (the started peer listens) and serve until the process is killed."""
    sys.stdout.write("ready\n")
    sys.stdout.flush()
    assert peer._thread is not None
    peer._thread.join()


if __name__ == "__main__":
    main()
