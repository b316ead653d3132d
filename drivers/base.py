"""The driver contract: every I/O back-end is a Driver exchanging a process image with the plant.

A driver owns its bus and exposes named *points* (``I0``, ``B3``, ``17``) with a direction.
The plant talks to every driver through this class only:

* ``add_point(point, direction)`` once per binding, before ``open()``;
* ``open()`` once; then every cycle ``read()`` (fills ``inputs``), the scans, the plant
  copies values into ``outputs``, ``write()``; ``safe_state()`` on any fault or stop;
  ``close()`` at the end (idempotent, outputs to the safe state first).

``read()``/``write()`` never raise for I/O faults and never block on a slow bus: a fault
marks ``health`` FAULT with ``fault_reason``, logs once per state change, and the plant
applies the driver's ``on_fault`` policy (``stop``/``hold``/``zero``).

A back-end **must** override:
  ``_check_point(point, direction) -> PointKind`` (raise PointError for a point it lacks),
  ``_open()``, ``_read()`` (fill ``self.inputs`` with physical values),
  ``_write()`` (send ``self.outputs``), ``_close()``.
It **may** override ``_safe_state()`` (default: every output 0, then ``_write()``) and
``_reopen()`` (default: ``_close()`` then ``_open()``), used for recovery with back-off.
"""

from __future__ import annotations

import abc
import enum
import logging
import time
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

log = logging.getLogger(__name__)


class Direction(enum.Enum):
    """Direction of a point, decided by the binding (grafcet input or output)."""

    IN = "in"
    OUT = "out"


class PointKind(enum.Enum):
    """What a point carries: a bit or a 16-bit register."""

    BOOL = "bool"
    INT = "int"


class Health(enum.Enum):
    """Driver state as seen by the plant."""

    CLOSED = "closed"
    OK = "ok"
    STALE = "stale"
    FAULT = "fault"


class FaultPolicy(enum.Enum):
    """What a driver fault does to the plant (language.md, "Drivers and their points")."""

    STOP = "stop"  # fault: every output off, charts stopped
    HOLD = "hold"  # keep running on the last good input values
    ZERO = "zero"  # keep running with this driver's inputs read as 0


class DriverError(Exception):
    """An I/O fault of a driver (bus error, node lost, timeout). Carries a readable reason."""


class PointError(ValueError):
    """A binding names a point the driver does not have, or uses it in the wrong direction."""


