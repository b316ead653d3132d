"""Linux GPIO lines through the character device (libgpiod v2 Python bindings, ``gpiod``).

One line request holds every bound line of the chip: inputs with the configured bias and
debounce (the kernel's), outputs initialised inactive (the next write sets what the image
holds). ``active_low`` is never set: the driver moves
physical levels only, and any inversion is the binding's (``invert: true``).

``chip`` names the chip by its character device (``/dev/gpiochip0``) or by its label
(``pinctrl-rp1``): a label is looked up among the chips at every open, so a chip that comes
back under another number (a removed chip whose old number is still held, a kernel that
numbers chips otherwise) is found again; a path is opened as it is.

Points are line offsets on the chip: ``gpio.17``. Config::

    gpio: {type: gpio, chip: pinctrl-rp1, bias: pull_up, debounce: 5ms}
"""

from __future__ import annotations

import datetime
import errno
import glob
import logging
import re
from collections.abc import Iterable
from typing import Any

import gpiod
from gpiod.line import Bias, Value
from gpiod.line import Direction as LineDirection

from drivers.bank import DigitalBank
from drivers.base import DriverError
from drivers.registry import GPIO_KEYS

log = logging.getLogger(__name__)

#: the declared choices of ``bias`` (drivers.registry) as libgpiod biases
BIASES = {"pull_up": Bias.PULL_UP, "pull_down": Bias.PULL_DOWN, "none": Bias.DISABLED}
#: the kernel's GPIO character devices
DEVICES = "/dev/gpiochip*"


def chip_paths() -> list[str]:
    """This machine's GPIO character devices, /dev/gpiochipN in the order of N."""
    def number(path: str) -> int:
        digits = re.search(r"[0-9]+$", path)
        return int(digits.group()) if digits else -1

    return sorted((p for p in glob.glob(DEVICES) if gpiod.is_gpiochip_device(p)),
                  key=lambda p: (number(p), p))


def chip_label(path: str) -> str:
    """The label of the chip at ``path`` (OSError if it cannot be opened)."""
    with gpiod.Chip(path) as chip:
        label: str = chip.get_info().label
        return label


def find_chip(label: str) -> str:
    """The character device of the one chip labelled ``label``; DriverError naming the
    chips there are if none is, or naming them if several are."""
    found: list[str] = []
    seen: list[str] = []
    for path in chip_paths():
        try:
            its = chip_label(path)
        except OSError as exc:
            seen.append(f"{path} (unreadable: {exc.strerror or exc})")
            continue
        seen.append(f"{path} '{its}'")
        if its == label:
            found.append(path)
    if len(found) == 1:
        return found[0]
    if not found:
        raise DriverError(f"no GPIO chip labelled '{label}' (chips: "
                          f"{', '.join(seen) or 'none'})")
    raise DriverError(f"{len(found)} GPIO chips are labelled '{label}' ({', '.join(found)}): "
                      "name one by its path")


class GpioDriver(DigitalBank):
    """GPIO lines of one chip. Reads and writes are one ioctl each, done in the scan; the
    kernel debounces (in hardware, or in software where the chip has none)."""

    type_name = "gpio"
    config_keys = GPIO_KEYS
    #: highest line offset accepted in a point name (the chip may have fewer lines)
    MAX_OFFSET = 1023
    #: consumer label shown by ``gpioinfo``
    CONSUMER_PREFIX = "softplc"

    def _init(self) -> None:
        super()._init()
        #: the chip as configured: a path, or a label (looked up at every open)
        self.chip: str = self.params["chip"]
        self.by_label = not self.chip.startswith("/")
        #: the character device opened (for a label: the one found at the last open)
        self.path: str | None = None if self.by_label else self.chip
        self.bias: Bias = BIASES[self.params["bias"]]
        self._request: Any = None
        self._label: str | None = None  # of the chip last opened by path

    def line(self, point: str) -> int:
        return int(point)

    def where(self) -> str:
        if self.by_label and self.path is not None:
            return f"{self.chip} ({self.path})"
        return self.chip

    def _attach(self) -> int:
        config: dict[Iterable[int | str] | int | str, gpiod.LineSettings | None] = {}
        if self.in_lines:
            config[tuple(self.in_lines)] = gpiod.LineSettings(
                direction=LineDirection.INPUT,
                bias=self.bias,
                active_low=False,
                debounce_period=datetime.timedelta(seconds=self.debounce_s),
            )
        if self.out_lines:  # inactive: the next write sets what the image holds
            config[tuple(self.out_lines)] = gpiod.LineSettings(
                direction=LineDirection.OUTPUT,
                active_low=False,
                output_value=Value.INACTIVE,
            )
        if not config:
            return 0
        path = self.path = find_chip(self.chip) if self.by_label else self.chip
        try:
            self._request = gpiod.request_lines(
                path, config=config, consumer=f"{self.CONSUMER_PREFIX}:{self.name}"
            )
        except ValueError as exc:  # gpiod: bad offset or setting
            raise DriverError(f"{self.where()}: {exc}") from exc
        except OSError as exc:
            raise DriverError(f"{self.where()}: cannot request lines "
                              f"{self.in_lines + self.out_lines}: {exc}"
                              f"{self._moved(exc)}") from exc
        if not self.by_label:
            try:
                self._label = chip_label(path)
            except OSError:  # pragma: no cover - it was just opened
                self._label = None
        return 0

    def _moved(self, exc: OSError) -> str:
        """Where the chip last opened at the configured path is now, when that path is
        gone: the words that end the fault ("" if unknown)."""
        if self.by_label or self._label is None or exc.errno not in (errno.ENOENT,
                                                                     errno.ENODEV):
            return ""
        try:
            now = find_chip(self._label)
        except DriverError:
            return ""
        if now == self.chip:
            return ""
        return (f"; the chip labelled '{self._label}' that was there is now {now}: name "
                f"it by its label (chip: {self._label}) to follow it")

    def _read_word(self) -> int:
        if not self.in_lines:
            return 0
        word = 0
        for n, v in zip(self.in_lines, self._request.get_values(self.in_lines), strict=True):
            if v is Value.ACTIVE:
                word |= 1 << n
        return word

    def _write_word(self, word: int, changed: int) -> None:
        self._request.set_values({n: Value.ACTIVE if word >> n & 1 else Value.INACTIVE
                                  for n in self.out_lines if changed >> n & 1})

    def _detach(self) -> None:
        req, self._request = self._request, None
        if req is not None:
            req.release()
