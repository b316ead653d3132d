"""GPIO driver against the fake character device, plus an opt-in test on a real chip."""

from __future__ import annotations

import errno
import glob
import inspect
import os
from collections.abc import Callable

import gpiod
import pytest
from gpiod.line import Bias, Value
from gpiod.line import Direction as LineDirection

import drivers.gpio
from drivers.base import Direction, Health, PointError
from drivers.config import ConfigError
from drivers.gpio import GpioDriver
from tests.drivers.drvkit import FakeClock, wait_until
from tests.drivers.fake_gpiod import FakeChipHandle, FakeGpio, debounce_of


@pytest.fixture
def kernel(monkeypatch: pytest.MonkeyPatch, clock: FakeClock) -> FakeGpio:
    k = FakeGpio(clock)
    k.add_chip("/dev/gpiochip0", 54, label="pinctrl-bcm2711")
    monkeypatch.setattr(gpiod, "request_lines", k.request_lines)
    monkeypatch.setattr(gpiod, "Chip", k.Chip)
    monkeypatch.setattr(drivers.gpio, "chip_paths", k.paths)
    return k


def make(clock: FakeClock, **cfg: object) -> GpioDriver:
    d = GpioDriver("gpio", {"chip": "/dev/gpiochip0", **cfg}, clock=clock)
    d.add_point("17", Direction.IN)
    d.add_point("27", Direction.IN)
    d.add_point("22", Direction.OUT)
    d.add_point("23", Direction.OUT)
    return d


def test_one_request_physical_levels_no_active_low(kernel: FakeGpio, clock: FakeClock) -> None:
    d = make(clock, bias="pull_up", debounce="5ms")
    d.open()
    assert d.health is Health.OK
    assert len(kernel.requests) == 1
    path, settings, consumer = kernel.requests[0]
    assert path == "/dev/gpiochip0" and consumer == "softplc:gpio"
    assert sorted(settings) == [17, 22, 23, 27]
    for off in (17, 27):
        s = settings[off]
        assert s.direction is LineDirection.INPUT and s.bias is Bias.PULL_UP
        assert s.active_low is False and debounce_of(s) == pytest.approx(0.005)
    for off in (22, 23):
        assert settings[off].direction is LineDirection.OUTPUT
        assert settings[off].active_low is False
    chip = kernel.chips["/dev/gpiochip0"]
    # outputs start inactive, before any write
    assert chip.level(22) == 0 and chip.level(23) == 0
    # a floating input with pull-up reads 1; an NC contact pulling to ground reads 0
    chip.drive(27, 0)
    d.read()
    assert d.inputs == {"17": 1, "27": 1}  # not yet stable for the 5 ms debounce
    clock.advance(0.006)
    d.read()
    assert d.inputs == {"17": 1, "27": 0}
    d.close()


def test_debounce_given_in_seconds_and_glitch_filtered(kernel: FakeGpio, clock: FakeClock) -> None:
    d = make(clock, debounce=0.01)
    d.open()
    chip = kernel.chips["/dev/gpiochip0"]
    chip.drive(17, 1)
    clock.advance(0.02)
    d.read()
    assert d.inputs["17"] == 1
    chip.drive(17, 0)  # a 2 ms bounce
    clock.advance(0.002)
    chip.drive(17, 1)
    clock.advance(0.02)
    d.read()
    assert d.inputs["17"] == 1
    d.close()


def test_writes_only_changed_lines_and_safe_state(kernel: FakeGpio, clock: FakeClock) -> None:
    d = make(clock)
    d.open()
    chip = kernel.chips["/dev/gpiochip0"]
    chip.writes.clear()
    d.outputs["22"] = True
    d.write()
    d.write()  # nothing changed: no ioctl
    assert chip.writes == [{22: 1}]
    assert chip.level(22) == 1
    d.outputs["23"] = 1
    d.write()
    assert chip.writes[-1] == {23: 1}
    d.safe_state()
    assert chip.level(22) == 0 and chip.level(23) == 0
    d.close()
    d.close()  # idempotent
    assert d.health is Health.CLOSED


def test_busy_line_faults_with_reason(kernel: FakeGpio, clock: FakeClock) -> None:
    other = GpioDriver("other", {}, clock=clock)
    other.add_point("17", Direction.OUT)
    other.open()
    d = make(clock)
    d.open()
    assert d.health is Health.FAULT
    assert "busy" in (d.fault_reason or "").lower()
    other.close()
    clock.advance(d.RECONNECT_MIN_S)
    d.read()
    assert d.health is Health.OK
    d.close()


def test_chip_removed_then_back(kernel: FakeGpio, clock: FakeClock) -> None:
    d = make(clock, on_fault="zero")
    d.open()
    chip = kernel.chips["/dev/gpiochip0"]
    chip.drive(17, 1)
    d.read()
    assert d.inputs["17"] == 1
    chip.removed = True
    d.read()
    assert d.health is Health.FAULT and "No such device" in (d.fault_reason or "")
    assert d.inputs["17"] == 0  # on_fault: zero
    chip.removed = False
    d.read()
    assert d.health is Health.FAULT  # no retry before the back-off delay
    clock.advance(d.RECONNECT_MIN_S)
    d.read()
    assert d.health is Health.OK and d.inputs["17"] == 1
    d.close()


