"""The controller process: a plant run in real time, failing safe, keeping its data.

``Daemon`` owns the scan thread (``Scheduler``), the scan watchdog, the retain writer and
the systemd notifications, and offers the console what it needs (``call``, ``status``,
``stats``, ``ack``...): every console request runs in the scan thread, between two scans.
``serve`` (service.py) runs it in the foreground until a stop signal; ``TraceWriter``
(tracewriter.py) writes ``run --trace``.

States: starting -> running <-> paused/stepping (console), iocheck (bench wiring),
fault (outputs off, charts stopped: an exception in a scan, a watchdog overrun, a driver
with ``on_fault: stop`` that failed), halted (outputs off after iocheck, waiting for
``ack``), stopped. A fault is left only by ``ack`` once its cause is gone, or by a
restart; the charts then begin again from their initial situation, retained memory kept.
"""

from __future__ import annotations

import collections
import enum
import json
import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Collection
from typing import IO, Any, TypeVar

from runtime.controller.alarms import AlarmBoard
from runtime.controller.events import EventWatcher
from runtime.controller.notify import Notifier
from runtime.controller.realtime import (
    lock_memory,
    pin_process,
    reduce_timer_slack,
    set_fifo_priority,
)
from runtime.controller.reload import Reloader, ReloadHook, ReloadResult
from runtime.controller.retain import (
    RetainedVars,
    RetainForeign,
    RetainLost,
    RetainStore,
    RetainWriter,
    restore,
    unfit_reason,
    write_new,
)
from runtime.controller.scheduler import Scheduler, Watchdog
from runtime.controller.stats import ScanStats
from runtime.controller.tracewriter import TraceWriter
from runtime.engine.commands import CommandRefused
from runtime.engine.plant import Plant
from runtime.engine.trace import trace_columns
from runtime.errors import Loc, SourceError
from runtime.language.flagtexts import sfcerror_cause
from runtime.language.model import DEFAULT_REALTIME_PRIORITY, PlantDef
from runtime.language.runtimedir import locate
from runtime.language.safefile import UnfitFile, read_bounded

log = logging.getLogger(__name__)
R = TypeVar("R")

#: how often STATUS= is refreshed for systemd, ns
STATUS_EVERY_NS = 5_000_000_000
#: faults remembered for ``status`` and the monitor
FAULT_HISTORY = 20
#: the longest fault record read at start (softplc writes ~200 bytes), bytes
FAULT_RECORD_MAX_BYTES = 64 * 1024
#: the longest reason taken from a fault record, characters
FAULT_REASON_MAX = 500
#: the interpreter's GIL switch interval while the scan runs, seconds: the longest a
#: scan waits for the GIL held by another thread (a console serving a flood). Python's
#: default, 5 ms, is half a 10 ms cycle (docs/console.md, "Transports and limits")...
GIL_SWITCH_S = 0.0005
#: ...and at most this part of the cycle (0.1 ms at a 1 ms cycle, where 0.5 ms was half
#: of it: bench.observers' busiest threads, the feed's and the console's, ran 0.5-0.6 ms
#: while a late scan waited)
GIL_SWITCH_CYCLE_PART = 0.1
#: ``stats`` figures are at most this many ns of cycles old...
STATS_MAX_AGE_NS = 100_000_000
#: ...and their percentiles (of 8192 cycles: a few ms of processor time) at most this
#: many: they barely move in a second
STATS_QUANTILES_MAX_AGE_NS = 1_000_000_000
#: the thread computing percentiles sleeps this long after sorting each slice of a
#: window, seconds (ScanStats: it never runs for long at a stretch)
STATS_PAUSE_S = 0.0001
#: chart flags that hold an instance (initial situation, reset, frozen situation)
HOLD_FLAGS = ("SFCInit", "SFCReset", "SFCPause")


def gil_switch_s(cycle_ns: int) -> float:
    """The GIL switch interval a controller of this cycle (ns) sets while it runs, s."""
    return min(GIL_SWITCH_S, cycle_ns / 1e9 * GIL_SWITCH_CYCLE_PART)


class State(enum.Enum):
    STARTING = "starting"
    RUNNING = "running"
    PAUSED = "paused"
    STEPPING = "stepping"
    IOCHECK = "iocheck"
    FAULT = "fault"
    HALTED = "halted"
    STOPPED = "stopped"


