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
  ``_open()``, ``_read()`` (fill ``self.inputs`` with physical values),
  ``_write()`` (send ``self.outputs``), ``_close()``.
It **may** override ``_init()`` (its own fields, from ``self.params``: called at the end of
``__init__``, so a back-end needs no constructor of its own), ``_check_point(point,
direction) -> PointKind`` (default: the type's points as drivers.registry describes them;
raise PointError for a point it lacks), ``_safe_state()`` (default: every output 0, then
``_write()``) and ``_reopen()`` (default: ``_close()`` then ``_open()``), used for recovery
with back-off. A digital bank (a GPIO chip, an I2C expander) builds on
:class:`drivers.bank.DigitalBank`, which fills these hooks from a few of its own.
A back-end that writes outputs outside ``_write()`` (a device set up again after a
reconnect or a power glitch) must write them all 0 while ``inhibited`` is set.

The images ``inputs`` and ``outputs`` are :class:`drivers.image.Image` objects: mappings
point -> value like a dict, kept as a list of values by position (``vals``) and an index
point -> position (``index``) that only grows, so the plant's cycle reads and writes them
by position. A back-end may read and assign them by name as a dict; a hot ``_read`` may
assign ``self.inputs.vals[i]`` directly (positions taken from ``self.inputs.index`` at
``_open()``; they never change). A BOOL point's input value is a bool, True or False (the
plant reads the bits of the image as they are: drivers/image.py): a ``_read`` that
assigns ``vals[i]`` stores one; ``publish_inputs`` makes one, and so does a store by name
at a bit the plant declared. It must never rebind ``inputs``, ``outputs``, their ``vals``
or ``index``, nor delete a point: the plant's generated cycle holds them.

