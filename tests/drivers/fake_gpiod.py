"""A GPIO chip as the kernel's character device (uAPI v2) shows it through libgpiod v2.

``FakeGpio.request_lines`` has the signature of ``gpiod.request_lines`` and is installed
over it by the tests (monkeypatch): production code never sees this module. Tests of a chip
named by its label also install ``FakeGpio.Chip`` over ``gpiod.Chip`` (its ``get_info``)
and ``FakeGpio.paths`` over ``drivers.gpio.chip_paths`` (the chips of the machine).

What is modelled, as the kernel does it:

* a pin has a physical level: an output drives it; an input follows what drives it from
  outside (``drive()``), else its bias (pull-up 1, pull-down 0), else ``floating_level``;
* ``active_low`` inverts between the physical level and the logical value that
  ``get_values``/``set_values``/``output_value`` carry;
* ``debounce_period``: an input change shorter than the period is not seen (on the chip's
  clock, so tests step time instead of sleeping);
* a line can be requested once (EBUSY), offsets beyond the chip fail (EINVAL), a missing
  chip fails (ENOENT), a removed chip fails every call (ENODEV), a released request raises
  ``gpiod.RequestReleasedError`` (releasing it again too);
* a chip has a label (``ChipInfo.label``); ``move`` gives it another path, as the kernel
  numbers a chip anew that comes back while its old number is still held;
* ``output_values`` of ``request_lines``, when given, override every output line's
  ``LineSettings.output_value`` (a line it omits starts INACTIVE), as libgpiod does.

The signatures are those of the installed ``gpiod`` 2.x package (test_gpio.py compares
them), so a driver that runs here calls the real bindings the same way.
"""

from __future__ import annotations

import datetime
import errno
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import gpiod
from gpiod.line import Bias, Direction, Value


def _offsets(key: Any) -> list[int]:
    if isinstance(key, (int, str)):
        return [int(key)]
    return [int(k) for k in key]


@dataclass
class LineState:
    """One line of the chip."""

    external: int | None = None  # level forced from outside, None: high impedance
    changes: list[tuple[int, int]] = field(default_factory=list)  # (ns, level) history
    settings: gpiod.LineSettings | None = None  # while requested
    logical_out: int = 0
    consumer: str | None = None


class FakeChip:
    """One /dev/gpiochipN."""

    def __init__(self, path: str, num_lines: int, clock: Callable[[], int],
                 label: str = "") -> None:
        self.path = path
        self.label = label
        self.num_lines = num_lines
        self.clock = clock
        self.lines = [LineState() for _ in range(num_lines)]
        self.removed = False
        #: a pin left floating (no bias, nothing driving) reads this level
        self.floating_level = 0
        #: every set_values call: {offset: physical level}
        self.writes: list[dict[int, int]] = []

    # -- the outside world ----------------------------------------------------------
    def drive(self, offset: int, level: int | None) -> None:
        """Drive a pin from outside (a switch, a sensor): 0, 1, or None (released)."""
        line = self.lines[offset]
        line.external = level
        line.changes.append((self.clock(), self._raw_input(line)))

    def level(self, offset: int) -> int:
        """The physical level on the pin now (what a voltmeter shows)."""
        line = self.lines[offset]
        s = line.settings
        if s is not None and s.direction is Direction.OUTPUT:
            return line.logical_out ^ int(s.active_low)
        return self._raw_input(line)

    def _raw_input(self, line: LineState) -> int:
        if line.external is not None:
            return line.external
        bias = line.settings.bias if line.settings is not None else Bias.AS_IS
        if bias is Bias.PULL_UP:
            return 1
        if bias is Bias.PULL_DOWN:
            return 0
        return self.floating_level

    def _debounced(self, line: LineState) -> int:
        assert line.settings is not None
        period = int(line.settings.debounce_period.total_seconds() * 1e9)
        now = self.clock()
        current = self._raw_input(line)
        if period <= 0:
            return current
        # the value seen is the last level that stayed put for the whole period
        history = [(t, v) for t, v in line.changes if t <= now]
        seen = history[0][1] if history else current
        for i, (t, v) in enumerate(history):
            end = history[i + 1][0] if i + 1 < len(history) else now
            if end - t >= period:
                seen = v
        return seen

    def _check(self) -> None:
        if self.removed:
            raise OSError(errno.ENODEV, "No such device", self.path)