class ScanCall:
    """A function to run in the scan thread at the next scan boundary (``Daemon.submit``):
    ``done`` is set once it ran, with its ``result`` or its ``error``; a caller that gives
    up sets ``abandoned`` (a call not started yet is then skipped)."""

    __slots__ = ("fn", "done", "result", "error", "abandoned")

    def __init__(self, fn: Callable[[], Any]) -> None:
        self.fn = fn
        self.done = threading.Event()
        self.result: Any = None
        self.error: BaseException | None = None
        self.abandoned = False

    def run(self) -> None:
        if self.abandoned:
            return
        try:
            self.result = self.fn()
        except BaseException as exc:  # handed to the caller's thread
            self.error = exc
        self.done.set()


def recorded_fault(path: str) -> str | None:
    """The reason the fault record at ``path`` gives, None if there is none. A record that
    cannot be read (a FIFO, a symbolic link, a device, a huge or garbled file: read by
    ``safefile.read_bounded``, never blocking, never past FAULT_RECORD_MAX_BYTES) is a
    fault all the same: the start stays in fault, saying why."""
    try:
        raw = read_bounded(path, FAULT_RECORD_MAX_BYTES)
    except FileNotFoundError:
        return None
    except UnfitFile as exc:
        return f"unreadable fault record {path}: {unfit_reason(exc, FAULT_RECORD_MAX_BYTES)}"
    except OSError as exc:
        return f"unreadable fault record {path}: {exc.strerror or exc}"
    try:
        doc = json.loads(raw.decode("utf-8"))
        reason = str(doc.get("reason", "unknown"))
    except (ValueError, AttributeError, RecursionError):  # not UTF-8, not JSON, not a map
        return f"unreadable fault record {path}: not what softplc writes"
    return reason if len(reason) <= FAULT_REASON_MAX else reason[:FAULT_REASON_MAX] + "..."