A back-end whose bus is too slow to be served inside the scan builds on ``PolledDriver``:
its own thread (or a bus library's receive thread) does the I/O and exchanges buffers with
the scan; inputs that are too old show as ``Health.STALE``.
"""

from __future__ import annotations

import abc
import enum
import logging
import sys
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

from drivers.config import ConfigError, ConfigKeys
from drivers.image import Image

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
    """A binding names a point the driver does not have, or uses it in the wrong direction.

    Examples: ``exp1.C0`` on an MCP23017 (ports are A and B), ``mb.I3`` bound as an output
    (discrete inputs are read-only), ``gpio.17`` bound both as an input and as an output.
    """


def as_bit(value: Any) -> int:
    """A physical bit from whatever the plant stored (bool, int): 0 or 1."""
    return 1 if value else 0


class Driver(abc.ABC):
    """Base class of every I/O back-end. See the module docstring for what to override."""

    #: the ``type:`` key of the plant file that selects this driver
    type_name: ClassVar[str] = ""
    #: config keys accepted besides ``type`` and ``on_fault`` (declared in drivers.registry)
    config_keys: ClassVar[ConfigKeys] = ConfigKeys()
    #: first reconnect delay after a fault, seconds; doubled up to RECONNECT_MAX_S
    RECONNECT_MIN_S: ClassVar[float] = 0.1
    #: longest delay between reconnect attempts, seconds
    RECONNECT_MAX_S: ClassVar[float] = 5.0
    #: True for a hardware back-end where a point is either an input or an output
    ONE_DIRECTION_PER_POINT: ClassVar[bool] = False

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
        unknown = set(self.config) - set(self.config_keys)
        if unknown:
            raise ConfigError(f"driver {name} ({self.type_name}): unknown keys "
                              f"{sorted(unknown)}")
        #: the config as checked by ``config_keys``: every declared key, defaults filled in,
        #: times in seconds, I2C addresses as ints, choices as declared
        self.params = self.config_keys.validate(self.config, name, self.type_name)
        self.clock = clock
        #: physical input values, point -> value, filled by read() (never rebound)
        self.inputs = Image()
        #: physical output values, point -> value, set by the plant, sent by write()
        #: (never rebound)
        self.outputs = Image()
        self.kinds: dict[str, PointKind] = {}
        self.health = Health.CLOSED
        self.fault_reason: str | None = None
        self._next_retry_ns = 0
        self._retry_delay_s = self.RECONNECT_MIN_S
        #: set by inhibit(): write() sends nothing, the safe state stays on the bus
        self.inhibited = False
        # write() and safe_state() may race when the scan watchdog (another thread) puts
        # the outputs off while the scan thread is stuck: this lock orders them
        self._out_lock = threading.Lock()
        self._init()

    # -- plant-facing API -------------------------------------------------------------
    @property
    def ok(self) -> bool:
        """True while the driver is healthy (the ``driver.ok`` point)."""
        return self.health is Health.OK

    def add_point(self, point: str, direction: Direction) -> PointKind:
        """Declare a point used by a binding; returns its kind. Raises PointError."""
        # interned (the image interns it too): a lookup by the name the plant holds
        # matches by identity
        point = sys.intern(point)
        if self.ONE_DIRECTION_PER_POINT:
            other = self.outputs if direction is Direction.IN else self.inputs
            if point in other:
                was = "an output" if direction is Direction.IN else "an input"
                raise PointError(f"{self.name}.{point} is already bound as {was}: a point of a "
                                 f"{self.type_name} driver is either an input or an output")
            if direction is Direction.OUT and point in self.outputs:
                raise PointError(f"{self.name}.{point} is bound as an output twice")
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
                self.inputs.fill(0)
            return
        try:
            self._read()
        except (DriverError, OSError) as exc:
            self._fault(str(exc))
            if self.on_fault is FaultPolicy.ZERO:
                self.inputs.fill(0)

    def write(self) -> None:
        """Send ``outputs`` (one non-blocking update). Never raises for I/O faults."""
        with self._out_lock:
            if self.health is Health.FAULT or self.inhibited:
                return
            try:
                self._write()
            except (DriverError, OSError) as exc:
                self._fault(str(exc))

    def safe_state(self) -> None:
        """Put every output of this driver off, as far as the bus allows. Thread-safe with
        respect to write()."""
        with self._out_lock:
            self.outputs.fill(0)
            if self.health in (Health.CLOSED,):
                return
            try:
                self._safe_state()
            except (DriverError, OSError) as exc:
                self._fault(f"safe state not written: {exc}")

    def inhibit(self, on: bool) -> None:
        """Block (True) or allow (False) write(); inhibiting also writes the safe state.

        The scan watchdog calls this from its own thread when a scan hangs: whatever the
        stuck scan thread does afterwards, no output of this driver is energised again
        until the fault is acknowledged."""
        self.inhibited = on
        if on:
            self.safe_state()

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
    def _init(self) -> None:  # noqa: B027 - a hook, empty unless a back-end fills it
        """Set the back-end's own fields (from ``self.params``); a subclass of a class that
        has one calls ``super()._init()`` first."""

    def _check_point(self, point: str, direction: Direction) -> PointKind:
        """Validate ``point`` for ``direction``; return its kind or raise PointError."""
        from drivers.registry import POINTS  # it imports this module

        return POINTS[self.type_name].check(self.name, point, direction)

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


class PolledDriver(Driver):
    """A driver whose bus is served off the scan thread; the scan only exchanges buffers.

    The I/O side is the back-end's own poll thread, or a bus library's receive thread
    (python-can's notifier). It talks to the scan through these thread-safe calls:
    ``publish_inputs()`` (a fresh input image), ``report_fault()`` (an I/O fault, e.g. a
    timeout after retries), ``report_error()`` (an unexpected exception: re-raised by the
    next ``read()`` in the scan thread, so a bug never hides in a background thread),
    ``take_outputs()`` (the outputs the scan wrote since the last take) and
    ``mark_outputs_dirty()`` (send them again, e.g. after the device came back).

    On the scan side ``read()`` copies the latest image and reports ``Health.STALE`` when it
    is older than ``stale_after_s``; ``write()`` copies the outputs and calls ``_wake()``
(and so does ``read()`` while the driver is inhibited: its inputs are still read).
    While faulted, the I/O side is asked to try again (``_retry()``) at back-off times of
    the injected clock, and recovery is seen as soon as the I/O side reports success.

    A back-end **must** override ``_start()`` (connect and begin I/O,
    quickly: it runs in ``open()``, which then waits up to ``first_data_timeout_s`` for the
    I/O side's first report, and in the scan thread at recovery until it has once
    succeeded) and ``_stop()`` (end I/O, release the bus; idempotent).
    It **may** override ``_init()`` (calling ``super()._init()`` first), ``_check_point``,
    ``_wake()`` (new outputs are waiting), ``_retry()`` (ask the I/O side for one more
    attempt; must not block), ``_check()`` (extra health checks in the scan thread, raise
    DriverError) and ``_write()``.
    """

    #: inputs older than this are STALE, seconds; None: never stale by age
    STALE_AFTER_S: ClassVar[float | None] = 0.5
    #: longest wait in open() for the first input image, seconds
    FIRST_DATA_TIMEOUT_S: ClassVar[float] = 2.0

    def _init(self) -> None:
        #: inputs older than this are STALE, seconds (None: never)
        self.stale_after_s: float | None = self.STALE_AFTER_S
        #: longest wait in open() for the I/O side's first report, seconds
        self.first_data_timeout_s = self.FIRST_DATA_TIMEOUT_S
        self._lock = threading.Lock()
        self._updated = threading.Condition(self._lock)
        self._in_buf: dict[str, int] = {}
        self._in_seq = 0  # every report of the I/O side
        self._status_seq = 0  # reports that say whether the device works
        self._in_seen = 0
        self._fresh_ns: int | None = None
        self._io_fault: str | None = None
        self._io_error: BaseException | None = None
        self._out_buf: dict[str, int] = {}
        self._out_seq = 0
        self._out_taken = 0
        self._started = False

    # -- I/O side (any thread) ------------------------------------------------------------
    def publish_inputs(self, values: Mapping[str, int], ok: bool = True) -> None:
        """A fresh input image (physical values; a BOOL point's made a bool here, off the
        scan). With ``ok`` (an exchange that proves the device works) it also clears any
        I/O fault; a receive callback passes False."""
        kinds, bit = self.kinds, PointKind.BOOL
        fresh = {p: v != 0 if kinds.get(p) is bit else v for p, v in values.items()}
        with self._lock:
            self._in_buf.update(fresh)
            self._in_seq += 1
            self._fresh_ns = self.clock()
            if ok:
                self._io_fault = None
                self._status_seq += 1
            self._updated.notify_all()

    def report_ok(self) -> None:
        """The bus works again, with no new input values (e.g. a driver without inputs)."""
        self.publish_inputs({})

    def report_fault(self, reason: str) -> None:
        """An I/O fault seen by the I/O side; the scan turns it into Health.FAULT."""
        with self._lock:
            self._io_fault = reason
            self._in_seq += 1
            self._status_seq += 1
            self._updated.notify_all()

    def report_error(self, exc: BaseException) -> None:
        """An unexpected exception of the I/O side (a bug), re-raised by the next read() in
        the scan thread. An I/O error (DriverError, OSError) passed here is a fault like
        ``report_fault``: read() never raises for I/O faults."""
        if isinstance(exc, (DriverError, OSError)):
            self.report_fault(str(exc))
            return
        with self._lock:
            self._io_error = exc
            self._in_seq += 1
            self._status_seq += 1
            self._updated.notify_all()

    def take_outputs(self) -> dict[str, int] | None:
        """The output image if the scan changed it since the last take, else None."""
        with self._lock:
            if self._out_taken == self._out_seq:
                return None
            self._out_taken = self._out_seq
            return dict(self._out_buf)

    def mark_outputs_dirty(self) -> None:
        """Make the next take_outputs() return the image even if unchanged."""
        with self._lock:
            self._out_seq += 1

    @property
    def io_faulted(self) -> bool:
        """True while the I/O side reports a fault (thread-safe)."""
        with self._lock:
            return self._io_fault is not None

    @property
    def updates(self) -> int:
        """How many reports (inputs or faults) the I/O side made so far."""
        with self._lock:
            return self._in_seq

    def wait_for_update(self, timeout: float, since: int | None = None) -> bool:
        """Wait up to ``timeout`` seconds for a report of the I/O side after ``since``
        (a value of ``updates``; default: now). For tests and benches; the scan never
        waits."""
        with self._lock:
            seq = self._in_seq if since is None else since
            return self._updated.wait_for(lambda: self._in_seq != seq, timeout)

    # -- back-end hooks ---------------------------------------------------------------
    @abc.abstractmethod
    def _start(self) -> None:
        """Connect and begin I/O (may block). Raise DriverError/OSError on failure."""

    @abc.abstractmethod
    def _stop(self) -> None:
        """End I/O and release the bus. Idempotent."""

    def _wake(self) -> None:
        """New outputs are waiting for the I/O side."""

    def _retry(self) -> None:
        """While faulted, at back-off times: ask the I/O side for one more attempt."""

    def _check(self) -> None:
        """Extra checks in the scan thread, every read(); raise DriverError on a fault."""

    # -- Driver hooks -----------------------------------------------------------------
    def _open(self) -> None:
        with self._lock:
            self._io_fault = None
            self._io_error = None
            self._fresh_ns = None
            seq = self._status_seq
            # the first exchange writes the whole output image, as the plant holds it now
            self._out_buf.update({p: 0 if self.inhibited else int(v)
                                  for p, v in self.outputs.items()})
            self._out_seq += 1
        self._start()
        self._started = True
        with self._lock:
            self._updated.wait_for(lambda: self._status_seq != seq, self.first_data_timeout_s)
        self._check_io()
        self._check()

    def _read(self) -> None:
        self._check_io()
        self._check()
        if self.inhibited:  # write() sends nothing: the I/O side still reads the inputs
            self._wake()
        with self._lock:
            if self._in_seen != self._in_seq:
                self._in_seen = self._in_seq
                index, vals = self.inputs.index, self.inputs.vals
                for p, v in self._in_buf.items():
                    i = index.get(p)
                    if i is not None:
                        vals[i] = v
            fresh = self._fresh_ns
        stale = fresh is None or (
            self.stale_after_s is not None
            and self.clock() - fresh > self.stale_after_s * 1e9
        )
        if stale and self.health is Health.OK:
            log.warning("driver %s: inputs stale", self.name)
            self.health = Health.STALE
        elif not stale and self.health is Health.STALE:
            log.info("driver %s: inputs fresh again", self.name)
            self.health = Health.OK

    def _write(self) -> None:
        with self._lock:
            changed = False
            out = self.outputs
            for p, v in zip(out.index, out.vals, strict=True):  # the tables: no view
                bit = int(v)
                if self._out_buf.get(p) != bit:
                    self._out_buf[p] = bit
                    changed = True
            if changed:
                self._out_seq += 1
        self._wake()

    def _close(self) -> None:
        self._started = False
        self._stop()

    def _check_io(self) -> None:
        with self._lock:
            error, fault = self._io_error, self._io_fault
        if error is not None:
            raise error
        if fault is not None:
            raise DriverError(fault)

    def _try_recover(self) -> bool:
        if self._started:
            try:
                self._check_io()
                self._check()
            except DriverError as exc:
                self.fault_reason = str(exc)
            else:
                self._set_ok()
                return True
        now = self.clock()
        if now < self._next_retry_ns:
            return False
        try:
            if self._started:
                self._retry()
            else:
                self._start()
                self._started = True
        except (DriverError, OSError) as exc:
            self.fault_reason = str(exc)
        self._retry_delay_s = min(self._retry_delay_s * 2, self.RECONNECT_MAX_S)
        self._next_retry_ns = now + int(self._retry_delay_s * 1e9)
        return False
