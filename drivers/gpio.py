"""Linux GPIO lines through the character device (libgpiod v2 Python bindings, ``gpiod``).

One line request holds every bound line of the chip: inputs with the configured bias and
debounce, outputs initialised inactive. ``active_low`` is never set: the driver moves
physical levels only, and any inversion is the binding's (``invert: true``).

Points are line offsets on the chip: ``gpio.17``. Config::

    gpio: {type: gpio, chip: /dev/gpiochip0, bias: pull_up, debounce: 5ms}
"""

from __future__ import annotations

import datetime
import logging
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import gpiod
from gpiod.line import Bias, Value
from gpiod.line import Direction as LineDirection

from drivers.base import Direction, Driver, DriverError, PointKind, as_bit
from drivers.registry import GPIO_KEYS, POINTS

log = logging.getLogger(__name__)

#: the declared choices of ``bias`` (drivers.registry) as libgpiod biases
BIASES = {"pull_up": Bias.PULL_UP, "pull_down": Bias.PULL_DOWN, "none": Bias.DISABLED}


class GpioDriver(Driver):
    """GPIO lines of one chip. Reads and writes are one ioctl each, done in the scan."""

    type_name = "gpio"
    config_keys = GPIO_KEYS
    ONE_DIRECTION_PER_POINT = True
    #: highest line offset accepted in a point name (the chip may have fewer lines)
    MAX_OFFSET = 1023
    #: consumer label shown by ``gpioinfo``
    CONSUMER_PREFIX = "softplc"

    def __init__(
        self,
        name: str,
        config: Mapping[str, Any] | None = None,
        *,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        super().__init__(name, config, clock=clock)
        self.chip: str = self.params["chip"]
        self.bias: Bias = BIASES[self.params["bias"]]
        #: debounce period of the inputs, seconds (0: none)
        self.debounce_s: float = self.params["debounce"]
        self._request: Any = None
        self._in_offsets: list[int] = []
        self._in_points: list[str] = []
        self._in_pos: list[int] = []  # the input points' positions in the image
        self._last_written: dict[int, int] | None = None

    def _check_point(self, point: str, direction: Direction) -> PointKind:
        return POINTS[self.type_name].check(self.name, point, direction)

    def _open(self) -> None:
        self._in_points = sorted(self.inputs, key=int)
        self._in_offsets = [int(p) for p in self._in_points]
        self._in_pos = [self.inputs.index[p] for p in self._in_points]
        out_offsets = sorted(int(p) for p in self.outputs)
        config: dict[Iterable[int | str] | int | str, gpiod.LineSettings | None] = {}
        if self._in_offsets:
            config[tuple(self._in_offsets)] = gpiod.LineSettings(
                direction=LineDirection.INPUT,
                bias=self.bias,
                active_low=False,
                debounce_period=datetime.timedelta(seconds=self.debounce_s),
            )
        if out_offsets:
            config[tuple(out_offsets)] = gpiod.LineSettings(
                direction=LineDirection.OUTPUT,
                active_low=False,
                output_value=Value.INACTIVE,
            )
        if not config:
            return
        try:
            self._request = gpiod.request_lines(
                self.chip, config=config, consumer=f"{self.CONSUMER_PREFIX}:{self.name}"
            )
        except ValueError as exc:  # gpiod: bad offset or setting
            raise DriverError(f"{self.chip}: {exc}") from exc
        except OSError as exc:
            raise DriverError(f"{self.chip}: cannot request lines "
                              f"{self._in_offsets + out_offsets}: {exc}") from exc
        self._last_written = {o: 0 for o in out_offsets}

    def _read(self) -> None:
        if not self._in_offsets:
            return
        values = self._request.get_values(self._in_offsets)
        vals = self.inputs.vals
        for i, v in zip(self._in_pos, values, strict=True):
            vals[i] = v is Value.ACTIVE

    def _write(self) -> None:
        last = self._last_written
        if last is None:
            return
        changed = {}
        out = self.outputs
        for point, v in zip(out.index, out.vals, strict=True):  # the tables: no view
            bit = as_bit(v)
            off = int(point)
            if last.get(off) != bit:
                changed[off] = Value.ACTIVE if bit else Value.INACTIVE
        if changed:
            self._request.set_values(changed)
            for off, val in changed.items():
                last[off] = 1 if val is Value.ACTIVE else 0

    def _safe_state(self) -> None:
        if self._last_written is not None:
            self._last_written = {o: -1 for o in self._last_written}  # force a full write
        self._write()

    def _close(self) -> None:
        req, self._request = self._request, None
        self._last_written = None
        if req is not None:
            req.release()
