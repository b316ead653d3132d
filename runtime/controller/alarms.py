"""The plant's alarms (docs/daemon.md, "Alarms"): one condition per cause, its state
(active, acknowledged, confirmed) kept here in the controller, shown alike by the console's
``status``, the log and the OPC UA server's Alarms and Conditions.

The conditions, from the plant:

- ``controller.fault``: the controller is in fault (``fault``);
- ``controller.overruns``: more than ``alarms: overruns: count`` overruns in the last
  ``window`` (``overruns``);
- ``driver.NAME``: a driver is in fault (``driver``);
- ``INSTANCE.STEP.maxtime``, for each step with a ``max``: SFCError set by that step's
  max time supervision (``maxtime``);
- ``INSTANCE.SFCError``: SFCError set otherwise (the chart wrote it, or the step named has
  no condition of its own) (``sfcerror``).

Each has a severity from ``alarms: severity:`` and a message naming what is wrong with the
plant's descriptions (language/iolist.py). An alarm becomes active when its cause appears:
unacknowledged and unconfirmed; inactive when the cause is gone. ``acknowledge`` (by a
person, with their name and a comment) is allowed while unacknowledged; ``confirm`` once
acknowledged and not confirmed. An acknowledged alarm stays active until its cause clears;
an alarm is shown (``retain``) while active, unacknowledged or unconfirmed. Every change
is one log line, and one entry of the board's journal (``changes``: the board's version
and the alarm's state as plain data, a ring of JOURNAL_MAX), from which the feed sends
each change to the side processes as its own line, in order: a state that lasts less than
a feed sample still reaches an OPC UA client as its own event.

The scan thread only copies a few flags (``on_scan``, every ``EVERY_NS`` worth of scans,
as a compact tuple, when it changed); the board's own thread evaluates them, logs, and
keeps the overrun window. The state is lost with the process: after a restart, a cause
still there is a new, unacknowledged alarm.
"""

from __future__ import annotations

import collections
import enum
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

from drivers.base import Health
from drivers.durations import format_ns
from runtime.errors import SoftplcError
from runtime.language.flagtexts import sfcerror_cause
from runtime.language.iolist import IOList

if TYPE_CHECKING:
    from runtime.controller.daemon import Daemon
    from runtime.engine.plant import Plant

log = logging.getLogger(__name__)

#: the scan thread looks at the alarms' causes every this many ns of scans
EVERY_NS = 50_000_000
#: the board's thread looks at the overrun window at least this often, seconds
POLL_S = 1.0
#: changes of the board kept for its readers (the feed): a reader further behind than
#: this many loses the oldest (said in one log line; the whole board still follows)
JOURNAL_MAX = 4096


class Kind(enum.Enum):
    """What an alarm is about (the key of its severity in ``alarms: severity:``)."""

    FAULT = "fault"
    DRIVER = "driver"
    OVERRUNS = "overruns"
    SFCERROR = "sfcerror"
    MAXTIME = "maxtime"


