"""Linux GPIO lines through the character device (libgpiod v2 Python bindings, ``gpiod``).

One line request holds every bound line of the chip: inputs with the configured bias and
debounce (the kernel's), outputs initialised inactive (the next write sets what the image
holds). ``active_low`` is never set: the driver moves
physical levels only, and any inversion is the binding's (``invert: true``).

Points are line offsets on the chip: ``gpio.17``. Config::

    gpio: {type: gpio, chip: /dev/gpiochip0, bias: pull_up, debounce: 5ms}
"""

from __future__ import annotations

import datetime
import logging
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
        self.chip: str = self.params["chip"]
        self.bias: Bias = BIASES[self.params["bias"]]
        self._request: Any = None

    def line(self, point: str) -> int:
        return int(point)

    def where(self) -> str:
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
        try:
            self._request = gpiod.request_lines(
                self.chip, config=config, consumer=f"{self.CONSUMER_PREFIX}:{self.name}"
            )
        except ValueError as exc:  # gpiod: bad offset or setting
            raise DriverError(f"{self.chip}: {exc}") from exc
        except OSError as exc:
            raise DriverError(f"{self.chip}: cannot request lines "
                              f"{self.in_lines + self.out_lines}: {exc}") from exc
        return 0

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