class Driver(abc.ABC):
    """Base class of every I/O back-end. See the module docstring for what to override."""

    #: the ``type:`` key of the plant file that selects this driver
    type_name: ClassVar[str] = ""
    #: config keys this driver accepts besides ``type`` and ``on_fault``
    config_keys: ClassVar[frozenset[str]] = frozenset()
    #: first reconnect delay after a fault, seconds; doubled up to RECONNECT_MAX_S
    RECONNECT_MIN_S: ClassVar[float] = 0.1
    #: longest delay between reconnect attempts, seconds
    RECONNECT_MAX_S: ClassVar[float] = 5.0

    def __init__(
        self,
        name: str,
        config: Mapping[str, Any] | None = None,
        *,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.name = name
        self.config: dict[str, Any] = dict(config or {})
        self.on_fault = FaultPolicy(self.config.pop("on_fault", "stop"))
        self.clock = clock
        #: physical input values, point -> value, filled by read()
        self.inputs: dict[str, Any] = {}
        #: physical output values, point -> value, set by the plant, sent by write()
        self.outputs: dict[str, Any] = {}
        self.kinds: dict[str, PointKind] = {}
        self.health = Health.CLOSED
        self.fault_reason: str | None = None
        self._next_retry_ns = 0
        self._retry_delay_s = self.RECONNECT_MIN_S

    # -- plant-facing API -------------------------------------------------------------
    @property
    def ok(self) -> bool:
        """True while the driver is healthy (the ``driver.ok`` point)."""
        return self.health is Health.OK

    def add_point(self, point: str, direction: Direction) -> PointKind:
        """Declare a point used by a binding; returns its kind. Raises PointError."""
        kind = self._check_point(point, direction)
        self.kinds[point] = kind
        if direction is Direction.IN:
            self.inputs[point] = 0
        else:
            self.outputs[point] = 0
        return kind

    def open(self) -> None:
        """Open the bus; a failure leaves the driver in FAULT (retried by read())."""
        try:
            self._open()
        except (DriverError, OSError) as exc:
            self._fault(str(exc))
        else:
            self._set_ok()

    def read(self) -> None:
        """Refresh ``inputs`` (one non-blocking update). Never raises for I/O faults."""
        if self.health is Health.FAULT and not self._try_recover():
            if self.on_fault is FaultPolicy.ZERO:
                for p in self.inputs:
                    self.inputs[p] = 0
            return
        try:
            self._read()
        except (DriverError, OSError) as exc:
            self._fault(str(exc))
            if self.on_fault is FaultPolicy.ZERO:
                for p in self.inputs:
                    self.inputs[p] = 0

    def write(self) -> None:
        """Send ``outputs`` (one non-blocking update). Never raises for I/O faults."""
        if self.health is Health.FAULT:
            return
        try:
            self._write()
        except (DriverError, OSError) as exc:
            self._fault(str(exc))

    def safe_state(self) -> None:
        """Put every output of this driver off, as far as the bus allows."""
        for p in self.outputs:
            self.outputs[p] = 0
        if self.health in (Health.CLOSED,):
            return
        try:
            self._safe_state()
        except (DriverError, OSError) as exc:
            self._fault(f"safe state not written: {exc}")

    def close(self) -> None:
        """Outputs to the safe state, then release the bus. Idempotent."""
        if self.health is Health.CLOSED:
            return
        self.safe_state()
        try:
            self._close()
        except (DriverError, OSError) as exc:  # pragma: no cover - best effort on shutdown
            log.warning("driver %s: close failed: %s", self.name, exc)
        self.health = Health.CLOSED

    # -- back-end hooks ---------------------------------------------------------------
    @abc.abstractmethod
    def _check_point(self, point: str, direction: Direction) -> PointKind:
        """Validate ``point`` for ``direction``; return its kind or raise PointError."""

    @abc.abstractmethod
    def _open(self) -> None:
        """Acquire the bus and initialise the device (outputs inactive)."""

    @abc.abstractmethod
    def _read(self) -> None:
        """Fill ``self.inputs``; raise DriverError/OSError on a fault."""

    @abc.abstractmethod
    def _write(self) -> None:
        """Send ``self.outputs``; raise DriverError/OSError on a fault."""

    @abc.abstractmethod
    def _close(self) -> None:
        """Release the bus."""

    def _safe_state(self) -> None:
        self._write()

    def _reopen(self) -> None:
        try:
            self._close()
        except (DriverError, OSError):
            pass
        self._open()

    # -- health bookkeeping -----------------------------------------------------------
    def _fault(self, reason: str) -> None:
        if self.health is not Health.FAULT or reason != self.fault_reason:
            log.error("driver %s: fault: %s", self.name, reason)
        if self.health is not Health.FAULT:
            self._retry_delay_s = self.RECONNECT_MIN_S
            self._next_retry_ns = self.clock() + int(self._retry_delay_s * 1e9)
        self.health = Health.FAULT
        self.fault_reason = reason

    def _set_ok(self) -> None:
        if self.health is not Health.OK:
            if self.health is Health.FAULT:
                log.warning("driver %s: recovered after: %s", self.name, self.fault_reason)
            else:
                log.info("driver %s: open", self.name)
        self.health = Health.OK

    def _try_recover(self) -> bool:
        now = self.clock()
        if now < self._next_retry_ns:
            return False
        try:
            self._reopen()
        except (DriverError, OSError) as exc:
            self.fault_reason = str(exc)
            self._retry_delay_s = min(self._retry_delay_s * 2, self.RECONNECT_MAX_S)
            self._next_retry_ns = now + int(self._retry_delay_s * 1e9)
            return False
        self._set_ok()
        return True