class Daemon:
    """A plant run by a scan thread paced to its cycle; see the module docstring."""

    def __init__(self, pdef: PlantDef, *, plant: Plant | None = None, sim: bool = False,
                 clock: Callable[[], int] = time.monotonic_ns,
                 notifier: Notifier | None = None, trace: IO[str] | None = None,
                 manage_gc: bool = True) -> None:
        self.pdef = pdef
        self.plant = plant or Plant(pdef, sim=sim)
        self.clock = clock
        self.notifier = notifier or Notifier()
        self.scan_stats = ScanStats()
        self.scheduler = Scheduler(self._cycle, self.plant.cycle_ns, self.plant.watchdog_ns,
                                   idle=self._idle, serve=self._serve,
                                   on_watchdog=self._slow_scan,
                                   on_freeze=self._frozen, clock=clock,
                                   stats=self.scan_stats, manage_gc=manage_gc)
        # systemd's watchdog is fed by the watchdog thread, not by the scan's idle time:
        # a cycle longer than WatchdogSec is valid, only a stuck scan stops the pings
        # ...and STATUS= (percentiles over 8192 cycles) is built there too, never in the
        # scan thread (docs/daemon.md, "Timing")
        self.watchdog = Watchdog(self.scheduler, self.plant.watchdog_ns, self._trip, clock,
                                 ping=self.notifier.watchdog,
                                 ping_interval_ns=self.notifier.watchdog_interval_ns,
                                 status=self._report_status,
                                 status_interval_ns=STATUS_EVERY_NS)
        self.fault: str | None = None
        self.halted: str | None = None
        #: (wall-clock time, reason) of the last faults, oldest first
        self.faults: collections.deque[tuple[float, str]] = collections.deque(
            maxlen=FAULT_HISTORY)
        self.stopped = False
        self._stopping = False
        self.started_ns: int | None = None
        self._calls: collections.deque[ScanCall] = collections.deque()
        self._listeners: tuple[Callable[[int], None], ...] = ()
        self._listeners_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._loop_alive = False
        self._ready_sent = False  # scan thread: READY requested from the watchdog thread
        self._ready_told = False  # watchdog thread: READY=1 sent
        #: READY=1 held back until the start is complete (``serve`` holds it while the
        #: consoles and the feed bind and the drivers are checked: a start that then fails
        #: never told systemd it was up)
        self.ready_held = False
        self._state_changed = False  # scan thread -> watchdog thread: log the new state
        self._last_state: State | None = None
        self._trip_reason: str | None = None
        self.retain: RetainStore | None = None
        self._retain_writer: RetainWriter | None = None
        self._retain_next = 0
        self._retain_last: dict[str, Any] | None = None
        self._retain_lost: str | None = None  # started without the retained data: why
        self._latch_path = (pdef.retain_path + ".fault") if pdef.retain_path else None
        self._trace = TraceWriter(self.plant, trace) if trace is not None else None
        self._switch_was = sys.getswitchinterval()
        self._stats_cache: tuple[int, dict[str, Any]] | None = None
        self._stats_quantiles: tuple[int, tuple[list[int], list[int]]] | None = None
        #: the last ``stats()`` result, and the figures it was made from
        self._stats_out: tuple[tuple[int, dict[str, Any]], dict[str, Any]] | None = None
        #: logs step changes (``log: steps``), SFCError and overrun bursts
        self.events = EventWatcher(self.plant, self.scan_stats, clock)
        #: the plant's alarms and their states (runtime/controller/alarms.py)
        self.alarms = AlarmBoard(self)
        #: online change (``reload``): its flow and history (runtime/controller/reload.py)
        self.reloader = Reloader(self)
        #: while a reload reopens drivers: no scan, no driver read or written
        self._gap = False

    # -- life cycle ------------------------------------------------------------------
    def start(self) -> None:
        """Restore retained data, open the drivers (outputs written off), start the scan."""
        if self.pdef.lock_memory:
            done, why = lock_memory()
            if done:
                log.info("memory locked (mlockall)")
            else:
                log.warning("memory not locked: %s", why)
        cpu = self.pdef.realtime_cpu
        if cpu is not None:  # before the scan thread starts: it inherits the affinity
            done, why = pin_process(cpu)
            if done:
                log.info("the controller's threads on processor %d (plc: realtime: cpu)",
                         cpu)
            else:
                log.warning("the controller not kept to processor %d: %s", cpu, why)
        try:
            self._restore()
        except SourceError as exc:  # nothing opened yet: nothing for stop() to do
            self.notifier.status(exc.message)
            self.notifier.close()
            self._stopping = self.stopped = True
            raise
        self.plant.open()  # every output off before the first scan
        self.scheduler.stop_event.clear()
        self._switch_was = sys.getswitchinterval()
        switch = gil_switch_s(self.plant.cycle_ns)
        if switch < self._switch_was:  # a shorter one set before is kept
            sys.setswitchinterval(switch)
        self._loop_alive = True
        self._thread = threading.Thread(target=self._scan_thread, name="softplc-scan",
                                        daemon=True)
        if self._trace is not None:
            self.add_listener(self._trace)
        self.events.start()
        self.add_listener(self.events)
        self.alarms.start()
        self.add_listener(self.alarms.on_scan)
        self._thread.start()
        self.watchdog.start()
        log.info("running %s: %d instance(s), cycle %s ms, watchdog %s ms", self.pdef.path,
                 len(self.plant.instances), self.plant.cycle_ns / 1e6,
                 self.plant.watchdog_ns / 1e6)

    def stop(self, why: str = "stop requested") -> None:
        """Orderly stop: finish the current scan, every output off, save retained data,
        close the drivers. Idempotent."""
        if self._stopping:
            return
        self._stopping = True
        self.watchdog.stop_pinging()
        self.notifier.stopping(f"stopping: {why}")
        log.info("stopping: %s", why)
        self.scheduler.stop()
        if self._thread is not None:
            self._thread.join(timeout=max(5.0, 3 * self.plant.watchdog_ns / 1e9))
            if self._thread.is_alive():
                log.error("the scan thread did not stop: outputs forced off from here")
                for d in self.plant.drivers.values():
                    d.inhibit(True)
        self.stopped = True
        self.events.close()  # the scan thread is over: nothing more to watch
        self.alarms.close()
        if sys.getswitchinterval() < self._switch_was:
            sys.setswitchinterval(self._switch_was)
        self.watchdog.stop()
        self.plant.safe_state()
        if self._retain_writer is not None:
            self._retain_writer.submit(self.plant.retain_snapshot())
            self._retain_writer.close()
            if self._retain_writer.last_error is not None and self.retain is not None:
                log.error("retained data not saved at the stop: %s (%s keeps generation %d)",
                          self._retain_writer.last_error, self.retain.path,
                          self.retain.generation)
        if self._trace is not None:
            self._trace.close()
        self.plant.close()
        self.notifier.close()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for the scan thread to end (after stop); True if it did."""
        if self._thread is None:
            return True
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def _scan_thread(self) -> None:
        done, why = reduce_timer_slack()
        if not done:
            log.debug("timer slack not reduced: %s", why)
        prio = self.pdef.realtime_priority
        if prio is None:  # not set: real time where permitted (the installed service)
            done, why = set_fifo_priority(DEFAULT_REALTIME_PRIORITY)
            if done:
                log.info("scan thread at SCHED_FIFO priority %d", DEFAULT_REALTIME_PRIORITY)
            else:
                log.info("scan thread at normal priority (SCHED_FIFO %s): other processes "
                         "can delay its scans", why)
        elif not prio:
            log.info("scan thread at normal priority (plc: realtime: false)")
        else:
            done, why = set_fifo_priority(prio)
            if done:
                log.info("scan thread at SCHED_FIFO priority %d", prio)
            else:
                log.warning("scan thread not made real-time: %s", why)
        try:
            self.scheduler.run()
        except BaseException:  # noqa: BLE001 - the loop itself failed: fail safe, say why
            log.exception("scan loop failed")
            for d in self.plant.drivers.values():
                d.inhibit(True)
            raise
        finally:
            self._loop_alive = False
            while self._calls:  # nobody else will serve them now
                self._calls.popleft().run()

    # -- the cycle (scan thread) -----------------------------------------------------
    def _cycle(self, now: int) -> None:
        if self.started_ns is None:
            self.started_ns = now
        if self._gap:
            return
        try:
            if self.fault is not None or self.halted is not None:
                self.plant.exchange(zero_outputs=True)
                return
            stopped = self.plant.cycle(now)
        except Exception as exc:  # a bug in a chart or a driver: fail safe, keep looping
            if self.fault is None:
                log.exception("exception in a scan")
            self._enter_fault(f"exception in scan: {type(exc).__name__}: {exc}")
            return
        if stopped is not None:
            self._enter_fault(stopped)
        elif self._trip_reason is not None:
            self._enter_fault(self._trip_reason)

    def _enter_fault(self, reason: str) -> None:
        if self.fault is None:
            log.error("FAULT: %s: every output off, charts stopped until ack", reason)
            self.faults.append((time.time(), reason))
            self._latch(reason)
            self.fault = reason
        self.plant.safe_state()

    def _slow_scan(self, scan_ns: int) -> None:
        """The scheduler saw a scan longer than the watchdog (it returned, late)."""
        end = self.clock()
        frozen = self.watchdog.froze_during(end - scan_ns, end)
        if frozen:  # the process was stopped in the middle of the scan
            self.scan_stats.record_freeze(frozen)
            self._frozen(frozen)
        elif self.fault is None:
            self._enter_fault(self._trip_reason or
                              f"watchdog: a scan took {scan_ns / 1e6:.1f} ms (watchdog "
                              f"{self.plant.watchdog_ns / 1e6:g} ms)")

    def _frozen(self, frozen_ns: int) -> None:
        """The process did not run for longer than the watchdog (SIGSTOP, a paused VM, a
        suspend, a CPU taken by others): the outputs stood unwatched, a fault like an
        overrun."""
        reason = (f"frozen for {frozen_ns / 1e6:.0f} ms: the process did not run "
                  f"(stopped, paused, suspended or starved of CPU; watchdog "
                  f"{self.plant.watchdog_ns / 1e6:g} ms)")
        if self.fault is None:
            self._enter_fault(reason)
        else:
            log.warning("%s", reason)

    def _trip(self, running_ns: int) -> None:
        """Watchdog thread: a scan has been running too long; outputs off from here."""
        reason = (f"watchdog: a scan has been running for {running_ns / 1e6:.0f} ms "
                  f"(watchdog {self.plant.watchdog_ns / 1e6:g} ms)")
        self._trip_reason = reason
        for d in self.plant.drivers.values():
            d.inhibit(True)
        log.error("FAULT: %s: outputs forced off by the watchdog thread", reason)
        self._latch(reason)

    def _idle(self, until: int) -> None:
        """What the scan thread does between cycles, before ``until`` (monotonic ns)."""
        listeners = self._listeners
        if listeners:
            n = self.scan_stats.count
            for fn in listeners:
                fn(n)
        self._serve(until)
        state = self.state
        if state is not self._last_state or not self._ready_sent:
            # STATUS= and the log line are built by the watchdog thread: no percentile
            # sort in the scan thread
            if self._last_state is not None and state is not self._last_state:
                self._state_changed = True
            self._last_state = state
            if self.scan_stats.count > 0:
                self._ready_sent = True
            self.watchdog.request_status()
        if self._retain_writer is not None and (now := self.clock()) >= self._retain_next:
            self._retain_next = now + self.plant.retain_interval_ns
            snap = self.plant.retain_snapshot()
            if snap != self._retain_last or self._retain_writer.last_error is not None:
                self._retain_writer.submit(snap)
                self._retain_last = snap

    def _serve(self, until: int) -> None:
        """Run the queued ``call``s, stopping at monotonic ``until`` (the scheduler calls it
        again when one is queued in a long cycle's wait)."""
        calls = self._calls
        while calls:
            calls.popleft().run()
            if self.clock() >= until:
                break

    # -- retain and the fault latch ----------------------------------------------------
    def _restore(self) -> None:
        """Load the retained data and restore what the plant may reuse (docs/daemon.md,
        "Retained memory"); SourceError if it is lost and the plant requires it."""
        path = self.pdef.retain_path
        if path is None:
            return
        try:
            os.makedirs(os.path.dirname(os.path.abspath(path)), mode=0o750, exist_ok=True)
        except OSError as exc:
            log.error("retain directory of %s not usable: %s", path, exc)
        where = locate(self.pdef)
        self.retain = RetainStore(path, RetainedVars.of(self.pdef),
                                  owner={"name": where.name, "path": where.home})
        try:
            restored = restore(self.retain, refuse_if_lost=self.pdef.retain_required)
        except RetainForeign as exc:
            raise SourceError(self.pdef.retain_loc or Loc(self.pdef.path, 1, 1),
                              f"plc retain: {exc}") from None
        except RetainLost as exc:
            raise SourceError(self.pdef.retain_required_loc or Loc(self.pdef.path, 1, 1),
                              f"retained data required but lost ({exc}): not started") from None
        self.plant.restore_retain(restored.values)
        if restored.lost is not None:
            self._retain_lost = f"started without retained data: {restored.lost}"
        self._retain_last = self.plant.retain_snapshot()
        self._retain_writer = RetainWriter(self.retain)
        reason = recorded_fault(self._latch_path) if self._latch_path else None
        if reason is not None:
            self.fault = f"before the restart: {reason}"
            self.faults.append((time.time(), self.fault))
            log.error("FAULT carried over from the previous run (%s): outputs off until ack",
                      reason)

    def _latch(self, reason: str) -> None:
        """Record a fault on disk: if the process dies or is restarted by systemd's
        watchdog before an ack, it starts again in fault instead of resuming by itself."""
        if self._latch_path is None:
            return
        try:
            tmp = self._latch_path + ".tmp"
            # never through a link planted there; no fsync: this is the scan thread
            write_new(tmp, json.dumps({"reason": reason, "time": time.time()}).encode(),
                      exclusive=False, sync=False)
            os.replace(tmp, self._latch_path)
        except OSError as exc:
            log.warning("fault record not written: %s", exc)

    def _unlatch(self) -> None:
        if self._latch_path and os.path.lexists(self._latch_path):
            try:
                os.unlink(self._latch_path)
            except OSError as exc:
                log.warning("fault record not removed: %s", exc)

    # -- what the console uses ------------------------------------------------------
    def call(self, fn: Callable[[], R], timeout: float = 2.0) -> R:
        """Run ``fn`` in the scan thread at the next scan boundary and return its result
        (its exception is raised here). TimeoutError if the scan does not get to it."""
        if not self._loop_alive or threading.current_thread() is self._thread:
            return fn()
        c = self.submit(fn)
        if not c.done.wait(timeout):
            c.abandoned = True
            raise TimeoutError("the scan did not answer in time")
        if c.error is not None:
            raise c.error
        result: R = c.result
        return result

    def submit(self, fn: Callable[[], Any]) -> ScanCall:
        """Queue ``fn`` for the scan thread at the next scan boundary and return at once
        (``call`` without the wait: a thread serving several clients never waits for a
        scan). Run here and now when no scan thread runs, or from the scan thread."""
        c = ScanCall(fn)
        if not self._loop_alive or threading.current_thread() is self._thread:
            c.run()
        else:
            self._calls.append(c)
            self.scheduler.wake()
        return c

    @property
    def state(self) -> State:
        plant = self.plant
        if self.stopped:
            return State.STOPPED
        if self.fault is not None:
            return State.FAULT
        if self.halted is not None:
            return State.HALTED
        if self.started_ns is None:
            return State.STARTING
        if plant.iocheck:
            return State.IOCHECK
        if plant.held:
            return State.STEPPING if plant.stepping else State.PAUSED
        return State.RUNNING

    def next_scan_due(self) -> float:
        """Monotonic seconds at which the next cycle is due (0 before the first cycle):
        when work beside the scan must have let go of the GIL (ScanWindow)."""
        return self.scheduler.due / 1e9

    def uptime_s(self) -> float:
        return 0.0 if self.started_ns is None else (self.clock() - self.started_ns) / 1e9

    def inhibits(self) -> list[str]:
        """Every condition that keeps the charts or the outputs from running, worst first
        (empty when the plant runs freely)."""
        plant = self.plant
        out = []
        if self.fault is not None:
            out.append(f"fault: {self.fault}")
        if any(d.inhibited for d in plant.drivers.values()):
            out.append("outputs inhibited by the watchdog thread")
        if self.halted is not None:
            out.append(f"halted: {self.halted} (outputs off until ack)")
        if plant.iocheck:
            out.append("iocheck: charts stopped, outputs set by hand")
        out += [f"{name}: in fault: {why} (its outputs off until ack or reload --restart "
                f"{name})" for name, why in list(plant.instance_faults.items())]
        if plant.stepping:
            out.append(f"stepping by the console: {plant.steps_left} cycle(s) to go")
        elif plant.held:
            out.append("paused by the console: charts held")
        for name, flags in self.held().items():
            out += [f"{name}: held by {flag}" for flag in flags]
        return out

    def held(self) -> dict[str, list[str]]:
        """The instances held by one of their chart flags (HOLD_FLAGS) -> those flags."""
        held = {}
        for name, inst in list(self.plant.instances.items()):  # read from any thread
            flags = [flag for flag in HOLD_FLAGS if inst.get(flag)]
            if flags:
                held[name] = flags
        return held

    def release_ready(self) -> None:
        """The start is complete: READY=1 (with the status line) as soon as a cycle ran."""
        self.ready_held = False
        self.watchdog.request_status()

    def _report_status(self) -> None:
        """Watchdog thread: READY=1 then STATUS= with ``summary()``, and the state line in
        the log when the scan thread saw the state change."""
        if not self._ready_sent or self.ready_held:
            return  # no cycle yet, or the start not complete: READY=1 comes after both
        changed, self._state_changed = self._state_changed, False  # a later one re-flags
        if not self.notifier.enabled and not changed:
            return  # nobody to tell: no percentiles computed for nothing
        text = self.summary()
        if not self._ready_told:
            self._ready_told = True
            self.notifier.ready(text)
        else:
            self.notifier.status(text)
        if changed:
            log.info("state: %s", text)

    def summary(self) -> str:
        """One line: state, what inhibits the plant, cycle figures (systemd's STATUS=,
        logs). Safe from any thread but the scan thread: the p99 figures never hold the
        GIL for long, and their thread pauses between the slices of the work."""
        scan_p99, late_p99 = self.scan_stats.p99(_stats_pause)
        text = self.state.value
        inhibits = [x.removeprefix(f"{text}: ") for x in self.inhibits()]
        if inhibits:
            text += f" ({'; '.join(inhibits)})"
        stats = self.scan_stats
        text += (f"; {len(self.plant.instances)} instance(s); {stats.count} cycles; "
                 f"scan p99 {scan_p99 / 1e3:.0f} us; lateness p99 {late_p99 / 1e3:.0f} us; "
                 f"{stats.overruns} overruns")
        if stats.freezes:
            text += f"; {stats.freezes} freezes"
        retain = self.retain_status()
        if retain is not None and retain["state"] != "ok":
            text += f"; retain {retain['state']}"
        return text

    def status(self) -> dict[str, Any]:
        """State, fault, ``inhibits`` (see ``inhibits()``), counts and the last faults;
        ``instance_faults``: the instances in fault by themselves (no active step left),
        with why; ``alarms``: the alarm board (``AlarmBoard.as_list``)."""
        return {"state": self.state.value, "fault": self.fault or self.halted,
                "inhibits": self.inhibits(), "held": self.held(),
                "scans": self.scan_stats.count, "uptime_s": round(self.uptime_s(), 3),
                "cycle_ms": self.plant.cycle_ns / 1e6, "freezes": self.scan_stats.freezes,
                "faults": [{"time": t, "reason": r} for t, r in self.faults],
                "retain": self.retain_status(), "reload": self.reloader.last(),
                "instance_faults": dict(self.plant.instance_faults),
                "alarms": self.alarms.as_list()}

    def retain_status(self) -> dict[str, Any] | None:
        """``status``'s ``retain`` entry: state ok | failing | lost, since (wall time), text;
        None without a retain file."""
        w, store = self._retain_writer, self.retain
        if w is None or store is None:
            return None
        texts = []
        if w.failing_since is not None:
            since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(w.failing_since))
            texts.append(f"saving fails since {since}: {w.last_error}")
        if self._retain_lost is not None:
            texts.append(self._retain_lost)
        state = "failing" if w.failing_since is not None else \
            "lost" if self._retain_lost is not None else "ok"
        return {"state": state, "since": w.failing_since, "generation": store.generation,
                "text": "; ".join(texts) or f"saved, generation {store.generation}"}

    def stats(self, pause: Callable[[], object] | None = None) -> dict[str, Any]:
        """Cycle statistics (µs) and driver health, computed at most every
        STATS_MAX_AGE_NS of cycles, their percentiles (of up to 8192 cycles: a few ms of
        processor time, in slices with ``pause()`` between them: by default a sleep of
        STATS_PAUSE_S; the console's waits for its next window once its window has
        closed) at most every STATS_QUANTILES_MAX_AGE_NS, however many consoles ask
        (docs/console.md, "Transports and limits"). Until they are computed again and
        while no driver's health changes, every caller gets the same dict (do not change
        it): the console formats its reply once for all."""
        stats = self.scan_stats
        count = stats.count
        cached = self._stats_cache
        if (cached is None or count < cached[0]  # reset since
                or count - cached[0] >= max(1, STATS_MAX_AGE_NS // self.plant.cycle_ns)):
            quantiles = self._stats_quantiles
            if (quantiles is None or count < quantiles[0] or count - quantiles[0]
                    >= max(1, STATS_QUANTILES_MAX_AGE_NS // self.plant.cycle_ns)):
                quantiles = self._stats_quantiles = (count,
                                                     stats.window_quantiles(
                                                         pause or _stats_pause))
            cached = self._stats_cache = (count, stats.as_dict(quantiles[1]))
        drivers = {name: {"health": d.health.value, "on_fault": d.on_fault.value,
                          "reason": d.fault_reason}
                   for name, d in self.plant.drivers.items()}
        cycle_us = self.plant.cycle_ns / 1e3
        last = self._stats_out
        if (last is not None and last[0] is cached and last[1]["drivers"] == drivers
                and last[1]["cycle_us"] == cycle_us):
            return last[1]
        out = {**cached[1], "cycle_us": cycle_us, "drivers": drivers}
        self._stats_out = (cached, out)
        return out

    def ack(self) -> str:
        """Acknowledge a fault, a halt or SFCError; raises CommandRefused if the cause of
        the fault is still there or there is nothing to acknowledge."""
        return self.call(self._ack)

    def _ack(self) -> str:
        plant = self.plant
        done = []
        if self.fault is not None:
            cause = plant.faulted()
            if cause is not None:
                raise CommandRefused(f"the fault is still there: {cause}")
            for d in plant.drivers.values():
                d.inhibit(False)
            # the console's ack logs this, naming the console (changing.cmd_ack)
            log.debug("fault acknowledged (%s): charts restart from their initial "
                      "situation", self.fault)
            self.fault = None
            self._trip_reason = None
            self._unlatch()
            plant.restart()
            done.append("fault acknowledged: charts restarted from their initial situation")
        if self.halted is not None:
            log.debug("acknowledged: %s", self.halted)
            self.halted = None
            plant.restart()
            done.append("charts restarted from their initial situation")
        for name, why in list(plant.instance_faults.items()):
            plant.restart_instance(name)
            done.append(f"{name}: in fault ({why}): restarted from its initial situation")
        for name, inst in plant.instances.items():
            if inst.get("SFCError"):
                plant.pulse(name, "SFCQuitError")
                step = inst.get("SFCErrorStep")
                done.append(f"SFCError of {name} ({sfcerror_cause(step)}) acknowledged")
        if not done:
            raise CommandRefused("nothing to acknowledge")
        forced = plant.forced_names()
        if forced:  # no force survives an ack: the restarted charts start clean
            plant.unforce(None)
            log.debug("ack released every force: %s", ", ".join(forced))
            done.append(f"forces released: {', '.join(forced)}")
        return "; ".join(done)

    def require_ack(self, reason: str) -> None:
        """Hold every output off and the charts stopped until ``ack`` (after iocheck)."""
        def halt() -> None:
            self.halted = reason
            self.plant.safe_state()
        self.call(halt)

    # -- online change (runtime/controller/reload.py) ----------------------------------------
    def reload(self, files: str | None = None, *, restart: Collection[str] = (),
               force: bool = False, back: bool = False) -> ReloadResult:
        """Load the plant file again (or ``files``), or go ``back`` to the program that
        ran before the last change, and apply it between two cycles without a stop
        (docs/online-change.md). Any thread but the scan thread; one at a time."""
        if self._thread is not None and threading.current_thread() is self._thread:
            raise RuntimeError("reload is never run in the scan thread")
        return self.reloader.reload(files, restart=restart, force=force, back=back)

    def on_reload(self, hook: ReloadHook) -> None:
        """Have ``hook`` follow the plant across reloads (the console's names)."""
        self.reloader.add_hook(hook)

    def prepare_switch(self, plant: Plant, pdef: PlantDef) -> Callable[[], None]:
        """Reload worker thread: what the daemon's own holders of the plant need (trace
        columns, event watcher, alarm board, retained variables), built now; the returned
        function switches them in the scan thread."""
        commit_events = self.events.prepare_switch(plant)
        commit_alarms = self.alarms.prepare_switch(plant)
        trace = self._trace
        columns = trace_columns(plant) if trace is not None else []
        retained = RetainedVars.of(pdef)

        def commit() -> None:
            commit_events()
            commit_alarms()
            if trace is not None:
                trace.plant, trace.columns = plant, columns
            if self.retain is not None:
                self.retain.plant = retained
                self._retain_last = None  # saved at the next idle time, with its charts
                self._retain_next = 0
        return commit

    def switch_plant(self, plant: Plant, pdef: PlantDef) -> None:
        """Scan thread, at the swap: ``plant`` runs from the next cycle on."""
        self.plant, self.pdef = plant, pdef

    def set_gap(self, on: bool) -> None:
        """Scan thread: while on, cycles neither scan nor touch a driver (a reload
        reopening drivers)."""
        self._gap = on

    def add_listener(self, fn: Callable[[int], None]) -> None:
        """Call ``fn(cycle_number)`` in the scan thread after every cycle (keep it tiny)."""
        with self._listeners_lock:
            self._listeners = (*self._listeners, fn)

    def remove_listener(self, fn: Callable[[int], None]) -> None:
        with self._listeners_lock:
            self._listeners = tuple(f for f in self._listeners if f != fn)


def _stats_pause() -> None:
    """Between two slices of a percentile computation (not in the scan thread)."""
    time.sleep(STATS_PAUSE_S)