class AlarmRefused(SoftplcError):
    """An acknowledge or confirm that cannot be done; ``code`` is OPC UA's status name.

    Examples: acknowledging an acknowledged alarm (BadConditionBranchAlreadyAcked),
    confirming one not yet acknowledged (BadInvalidState), an unknown alarm
    (BadNodeIdUnknown)."""

    def __init__(self, message: str, code: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(slots=True)
class Alarm:
    """One condition and its state."""

    key: str
    kind: Kind
    #: what it is about: an instance, a driver, or "controller"
    source: str
    severity: int
    message: str = ""
    active: bool = False
    acked: bool = True
    confirmed: bool = True
    #: wall-clock time of the last change of state
    time: float = 0.0
    comment: str = ""
    #: who acknowledged or confirmed it last
    by: str = ""

    @property
    def retain(self) -> bool:
        """Shown in an alarm list: active, or not yet acknowledged or confirmed."""
        return self.active or not self.acked or not self.confirmed

    def state_text(self) -> str:
        return (f"{'active' if self.active else 'inactive'}, "
                f"{'acknowledged' if self.acked else 'unacknowledged'}"
                + ("" if self.confirmed else ", unconfirmed"))

    def as_dict(self) -> dict[str, Any]:
        return {"key": self.key, "kind": self.kind.value, "source": self.source,
                "severity": self.severity, "message": self.message, "active": self.active,
                "acked": self.acked, "confirmed": self.confirmed, "time": self.time,
                "comment": self.comment, "by": self.by}


class _Causes:
    """The scan thread's view of one plant: where each alarm's cause is read."""

    def __init__(self, plant: Plant) -> None:
        self.plant = plant
        self.instances = list(plant.instances)
        self.getters: list[Callable[[], tuple[Any, ...]]] = []
        for inst in plant.instances.values():
            prog = inst.program
            self.getters.append(inst.m.getter([prog.var_index("SFCError"),
                                               prog.var_index("SFCErrorStep")]))
        self.drivers = list(plant.drivers.values())

    def read(self, fault: str | None, overruns: int) -> tuple[Any, ...]:
        return (tuple(g() for g in self.getters),
                tuple((d.health, d.fault_reason or "") for d in self.drivers), fault,
                overruns)


class AlarmBoard:
    """The alarms of a running plant (see the module docstring)."""

    def __init__(self, daemon: Daemon, clock: Callable[[], float] = time.monotonic,
                 wall: Callable[[], float] = time.time) -> None:
        self.daemon = daemon
        self.config = daemon.pdef.alarms
        self.clock = clock
        self.wall = wall
        self._lock = threading.Lock()
        self._alarms: dict[str, Alarm] = {}
        #: bumped at every change (a reader compares it to know whether to read again)
        self.version = 0
        #: the last JOURNAL_MAX changes of an alarm's state: (version, ``Alarm.as_dict``)
        self._journal: collections.deque[tuple[int, dict[str, Any]]] = collections.deque(
            maxlen=JOURNAL_MAX)
        #: the version of the newest change the ring no longer holds (0: none lost)
        self._forgotten = 0
        self._causes: _Causes | None = None
        self._slot: tuple[Any, ...] | None = None
        self._last: tuple[Any, ...] | None = None
        self._next = 0
        self._every = max(1, EVERY_NS // daemon.plant.cycle_ns)
        self._window: collections.deque[tuple[float, int]] = collections.deque()
        self._wake = threading.Event()
        self._stop = False
        self._thread: threading.Thread | None = None
        #: an online change switched the causes: the conditions are built again
        self._rebuild = False
        self._build(daemon.plant)

    # -- conditions ----------------------------------------------------------------------
    def _build(self, plant: Plant) -> None:
        """The conditions of ``plant`` (those of the same key keep their state; the
        plant file's ``alarms:`` settings, severities included, are the new plant's)."""
        self.config = plant.pdef.alarms
        sev = self.config.severity
        iolist = IOList(plant.pdef)
        fresh: dict[str, Alarm] = {}

        def add(key: str, kind: Kind, source: str) -> None:
            old = self._alarms.get(key)
            if old is not None:
                old.severity = sev[kind.value]
            fresh[key] = old if old is not None else Alarm(key, kind, source, sev[kind.value])
        add("controller.fault", Kind.FAULT, "controller")
        add("controller.overruns", Kind.OVERRUNS, "controller")
        for name in plant.drivers:
            add(f"driver.{name}", Kind.DRIVER, name)
        self._texts: dict[str, tuple[str, dict[str, str], dict[str, int]]] = {}
        for name, inst in plant.instances.items():
            g = inst.grafcet
            add(f"{name}.SFCError", Kind.SFCERROR, name)
            maxes = {s.name: s.max_ns for s in g.steps.values() if s.max_ns is not None}
            for step in maxes:
                add(f"{name}.{step}.maxtime", Kind.MAXTIME, name)
            about = iolist.meaning(name).description
            steps = {s: iolist.meaning(f"{name}.{s}").description for s in g.steps}
            self._texts[name] = (f"{name} ({about})" if about else name, steps,
                                 {s: int(ns) for s, ns in maxes.items()})
        with self._lock:
            for key, a in self._alarms.items():
                if key not in fresh and a.active:
                    log.warning("alarm %s gone with an online change (it was active)", key)
            self._alarms = fresh
            self.version += 1
        if self._causes is None or self._causes.plant is not plant:
            self._causes = _Causes(plant)

    def prepare_switch(self, plant: Plant) -> Callable[[], None]:
        """Reload worker thread: the new plant's causes, built now; the returned function
        (scan thread, at the swap) puts them in place of the old plant's, which the board
        then holds no more (a replaced plant is freed by reference counting alone), and
        has the board's thread build the new plant's conditions."""
        causes = _Causes(plant)

        def commit() -> None:
            self._causes, self._slot, self._last = causes, None, None
            self._rebuild = True
            self._wake.set()
        return commit

    # -- the scan thread -----------------------------------------------------------------
    def on_scan(self, n: int) -> None:
        """Scan thread, after cycle ``n``: every EVERY_NS of scans, the causes copied
        (when they changed) for the board's thread."""
        if n < self._next:
            return
        self._next = n + self._every
        causes, d = self._causes, self.daemon
        if causes is None or causes.plant is not d.plant:
            self._wake.set()  # an online change: the board's thread builds the new ones
            return
        # the fault's reason copied now: it may be acknowledged before the board looks
        snap = causes.read(d.fault, d.scan_stats.overruns)
        if snap != self._last:
            self._last = self._slot = snap
            self._wake.set()

    # -- the board's thread --------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="softplc-alarms", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the thread (idempotent)."""
        self._stop = True
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def _run(self) -> None:
        try:
            while not self._stop:
                self._wake.wait(POLL_S)
                self._wake.clear()
                if self._stop:
                    break
                self._turn()
        except Exception:  # noqa: BLE001 - the alarms die, never the controller
            log.exception("alarm board failed: alarms are no longer updated")

    def _turn(self) -> None:
        """One wake-up of the board's thread (a function of its own: no local of it holds
        a replaced plant while the thread waits)."""
        causes = self._causes
        if self._rebuild or causes is None or causes.plant is not self.daemon.plant:
            self._rebuild = False
            self._build(self.daemon.plant)
            return
        self.evaluate(self._slot)

    def evaluate(self, snap: tuple[Any, ...] | None) -> None:
        """The alarms' states from the causes ``snap`` (``_Causes.read``) and the overrun
        window; one log line per change."""
        causes = self._causes
        if snap is None or causes is None:
            return
        flags, drivers, fault, overruns = snap
        now = self.clock()
        window_s = self.config.overrun_window_ns / 1e9
        self._window.append((now, overruns))
        while self._window and self._window[0][0] < now - window_s:
            self._window.popleft()
        recent = overruns - self._window[0][1]
        want: dict[str, str] = {}  # key -> message, for every active cause
        if fault is not None:
            want["controller.fault"] = f"controller fault: {fault}"
        if recent > self.config.overrun_count:
            want["controller.overruns"] = (f"{recent} overruns in the last "
                                           f"{format_ns(self.config.overrun_window_ns)} "
                                           f"(more than {self.config.overrun_count})")
        for drv, (health, reason) in zip(causes.drivers, drivers, strict=True):
            if health is Health.FAULT:
                want[f"driver.{drv.name}"] = f"driver {drv.name}: {reason or 'fault'}"
        for name, (error, step) in zip(causes.instances, flags, strict=True):
            if not error:
                continue
            who, steps, maxes = self._texts[name]
            about = f"{step} ({steps[step]})" if steps.get(step) else str(step)
            if step in maxes:
                want[f"{name}.{step}.maxtime"] = (f"{who}: step {about} over its max time "
                                                  f"{format_ns(maxes[step])}")
            else:
                want[f"{name}.SFCError"] = (f"{who}: SFCError "
                                            f"{sfcerror_cause(step, steps.get(step, ''))}")
        with self._lock:
            for key, a in self._alarms.items():
                msg = want.get(key)
                if msg is not None and not a.active:
                    a.active, a.acked, a.confirmed = True, False, False
                    a.message, a.time, a.comment, a.by = msg, self.wall(), "", ""
                    self._changed(a)
                    log.warning("alarm %s raised (severity %d): %s", key, a.severity, msg)
                elif msg is None and a.active:
                    a.active, a.time = False, self.wall()
                    self._changed(a)
                    log.warning("alarm %s cleared (%s): %s", key, a.state_text(), a.message)

    # -- people --------------------------------------------------------------------------
    def acknowledge(self, key: str, who: str, comment: str = "") -> str:
        """Acknowledge alarm ``key`` for ``who``; AlarmRefused if it cannot be."""
        with self._lock:
            a = self._get(key)
            if a.acked:
                raise AlarmRefused(f"alarm {key} is already acknowledged",
                                   "BadConditionBranchAlreadyAcked")
            a.acked = True
            text = self._done_by(a, who, comment)
        return _said(key, "acknowledged", who, comment, text)

    def confirm(self, key: str, who: str, comment: str = "") -> str:
        """Confirm alarm ``key`` for ``who``: acknowledged first, and its cause gone (a
        confirmation says the cause was dealt with, OPC UA Part 9); AlarmRefused if not."""
        with self._lock:
            a = self._get(key)
            if not a.acked:
                raise AlarmRefused(f"alarm {key} is not acknowledged yet: acknowledge it "
                                   "first", "BadInvalidState")
            if a.active:
                raise AlarmRefused(f"alarm {key} is still active: {_CLEARED_BY[a.kind]}, "
                                   "then confirm it", "BadInvalidState")
            if a.confirmed:
                raise AlarmRefused(f"alarm {key} is already confirmed",
                                   "BadConditionBranchAlreadyConfirmed")
            a.confirmed = True
            text = self._done_by(a, who, comment)
        return _said(key, "confirmed", who, comment, text)

    def _done_by(self, a: Alarm, who: str, comment: str) -> str:
        """Under the lock: ``who`` acted on ``a`` now, saying ``comment``; its state text."""
        a.comment, a.by, a.time = comment, who, self.wall()
        self._changed(a)
        return a.state_text()

    def _changed(self, a: Alarm) -> None:
        """Under the lock: ``a``'s state changed: a new version, journalled."""
        self.version += 1
        journal = self._journal
        if len(journal) == journal.maxlen:
            self._forgotten = journal[0][0]
        journal.append((self.version, a.as_dict()))

    def _get(self, key: str) -> Alarm:
        a = self._alarms.get(key)
        if a is None:
            raise AlarmRefused(f"no alarm '{key}'", "BadNodeIdUnknown")
        return a

    # -- readers -------------------------------------------------------------------------
    def alarms(self) -> list[Alarm]:
        """A copy of every condition, in the order built (controller, drivers, instances)."""
        with self._lock:
            return [replace(a) for a in self._alarms.values()]

    def as_list(self) -> list[dict[str, Any]]:
        """Every condition as plain data (``Alarm.as_dict``), in the order built: made under
        the lock directly, without copying each alarm first."""
        with self._lock:
            return [a.as_dict() for a in self._alarms.values()]

    def changes(self, since: int) -> tuple[list[tuple[int, dict[str, Any]]], int,
                                           list[dict[str, Any]] | None, bool]:
        """What changed after version ``since``: the changes of an alarm's state, oldest
        first, as (version, ``Alarm.as_dict``); the board's version now; every condition
        (``as_list``) if the version moved past ``since``, else None (read together: the
        conditions are those the changes end with); and True if the journal
        (JOURNAL_MAX) no longer holds all of them (the oldest are lost)."""
        with self._lock:
            if self.version == since:
                return [], since, None, False
            out: list[tuple[int, dict[str, Any]]] = []
            for e in reversed(self._journal):  # the newest first: stop at ``since``
                if e[0] <= since:
                    break
                out.append(e)
            out.reverse()
            lost = 0 < self._forgotten and since < self._forgotten
            return out, self.version, [a.as_dict() for a in self._alarms.values()], lost


#: what ends each kind of alarm's cause (the text of a confirmation refused too soon)
_CLEARED_BY = {
    Kind.FAULT: "the controller is in fault: Ack it first (the Controller's Ack, the "
                "console's 'ack')",
    Kind.DRIVER: "the driver is in fault: it clears once the driver is back",
    Kind.OVERRUNS: "it clears once the overruns in its window are back under the count",
    Kind.SFCERROR: "acknowledge the chart's SFCError first (the instance's Acknowledge, "
                   "the console's 'ack')",
    Kind.MAXTIME: "acknowledge the chart's SFCError first (the instance's Acknowledge, "
                  "the console's 'ack')",
}


def _said(key: str, what: str, who: str, comment: str, text: str) -> str:
    """The log line and the answer of an acknowledgement or a confirmation."""
    log.warning("alarm %s %s by %s%s (%s)", key, what, who, f": {comment}" if comment else "",
                text)
    return f"alarm {key} {what} ({text})"


def alarm_lines(alarms: list[dict[str, Any]]) -> list[str]:
    """The alarms to show (active, unacknowledged or unconfirmed), worst first, one line
    each, from ``AlarmBoard.as_list()``: what the console's ``status`` and the monitor
    say."""
    shown = [Alarm(a["key"], Kind(a["kind"]), a["source"], a["severity"], a["message"],
                   a["active"], a["acked"], a["confirmed"]) for a in alarms]
    shown = sorted((a for a in shown if a.retain), key=lambda a: (-a.severity, a.key))
    return [f"alarm {a.key} ({a.severity}) {a.state_text()}: {a.message}" for a in shown]
