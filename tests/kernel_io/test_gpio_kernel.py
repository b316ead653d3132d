"""The gpio driver on the kernel's GPIO character device: a gpio-sim chip of its own per
test (tests/kernel_io/kio.py). Outputs are read back through the simulated line's value,
inputs driven through its pull; bias, debounce and EBUSY are the kernel's own."""

from __future__ import annotations

import time

import gpiod
import pytest
from gpiod.line import Direction as LineDirection

from drivers.base import Direction, Health
from drivers.gpio import GpioDriver
from tests.drivers.drvkit import FakeClock, wait_until
from tests.kernel_io.kio import SimChip

pytestmark = pytest.mark.kernel_io

IN_A, IN_B, OUT_A, OUT_B = 0, 1, 4, 5


def make(chip: str, clock: FakeClock, **cfg: object) -> GpioDriver:
    d = GpioDriver("gpio", {"chip": chip, **cfg}, clock=clock)
    for line in (IN_A, IN_B):
        d.add_point(str(line), Direction.IN)
    for line in (OUT_A, OUT_B):
        d.add_point(str(line), Direction.OUT)
    return d


def test_outputs_and_inputs_through_the_simulated_lines(sim_chip: SimChip,
                                                       clock: FakeClock) -> None:
    sim_chip.pull(OUT_A, 1)  # what the line showed before: the request makes it an output
    d = make(sim_chip.path, clock)
    d.open()
    assert d.health is Health.OK, d.fault_reason
    assert sim_chip.value(OUT_A) == 0 and sim_chip.value(OUT_B) == 0  # requested inactive
    d.outputs[str(OUT_A)] = 1
    d.write()
    assert (sim_chip.value(OUT_A), sim_chip.value(OUT_B)) == (1, 0)
    d.outputs[str(OUT_A)], d.outputs[str(OUT_B)] = 0, 1
    d.write()
    assert (sim_chip.value(OUT_A), sim_chip.value(OUT_B)) == (0, 1)
    for a, b in ((1, 0), (0, 1), (1, 1)):
        sim_chip.pull(IN_A, a)
        sim_chip.pull(IN_B, b)
        d.read()
        assert d.inputs == {str(IN_A): a, str(IN_B): b}
    info = gpiod.Chip(sim_chip.path).get_line_info(OUT_A)
    assert info.consumer == "softplc:gpio" and info.direction is LineDirection.OUTPUT
    assert not info.active_low
    d.close()
    assert sim_chip.value(OUT_B) == 0  # close: the safe state before the lines go


@pytest.mark.parametrize("bias, level", [("pull_up", 1), ("pull_down", 0)])
def test_the_bias_is_the_kernels(sim_chip: SimChip, clock: FakeClock, bias: str,
                                 level: int) -> None:
    sim_chip.pull(IN_A, 1 - level)
    d = make(sim_chip.path, clock, bias=bias)
    d.open()
    assert d.health is Health.OK, d.fault_reason
    assert sim_chip.pull_of(IN_A) == bias.replace("_", "-")  # the chip was told
    d.read()
    assert d.inputs[str(IN_A)] == level and d.inputs[str(IN_B)] == level
    d.close()


def test_without_bias_the_line_is_left_as_the_world_pulls_it(sim_chip: SimChip,
                                                            clock: FakeClock) -> None:
    sim_chip.pull(IN_A, 1)
    d = make(sim_chip.path, clock, bias="none")
    d.open()
    d.read()
    assert d.inputs[str(IN_A)] == 1 and sim_chip.pull_of(IN_A) == "pull-up"
    d.close()


#: the debounce period of the kernel test, s, and the longest pulse it counts as short
DEBOUNCE_S = 0.05
SHORT_S = DEBOUNCE_S / 2


