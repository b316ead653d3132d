"""Simulated I/O: an in-memory driver whose points are created by the bindings."""

from __future__ import annotations

from drivers.base import Driver
from drivers.image import Image
from drivers.registry import SIM_KEYS


class SimDriver(Driver):
    """Points of any name; inputs are set by a simulation script or a test, outputs recorded.

    A point used by a typed signal (``int``/``real``) holds numbers; otherwise bits.
    ``written`` is the output image as last sent by ``write()`` (what a real bus would
    show: nothing is sent while the driver is inhibited).
    """

    type_name = "sim"
    config_keys = SIM_KEYS

    def _init(self) -> None:
        #: the outputs as last written, point -> value (positions as in ``outputs``)
        self.written = Image()

    def _open(self) -> None:
        pass

    def _read(self) -> None:
        pass

    def _write(self) -> None:
        out, written = self.outputs, self.written
        if len(written.vals) == len(out.vals):  # the usual case: one list copy, no lookup
            written.vals[:] = out.vals
        else:  # points added since the last write: appended in the same order
            written.update(zip(out.index, out.vals, strict=True))

    def _close(self) -> None:
        pass

    def set_input(self, point: str, value: object) -> None:
        """Drive a physical input value (before any inversion)."""
        self.inputs[point] = value
