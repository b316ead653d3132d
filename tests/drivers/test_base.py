"""drivers.base and drivers.registry: what every back-end inherits (the poll-thread hand-over
in both directions, staleness) and the lazy lookup by ``type``."""

from __future__ import annotations

import logging
import os
import re
import subprocess
import sys
import threading
from collections.abc import Iterator

import pytest

from drivers.base import Direction, DriverError, Health, PointKind, PolledDriver
from drivers.registry import DRIVERS, DriverImportError, driver_class
from tests.drivers.drvkit import FakeClock

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class ThreadDriver(PolledDriver):
    """A PolledDriver whose I/O thread runs ``job`` once per wake-up (test double)."""

    type_name = "thread"

    def __init__(self, clock: FakeClock) -> None:
        super().__init__("t", clock=clock)
        self.job: list[object] = []  # what the thread does next: a dict, an exception
        self._go = threading.Event()
        self._thread: threading.Thread | None = None
        self._quit = False

    def _check_point(self, point: str, direction: Direction) -> PointKind:
        return PointKind.BOOL

    def _start(self) -> None:
        self._quit = False
        self._thread = threading.Thread(target=self._run, name="thread-driver")
        self._thread.start()
        self.run({"I0": 0})

    def _stop(self) -> None:
        self._quit = True
        self._go.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def run(self, what: object) -> None:
        """Hand ``what`` to the I/O thread and wait until it has reported."""
        since = self.updates
        self.job.append(what)
        self._go.set()
        assert self.wait_for_update(3.0, since=since)

    def _run(self) -> None:
        while True:
            self._go.wait()
            self._go.clear()
            if self._quit:
                return
            while self.job:
                what = self.job.pop(0)
                if isinstance(what, BaseException):
                    self.report_error(what)
                else:
                    assert isinstance(what, dict)
                    self.publish_inputs(what)


@pytest.fixture
def td(clock: FakeClock) -> Iterator[ThreadDriver]:
    d = ThreadDriver(clock)
    d.add_point("I0", Direction.IN)
    d.add_point("Q0", Direction.OUT)
    d.open()
    assert d.health is Health.OK
    yield d
    d.close()


def test_a_bug_in_the_io_thread_is_raised_in_the_scan_thread(td: ThreadDriver) -> None:
    td.run(ZeroDivisionError("in the I/O thread"))
    with pytest.raises(ZeroDivisionError, match="in the I/O thread"):
        td.read()
    with pytest.raises(ZeroDivisionError):  # every scan, until the driver is reopened
        td.read()


@pytest.mark.parametrize("error", [OSError(5, "Input/output error"), DriverError("unit lost")])
def test_an_io_error_handed_over_as_error_is_a_fault(td: ThreadDriver, clock: FakeClock,
                                                     error: Exception) -> None:
    td.run(error)
    td.read()  # never raises for an I/O fault
    assert td.health is Health.FAULT and str(error) in (td.fault_reason or "")
    td.run({"I0": 1})  # the I/O side works again
    clock.advance(td.RECONNECT_MIN_S)
    td.read()
    assert td.health is Health.OK and td.inputs["I0"] == 1


def test_outputs_reach_the_io_side_only_when_changed(td: ThreadDriver) -> None:
    assert td.take_outputs() == {"Q0": 0}  # the first exchange writes the whole image
    td.write()
    assert td.take_outputs() is None
    td.outputs["Q0"] = True
    td.write()
    assert td.take_outputs() == {"Q0": 1}
    td.mark_outputs_dirty()
    assert td.take_outputs() == {"Q0": 1}


def test_inputs_older_than_the_limit_are_stale(td: ThreadDriver, clock: FakeClock,
                                               caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    assert td.stale_after_s is not None
    td.read()
    assert td.ok
    clock.advance(td.stale_after_s + 0.001)
    for _ in range(10):
        td.read()
    assert td.health is Health.STALE and not td.ok
    td.run({"I0": 1})
    td.read()
    assert td.health is Health.OK and td.inputs["I0"] == 1
    changes = [r.getMessage() for r in caplog.records if r.name == "drivers.base"]
    assert changes == ["driver t: inputs stale", "driver t: inputs fresh again"]


# -- registry -------------------------------------------------------------------------------
def test_registry_imports_no_bus_library_until_asked() -> None:
    code = ("import sys, drivers.registry, drivers.base; "
            "print(sorted(m for m in ('gpiod', 'smbus2', 'canopen', 'can', 'serial') "
            "if m in sys.modules))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, timeout=60)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]"


@pytest.mark.parametrize("type_name,module,package", [
    ("mcp23017", "smbus2", "smbus2"), ("pcf8574", "smbus2", "smbus2"),
    ("gpio", "gpiod", "gpiod"), ("canopen", "canopen", "canopen"),
    ("canopen", "can", "canopen"), ("modbus_rtu", "serial", "pyserial")])
def test_a_missing_library_names_the_package(monkeypatch: pytest.MonkeyPatch, type_name: str,
                                             module: str, package: str) -> None:
    driver_module = DRIVERS[type_name][0]
    for name in list(sys.modules):
        if name == module or name.startswith(module + ".") or name == driver_module:
            monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, module, None)  # import raises ModuleNotFoundError
    # softplc is no package of an index: this environment's pip and this checkout
    hint = (re.escape(f"{sys.executable} -m pip install -e '{ROOT}[gpio]' (on 32-bit ARM "
                      "pip compiles it: apt-get install gcc python3-dev first)")
            if package == "gpiod" else f"pip install {package}")  # gpiod: an extra
    with pytest.raises(DriverImportError, match=f"{hint}$") as exc:
        driver_class(type_name)
    assert f"driver type '{type_name}' needs the Python package '{package}'" in str(exc.value)
    if module != package:
        assert f"module '{module}' not found" in str(exc.value)


def test_unknown_type() -> None:
    with pytest.raises(KeyError):
        driver_class("profibus")


def test_plant_file_accepts_exactly_the_keys_each_driver_takes() -> None:
    from drivers.registry import DRIVER_KEYS

    assert set(DRIVER_KEYS) == set(DRIVERS)
    for type_name, keys in DRIVER_KEYS.items():
        assert set(keys) == set(driver_class(type_name).config_keys), type_name