# -- a chip named by its label -------------------------------------------------------------
def test_a_label_names_the_chip_found_at_each_open(kernel: FakeGpio, clock: FakeClock) -> None:
    """A chip that comes back under another number (the kernel keeps the old one while it
    is held) is found again by its label; the fault and where() say which device."""
    kernel.add_chip("/dev/gpiochip1", 8, label="raspberrypi-exp-gpio")
    d = make(clock, chip="pinctrl-bcm2711", on_fault="zero")
    d.open()
    assert d.health is Health.OK, d.fault_reason
    assert kernel.requests[-1][0] == "/dev/gpiochip0"
    assert d.where() == "pinctrl-bcm2711 (/dev/gpiochip0)"
    chip = kernel.chips["/dev/gpiochip0"]
    chip.drive(17, 1)
    d.read()
    assert d.inputs["17"] == 1
    chip.removed = True
    d.read()
    assert d.health is Health.FAULT
    assert d.fault_reason == ("pinctrl-bcm2711 (/dev/gpiochip0): [Errno 19] No such device: "
                              "'/dev/gpiochip0'")
    kernel.move(chip, "/dev/gpiochip2")
    clock.advance(d.RECONNECT_MIN_S)
    d.read()
    assert d.health is Health.OK, d.fault_reason
    assert kernel.requests[-1][0] == "/dev/gpiochip2" and d.inputs["17"] == 1
    assert d.where() == "pinctrl-bcm2711 (/dev/gpiochip2)"
    d.close()


def test_a_label_no_chip_has_is_a_fault_naming_the_chips(kernel: FakeGpio,
                                                         clock: FakeClock) -> None:
    kernel.add_chip("/dev/gpiochip10", 8, label="raspberrypi-exp-gpio")
    d = make(clock, chip="pinctrl-rp1")
    d.open()
    assert d.health is Health.FAULT
    assert d.fault_reason == ("no GPIO chip labelled 'pinctrl-rp1' (chips: /dev/gpiochip0 "
                              "'pinctrl-bcm2711', /dev/gpiochip10 'raspberrypi-exp-gpio')")
    assert kernel.requests == []
    kernel.add_chip("/dev/gpiochip4", 54, label="pinctrl-rp1")  # a later kernel's driver
    clock.advance(d.RECONNECT_MIN_S)
    d.read()
    assert d.health is Health.OK, d.fault_reason
    assert kernel.requests[-1][0] == "/dev/gpiochip4"
    d.close()


def test_a_label_two_chips_have_is_refused(kernel: FakeGpio, clock: FakeClock) -> None:
    kernel.add_chip("/dev/gpiochip1", 54, label="pinctrl-bcm2711")
    d = make(clock, chip="pinctrl-bcm2711")
    d.open()
    assert d.health is Health.FAULT
    assert d.fault_reason == ("2 GPIO chips are labelled 'pinctrl-bcm2711' (/dev/gpiochip0, "
                              "/dev/gpiochip1): name one by its path")
    assert kernel.requests == []
    d.close()


def test_a_path_is_not_followed_but_the_fault_says_where_the_chip_went(
        kernel: FakeGpio, clock: FakeClock) -> None:
    d = make(clock)
    d.open()
    chip = kernel.chips["/dev/gpiochip0"]
    chip.removed = True
    d.read()
    kernel.move(chip, "/dev/gpiochip1")
    clock.advance(d.RECONNECT_MIN_S)
    d.read()
    assert d.health is Health.FAULT
    assert d.fault_reason == (
        "/dev/gpiochip0: cannot request lines [17, 27, 22, 23]: [Errno 2] No such file or "
        "directory: '/dev/gpiochip0'; the chip labelled 'pinctrl-bcm2711' that was there is "
        "now /dev/gpiochip1: name it by its label (chip: pinctrl-bcm2711) to follow it")
    d.close()


@pytest.mark.parametrize("chip", ["pinctrl-rp1", "INT3450:00", "gpio-sim.0-node0",
                                  "/dev/gpiochip4", "a" * 31])
def test_chip_is_a_path_or_a_label(chip: str) -> None:
    assert GpioDriver("gpio", {"chip": chip}).chip == chip


@pytest.mark.parametrize("chip", ["gpiochip0", "", " pinctrl-rp1", "pinctrl-rp1 ", "a" * 32,
                                  "pin\nctrl", "/"])
def test_chip_that_is_neither_a_path_nor_a_label_is_refused(chip: str) -> None:
    with pytest.raises(ConfigError, match="its character device such as /dev/gpiochip0"):
        GpioDriver("gpio", {"chip": chip})


@pytest.mark.parametrize("point", ["gpio17", "-1", "1024", "017", "A0", ""])
def test_bad_points(point: str, clock: FakeClock) -> None:
    d = GpioDriver("gpio", {}, clock=clock)
    with pytest.raises(PointError):
        d.add_point(point, Direction.IN)


