"""Test parts for the daemon: a chart and plant, a driver that records what it was told to
write and can be made to fail on demand, and a polling helper."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from drivers.base import Direction, Driver, DriverError, PointKind

if TYPE_CHECKING:
    from runtime.controller.daemon import Daemon

CHART = """\
grafcet: Runner
inputs: [iGo]
outputs: [oRun, oLamp]
memory:
  sN: {init: 0, retain: true}
  sDiv: 1
  sQ: 0
steps:
  gsIdle: {initial: true}
  gsRun: {max: 200ms, actions: [oRun, "N sN := sN + 1"]}
transitions:
  - {from: gsIdle, to: gsRun, when: iGo}
  - {from: gsRun, to: gsIdle, when: "iGo'"}
post:
  - oLamp := gsRun.X
  - sQ := 100 / sDiv
"""


def plant_yaml(cycle: str = "10ms", watchdog: str = "100ms", retain: str | None = None,
               interval: str = "1s", on_fault: str = "stop", extra: str = "",
               realtime: str | None = None) -> str:
    plc = f"  cycle: {cycle}\n  watchdog: {watchdog}\n  retain_interval: {interval}\n"
    if retain:
        plc += f"  retain: {retain}\n"
    if realtime is not None:
        plc += f"  realtime: {realtime}\n"
    return (f"plc:\n{plc}drivers:\n  io: {{type: sim, on_fault: {on_fault}}}\n"
            "instances:\n  m:\n    grafcet: runner.yaml\n"
            "    inputs: {iGo: io.I0}\n    outputs: {oRun: io.Q0, oLamp: io.Q1}\n" + extra)


class RecordingDriver(Driver):
    """In-memory I/O that keeps every output image it was asked to send, and fails when
    told to: ``fail_with`` (an exception raised by the next reads), ``block_s`` (the next
    read sleeps that long, as a hung bus call would)."""

    type_name = "recording"

    def __init__(self, name: str = "io", config: Mapping[str, Any] | None = None) -> None:
        super().__init__(name, config)
        self.lock = threading.Lock()
        #: ("safe" | "write", output image) in the order they reached the "bus"
        self.sent: list[tuple[str, dict[str, int]]] = []
        self.reads = 0
        self.fail_with: BaseException | None = None
        self.block_s = 0.0
        self.blocked = threading.Event()  # set while a read is blocked
        self.wrote_safe = threading.Event()
        self._in_safe = False
        self.RECONNECT_MIN_S = 0.02  # type: ignore[misc]  # this instance only

    def _check_point(self, point: str, direction: Direction) -> PointKind:
        return PointKind.BOOL

    def _open(self) -> None:
        if isinstance(self.fail_with, DriverError):
            raise self.fail_with

    def _read(self) -> None:
        self.reads += 1
        if self.block_s:
            delay, self.block_s = self.block_s, 0.0
            self.blocked.set()
            time.sleep(delay)
            self.blocked.clear()
        if self.fail_with is not None:
            raise self.fail_with

    def _write(self) -> None:
        image = {p: int(bool(v)) for p, v in self.outputs.items()}
        with self.lock:
            self.sent.append(("safe" if self._in_safe else "write", image))
        if self._in_safe:
            self.wrote_safe.set()

    def _safe_state(self) -> None:
        self._in_safe = True
        try:
            self._write()
        finally:
            self._in_safe = False

    def _close(self) -> None:
        pass

    def last(self) -> tuple[str, dict[str, int]]:
        with self.lock:
            return self.sent[-1]

    def energised_after(self, index: int) -> list[tuple[str, dict[str, int]]]:
        """Images sent after position ``index`` with any output on."""
        with self.lock:
            return [s for s in self.sent[index:] if any(s[1].values())]


#: make_daemon(start=True, **plant_yaml options) -> (daemon, its recording driver)
MakeDaemon = Callable[..., "tuple[Daemon, RecordingDriver]"]


def wait_until(pred: Callable[[], bool], timeout: float = 5.0, what: str = "") -> None:
    """Poll ``pred`` until it holds; fail after ``timeout`` seconds (a generous bound for a
    loaded machine, never an assertion about speed)."""
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what or pred}")
        time.sleep(0.005)