class FakeLineRequest:
    """What ``gpiod.request_lines`` returns, for the fake chip."""

    def __init__(self, chip: FakeChip, offsets: list[int], consumer: str | None) -> None:
        self.chip = chip
        self.offsets = offsets
        self.lines = list(offsets)
        self.consumer = consumer
        self.released = False

    def _check_released(self) -> None:
        if self.released:
            raise gpiod.RequestReleasedError()

    def _alive(self) -> None:
        self._check_released()
        self.chip._check()

    def get_values(self, lines: Iterable[int | str] | None = None) -> list[Value]:
        self._alive()
        out = []
        for off in _offsets(lines or self.offsets):  # as libgpiod: [] or None reads all
            if off not in self.offsets:
                raise OSError(errno.EINVAL, "Invalid argument: line not requested")
            line = self.chip.lines[off]
            s = line.settings
            assert s is not None
            if s.direction is Direction.OUTPUT:
                logical = line.logical_out
            else:
                logical = self.chip._debounced(line) ^ int(s.active_low)
            out.append(Value.ACTIVE if logical else Value.INACTIVE)
        return out

    def get_value(self, line: int | str) -> Value:
        return self.get_values([line])[0]

    def set_values(self, values: dict[int | str, Value]) -> None:
        self._alive()
        written = {}
        for key, value in values.items():
            off = int(key)
            if off not in self.offsets:
                raise OSError(errno.EINVAL, "Invalid argument: line not requested")
            line = self.chip.lines[off]
            s = line.settings
            assert s is not None
            if s.direction is not Direction.OUTPUT:
                raise OSError(errno.EPERM, "Operation not permitted: line is an input")
            line.logical_out = 1 if value is Value.ACTIVE else 0
            written[off] = self.chip.level(off)
        self.chip.writes.append(written)

    def set_value(self, line: int | str, value: Value) -> None:
        self.set_values({line: value})

    def release(self) -> None:
        self._check_released()  # libgpiod: releasing twice raises RequestReleasedError
        self.released = True
        for off in self.offsets:
            line = self.chip.lines[off]
            # as the kernel: a released output keeps its level until someone else takes it
            line.settings = None
            line.consumer = None

    def __enter__(self) -> FakeLineRequest:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __bool__(self) -> bool:
        return not self.released


class FakeChipHandle:
    """What ``gpiod.Chip(path)`` returns, for what the driver asks of it: its info."""

    def __init__(self, chip: FakeChip) -> None:
        self.chip = chip

    def get_info(self) -> gpiod.ChipInfo:
        self.chip._check()
        return gpiod.ChipInfo(self.chip.path.rsplit("/", 1)[-1], self.chip.label,
                              self.chip.num_lines)

    def close(self) -> None:
        pass

    def __enter__(self) -> FakeChipHandle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class FakeGpio:
    """The kernel's GPIO chips by path; ``request_lines`` replaces ``gpiod.request_lines``."""

    def __init__(self, clock: Callable[[], int] | None = None) -> None:
        self.clock = clock or (lambda: 0)
        self.chips: dict[str, FakeChip] = {}
        #: every request made: (path, {offset: LineSettings}, consumer)
        self.requests: list[tuple[str, dict[int, gpiod.LineSettings], str | None]] = []

    def add_chip(self, path: str = "/dev/gpiochip0", num_lines: int = 54,
                 label: str = "") -> FakeChip:
        chip = FakeChip(path, num_lines, self.clock, label)
        self.chips[path] = chip
        return chip

    def move(self, chip: FakeChip, path: str) -> None:
        """The chip comes back at ``path`` (its old path is gone), lines free, levels kept."""
        del self.chips[chip.path]
        chip.path = path
        chip.removed = False
        for line in chip.lines:
            line.settings = None
            line.consumer = None
        self.chips[path] = chip

    def paths(self) -> list[str]:
        """What ``drivers.gpio.chip_paths`` returns: the chips there are."""
        return sorted(self.chips)

    def Chip(self, path: str) -> FakeChipHandle:  # gpiod.Chip(path)
        chip = self.chips.get(path)
        if chip is None:
            raise FileNotFoundError(errno.ENOENT, "No such file or directory", path)
        chip._check()
        return FakeChipHandle(chip)

    def request_lines(
        self,
        path: str,
        config: dict[Any, gpiod.LineSettings | None],
        consumer: str | None = None,
        event_buffer_size: int | None = None,
        output_values: dict[int | str, Value] | None = None,
    ) -> FakeLineRequest:
        chip = self.chips.get(path)
        if chip is None:
            raise FileNotFoundError(errno.ENOENT, "No such file or directory", path)
        chip._check()
        settings: dict[int, gpiod.LineSettings] = {}
        for key, s in config.items():
            for off in _offsets(key):
                if off in settings:
                    raise ValueError(f"line {off} given twice")
                settings[off] = s if s is not None else gpiod.LineSettings()
        for off in settings:
            if off >= chip.num_lines:
                raise OSError(errno.EINVAL, "Invalid argument", path)
            if chip.lines[off].settings is not None:
                raise OSError(errno.EBUSY, "Device or resource busy", path)
        for off, s in settings.items():
            line = chip.lines[off]
            line.settings = s
            line.consumer = consumer
            if s.direction is Direction.OUTPUT:
                # as Chip.request_lines: global output_values, when given, override every
                # line's LineSettings.output_value, and a line they omit starts INACTIVE
                value = (output_values.get(off, Value.INACTIVE) if output_values
                         else s.output_value)
                line.logical_out = 1 if value is Value.ACTIVE else 0
            else:
                line.changes.append((self.clock(), chip._raw_input(line)))
        self.requests.append((path, dict(settings), consumer))
        return FakeLineRequest(chip, sorted(settings), consumer)


def debounce_of(settings: gpiod.LineSettings) -> float:
    """The debounce period of a line's settings, in seconds."""
    period: datetime.timedelta = settings.debounce_period
    return period.total_seconds()
