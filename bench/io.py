"""Benchmark: what each I/O driver costs the scan, and bus round trips against test peers.

1. Per driver, the time of one ``read()`` + ``write()`` as the scan sees it (4 inputs,
   4 outputs, one output toggled each cycle), on the same emulators and peers as the
   tests: GPIO and I2C on their register-level emulators (so the cost is the driver's
   Python plus the emulator's, not a real bus transfer), CANopen on python-can's virtual
   bus with the simulated CiA 401 node, Modbus RTU on a pty pair with pymodbus' server.
2. Round trips: one Modbus RTU transaction (FC 2, 8 inputs) with our master and with
   pymodbus' own sync client on the same pty pair; a CANopen RPDO -> node -> TPDO echo
   seen by the driver; one CANopen SDO upload.

Not a test: prints a table.

    python -m bench.io [--cycles N]
"""

from __future__ import annotations

import argparse
import logging
import statistics
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import gpiod
import smbus2

from drivers.base import Direction, Driver, Health
from drivers.canopen_io import CanopenDriver
from drivers.gpio import GpioDriver
from drivers.mcp23017 import Mcp23017Driver
from drivers.modbus_frame import read_request
from drivers.modbus_rtu import ModbusRtuDriver
from drivers.pcf8574 import Pcf8574Driver
from drivers.serial_line import RtuMaster, SerialSettings
from drivers.sim import SimDriver
from tests.drivers.canopen_slave import Cia401Slave
from tests.drivers.fake_gpiod import FakeGpio
from tests.drivers.i2c_emulator import I2CWorld, Mcp23017Model, Pcf8574Model
from tests.drivers.modbus_peer import ModbusPeer
from tests.drivers.pty_bridge import PtyBridge

#: pause between spaced Modbus requests, longer than t3.5 at 115200 baud (1.75 ms), s
GAP_S = 0.003


def stats_us(samples_ns: list[int]) -> tuple[float, float, float]:
    """(mean, p99, max) in µs."""
    s = sorted(samples_ns)
    p99 = s[min(len(s) - 1, int(len(s) * 0.99))]
    return statistics.fmean(s) / 1e3, p99 / 1e3, s[-1] / 1e3


def scan_cost(d: Driver, cycles: int, pause_s: float = 0.0) -> tuple[float, float, float]:
    """Time of read()+write() over ``cycles`` cycles, one output toggled each cycle."""
    out = sorted(d.outputs)[0]
    samples = []
    for k in range(cycles):
        d.outputs[out] = k & 1
        t0 = time.perf_counter_ns()
        d.read()
        d.write()
        samples.append(time.perf_counter_ns() - t0)
        if pause_s:
            time.sleep(pause_s)
    return stats_us(samples)

D = TypeVar("D", bound=Driver)


def points(d: D, ins: list[str], outs: list[str]) -> D:
    for p in ins:
        d.add_point(p, Direction.IN)
    for p in outs:
        d.add_point(p, Direction.OUT)
    return d


@contextmanager
def patched(obj: Any, name: str, value: Any) -> Iterator[None]:
    old = getattr(obj, name)
    setattr(obj, name, value)
    try:
        yield
    finally:
        setattr(obj, name, old)


def bench_sim(cycles: int) -> tuple[float, float, float]:
    d = points(SimDriver("sim"), ["I0", "I1", "I2", "I3"], ["Q0", "Q1", "Q2", "Q3"])
    d.open()
    try:
        return scan_cost(d, cycles)
    finally:
        d.close()


def bench_gpio(cycles: int) -> tuple[float, float, float]:
    kernel = FakeGpio()
    kernel.add_chip("/dev/gpiochip0", 54)
    with patched(gpiod, "request_lines", kernel.request_lines):
        d = points(GpioDriver("gpio", {}), ["4", "5", "6", "7"], ["20", "21", "22", "23"])
        d.open()
        try:
            return scan_cost(d, cycles)
        finally:
            d.close()


def bench_i2c(kind: str, cycles: int) -> tuple[float, float, float]:
    world = I2CWorld()
    d: Driver
    if kind == "mcp23017":
        world.bus(1).add(Mcp23017Model(0x20))
        d = points(Mcp23017Driver("exp1", {"bus": 1, "address": 0x20}),
                   ["A0", "A1", "A2", "A3"], ["B0", "B1", "B2", "B3"])
    else:
        world.bus(1).add(Pcf8574Model(0x38))
        d = points(Pcf8574Driver("exp2", {"bus": 1, "address": 0x38}),
                   ["P0", "P1", "P2", "P3"], ["P4", "P5", "P6", "P7"])
    with patched(smbus2, "SMBus", world.smbus_class):
        d.open()
        try:
            return scan_cost(d, cycles)
        finally:
            d.close()