def test_point_in_both_directions_rejected(clock: FakeClock) -> None:
    d = GpioDriver("gpio", {}, clock=clock)
    d.add_point("4", Direction.OUT)
    with pytest.raises(PointError, match="already bound as an output"):
        d.add_point("4", Direction.IN)


@pytest.mark.parametrize("cfg", [{"bias": "up"}, {"debounce": "5 parsecs"}, {"speed": 1}])
def test_bad_config(cfg: dict[str, object]) -> None:
    with pytest.raises(ConfigError):
        GpioDriver("gpio", cfg)


# -- the fake is the kernel as libgpiod v2 shows it ----------------------------------------
def test_fake_has_the_signatures_of_the_real_bindings() -> None:
    from tests.drivers.fake_gpiod import FakeLineRequest

    def params(fn: Callable[..., object]) -> list[tuple[str, object]]:
        return [(p.name, p.default) for p in inspect.signature(fn).parameters.values()
                if p.name != "self"]

    assert params(FakeGpio.request_lines) == params(gpiod.request_lines)
    assert params(FakeGpio.Chip) == params(gpiod.Chip.__init__)
    assert params(FakeChipHandle.get_info) == params(gpiod.Chip.get_info)
    for name in ("get_values", "get_value", "set_values", "set_value", "release"):
        assert params(getattr(FakeLineRequest, name)) == params(
            getattr(gpiod.LineRequest, name)), name


def test_fake_applies_active_low_as_the_kernel(kernel: FakeGpio) -> None:
    chip = kernel.chips["/dev/gpiochip0"]
    req = gpiod.request_lines("/dev/gpiochip0", config={
        5: gpiod.LineSettings(direction=LineDirection.INPUT, active_low=True,
                              bias=Bias.PULL_UP),
        6: gpiod.LineSettings(direction=LineDirection.OUTPUT, active_low=True,
                              output_value=Value.INACTIVE)})
    assert chip.level(6) == 1  # inactive on an active-low line: the pin is high
    assert req.get_values([5, 6]) == [Value.INACTIVE, Value.INACTIVE]  # pulled up: inactive
    chip.drive(5, 0)
    assert req.get_value(5) is Value.ACTIVE
    req.set_values({6: Value.ACTIVE})
    assert chip.level(6) == 0 and chip.writes[-1] == {6: 0}
    assert req.get_values() == [Value.ACTIVE, Value.ACTIVE]  # no list: every line
    req.release()
    with pytest.raises(gpiod.RequestReleasedError):
        req.get_values()
    with pytest.raises(gpiod.RequestReleasedError):
        req.release()


def test_fake_global_output_values_override_settings(kernel: FakeGpio) -> None:
    chip = kernel.chips["/dev/gpiochip0"]
    on = gpiod.LineSettings(direction=LineDirection.OUTPUT, output_value=Value.ACTIVE)
    req = gpiod.request_lines("/dev/gpiochip0", config={(7, 8): on},
                              output_values={8: Value.ACTIVE})
    assert chip.level(7) == 0 and chip.level(8) == 1  # 7 not in output_values: inactive
    with pytest.raises(OSError, match="Device or resource busy"):
        gpiod.request_lines("/dev/gpiochip0", config={7: None})
    with pytest.raises(OSError) as exc:
        req.set_values({9: Value.ACTIVE})
    assert exc.value.errno == errno.EINVAL
    req.release()


def test_driver_never_passes_active_low_nor_global_values(kernel: FakeGpio,
                                                         clock: FakeClock) -> None:
    """The driver moves physical levels: inversion is the binding's job."""
    d = make(clock, bias="pull_down")
    d.open()
    chip = kernel.chips["/dev/gpiochip0"]
    chip.drive(17, 1)
    d.outputs["22"] = 1
    d.read()
    d.write()
    assert d.inputs["17"] == 1 and chip.level(22) == 1
    assert all(not s.active_low for s in kernel.requests[0][1].values())
    d.close()
    assert chip.level(22) == 0  # close: safe state before the lines are released


# -- opt-in: a real chip, with one output wired to one input ----------------------------
REAL = os.environ.get("SOFTPLC_TEST_GPIO", "")


@pytest.mark.skipif(not glob.glob("/dev/gpiochip*"), reason="no /dev/gpiochip* on this machine")
@pytest.mark.skipif(not REAL, reason="set SOFTPLC_TEST_GPIO=/dev/gpiochipN:OUT:IN (line OUT "
                    "wired to line IN) to run on real hardware")
def test_real_chip_loopback() -> None:
    chip, out, inp = REAL.rsplit(":", 2)
    d = GpioDriver("gpio", {"chip": chip, "bias": "pull_down"})
    d.add_point(out, Direction.OUT)
    d.add_point(inp, Direction.IN)
    d.open()

    def read() -> int:
        d.read()
        return int(d.inputs[inp])

    try:
        assert d.health is Health.OK, d.fault_reason
        for level in (1, 0, 1, 0):
            d.outputs[out] = level
            d.write()
            # a wire is instant; the kernel_io guest's simulated one polls (1 ms)
            assert wait_until(lambda: read() == level, timeout=5), level  # noqa: B023
    finally:
        d.close()
