"""Simulated I/O: an in-memory driver whose points are created by the bindings."""

from __future__ import annotations

from drivers.base import Direction, Driver, PointKind


class SimDriver(Driver):
    """Points of any name; inputs are set by a simulation script or a test, outputs recorded.

    A point used by a typed signal (``int``/``real``) holds numbers; otherwise bits.
    """

    type_name = "sim"

    def _check_point(self, point: str, direction: Direction) -> PointKind:
        return PointKind.INT if point.upper().startswith(("IR", "HR")) else PointKind.BOOL

    def _open(self) -> None:
        pass

    def _read(self) -> None:
        pass

    def _write(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def set_input(self, point: str, value: object) -> None:
        """Drive a physical input value (before any inversion)."""
        self.inputs[point] = value