def bench_canopen(cycles: int) -> dict[str, tuple[float, float, float]]:
    channel = f"bench-{uuid.uuid4().hex[:8]}"
    out: dict[str, tuple[float, float, float]] = {}
    with Cia401Slave(5, channel=channel, echo=True) as slave:
        d = points(CanopenDriver("rio", {"interface": "virtual", "channel": channel,
                                         "node": 5, "heartbeat": "500ms"}),
                   ["I0", "I1", "I2", "I3"], ["Q0", "Q1", "Q2", "Q3"])
        d.open()
        try:
            assert d.health is not Health.FAULT, d.fault_reason
            out["canopen read+write"] = scan_cost(d, cycles, pause_s=0.001)
            # echo: Q0 -> RPDO -> node copies 0x6200 to 0x6000 -> TPDO -> I0
            samples = []
            for k in range(min(cycles, 300)):
                want = (k + 1) & 1
                d.outputs["Q0"] = want
                since = d.updates
                t0 = time.perf_counter_ns()
                d.write()
                while True:
                    d.wait_for_update(1.0, since=since)
                    since = d.updates
                    d.read()
                    if d.inputs["I0"] == want:
                        break
                samples.append(time.perf_counter_ns() - t0)
            out["canopen RPDO->TPDO echo"] = stats_us(samples)
            node = d._node
            assert node is not None
            samples = []
            for _ in range(min(cycles, 300)):
                t0 = time.perf_counter_ns()
                node.sdo.upload(0x1000, 0)
                samples.append(time.perf_counter_ns() - t0)
            out["canopen SDO upload"] = stats_us(samples)
        finally:
            d.close()
        del slave
    return out


def bench_modbus(cycles: int) -> dict[str, tuple[float, float, float]]:
    out: dict[str, tuple[float, float, float]] = {}
    with PtyBridge() as bridge, ModbusPeer(bridge.peer_port, units=(1,)):
        d = points(ModbusRtuDriver("mb", {"port": bridge.driver_port, "unit": 1,
                                          "baudrate": 115200, "timeout": "100ms"}),
                   ["I0", "I1", "I2", "I3"], ["Q0", "Q1", "Q2", "Q3"])
        d.open()
        try:
            assert d.health is Health.OK, d.fault_reason
            out["modbus_rtu read+write"] = scan_cost(d, cycles, pause_s=0.005)
        finally:
            d.close()
        master = RtuMaster(SerialSettings(bridge.driver_port, 115200))
        master.open()
        request = read_request(1, 2, 0, 8)
        for spaced in (False, True):
            samples = []
            try:
                for _ in range(min(cycles, 500)):
                    if spaced:
                        time.sleep(GAP_S)  # the line is idle: no t3.5 left to wait
                    t0 = time.perf_counter_ns()
                    master.transact(1, request[1:-2], 0.1, 0)
                    samples.append(time.perf_counter_ns() - t0)
            finally:
                if spaced:
                    master.close()
            key = "idle line" if spaced else "back to back, t3.5 gap"
            out[f"modbus FC2 ours, {key}"] = stats_us(samples)
        out.update(bench_pymodbus_client(bridge.driver_port, min(cycles, 500)))
    return out


def bench_pymodbus_client(port: str, n: int) -> dict[str, tuple[float, float, float]]:
    from pymodbus.client import ModbusSerialClient

    client = ModbusSerialClient(port, baudrate=115200, timeout=0.1, retries=0)
    if not client.connect():
        return {}
    out = {}
    try:
        for spaced in (False, True):
            samples = []
            for _ in range(n):
                if spaced:
                    time.sleep(GAP_S)
                t0 = time.perf_counter_ns()
                client.read_discrete_inputs(0, count=8, device_id=1)
                samples.append(time.perf_counter_ns() - t0)
            key = "idle line" if spaced else "back to back"
            out[f"modbus FC2 pymodbus sync, {key}"] = stats_us(samples)
    finally:
        client.close()
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=2000)
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    rows: dict[str, tuple[float, float, float]] = {}
    runs: list[tuple[str, Callable[[], Any]]] = [
        ("sim read+write", lambda: bench_sim(args.cycles)),
        ("gpio read+write (emulated chip)", lambda: bench_gpio(args.cycles)),
        ("mcp23017 read+write (emulated)", lambda: bench_i2c("mcp23017", args.cycles)),
        ("pcf8574 read+write (emulated)", lambda: bench_i2c("pcf8574", args.cycles)),
    ]
    for name, run in runs:
        rows[name] = run()
    rows.update(bench_canopen(min(args.cycles, 1000)))
    rows.update(bench_modbus(min(args.cycles, 1000)))
    print(f"{'what':<42} {'mean µs':>9} {'p99 µs':>9} {'max µs':>9}")  # noqa: T201
    for name, (mean, p99, worst) in rows.items():
        print(f"{name:<42} {mean:>9.1f} {p99:>9.1f} {worst:>9.1f}")  # noqa: T201
    print(f"(threads alive at the end: {threading.active_count()})")  # noqa: T201
    return 0


if __name__ == "__main__":
    sys.exit(main())