def test_the_kernel_debounces_the_inputs(sim_chip: SimChip, clock: FakeClock) -> None:
    """A pulse shorter than the period is never seen; a level held is seen, never before
    the period. Real time (the kernel's): a pulse is made, from a quiet line, until one is
    short enough (a busy machine may stretch it), and only such a pulse is judged."""
    d = make(sim_chip.path, clock, debounce=DEBOUNCE_S)
    d.open()
    assert d.health is Health.OK, d.fault_reason

    def level() -> int:
        d.read()
        return int(d.inputs[str(IN_A)])

    assert level() == 0
    for _ in range(20):
        begin = time.monotonic()
        sim_chip.pull(IN_A, 1)
        sim_chip.pull(IN_A, 0)
        fell = time.monotonic()
        if fell - begin < SHORT_S:
            break
        # a long pulse may be taken: the next starts from a quiet line, the debouncer's
        # timer run out (two periods after the edge) and the level back at 0
        assert wait_until(lambda: time.monotonic() - fell > 2 * DEBOUNCE_S  # noqa: B023
                          and level() == 0, timeout=10)
    else:
        pytest.fail(f"no pulse shorter than {SHORT_S * 1000:.0f} ms in 20 tries")
    width = fell - begin
    end = time.monotonic() + 4 * DEBOUNCE_S
    while time.monotonic() < end:
        assert level() == 0, f"a pulse of {width * 1000:.1f} ms was seen"
    held = time.monotonic()
    sim_chip.pull(IN_A, 1)
    assert wait_until(lambda: level() == 1, timeout=10)
    assert time.monotonic() - held >= DEBOUNCE_S
    d.close()


def test_a_line_held_by_another_consumer_is_a_fault_until_released(sim_chip: SimChip,
                                                                  clock: FakeClock) -> None:
    other = gpiod.request_lines(sim_chip.path, consumer="other", config={
        IN_B: gpiod.LineSettings(direction=LineDirection.INPUT)})
    d = make(sim_chip.path, clock)
    d.open()
    assert d.health is Health.FAULT
    assert "Device or resource busy" in (d.fault_reason or ""), d.fault_reason
    other.release()
    clock.advance(d.RECONNECT_MIN_S)
    d.read()
    assert d.health is Health.OK, d.fault_reason
    d.close()


def test_a_chip_removed_and_back_is_found_by_its_label(sim_chip: SimChip,
                                                      clock: FakeClock) -> None:
    """The kernel numbers a chip that comes back anew while the old one is still held
    (gpiochip0 becomes gpiochip1): named by its label, the driver finds it again."""
    d = make(sim_chip.label, clock, on_fault="zero")
    d.open()
    assert d.health is Health.OK, d.fault_reason
    assert sim_chip.path in d.where() and sim_chip.label in d.where()
    sim_chip.pull(IN_A, 1)
    d.outputs[str(OUT_A)] = 1
    d.read()
    d.write()
    assert d.inputs[str(IN_A)] == 1 and sim_chip.value(OUT_A) == 1
    was = sim_chip.path
    sim_chip.remove()
    d.read()
    assert d.health is Health.FAULT and "No such device" in (d.fault_reason or "")
    assert d.inputs[str(IN_A)] == 0  # on_fault: zero
    sim_chip.restore()
    assert sim_chip.path != was, "the kernel gave the chip its old number back"
    sim_chip.pull(IN_A, 1)
    clock.advance(d.RECONNECT_MIN_S)
    d.read()
    assert d.health is Health.OK, d.fault_reason
    assert sim_chip.path in d.where()
    d.write()
    assert d.inputs[str(IN_A)] == 1 and sim_chip.value(OUT_A) == 1  # written again
    d.close()


def test_a_chip_named_by_path_that_comes_back_elsewhere_is_said_where(
        sim_chip: SimChip, clock: FakeClock) -> None:
    """A path is a path: the driver does not follow the chip to its new number, but its
    fault says where the chip of that label went and how to follow it."""
    d = make(sim_chip.path, clock)
    d.open()
    was = sim_chip.path
    sim_chip.remove()
    d.read()
    assert d.health is Health.FAULT
    sim_chip.restore()
    for _ in range(3):
        clock.advance(d.RECONNECT_MAX_S)
        d.read()
    assert d.health is Health.FAULT
    reason = d.fault_reason or ""
    assert was in reason and "No such file or directory" in reason, reason
    assert f"'{sim_chip.label}'" in reason and sim_chip.path in reason, reason
    d.close()
