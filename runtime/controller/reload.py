"""Online change of a running controller: ``Daemon.reload`` (docs/online-change.md).

The flow, one reload at a time:

1. load the plant file again (its charts from disk), or take the program that ran before
   the last change (``back``), and compile its code, in a child process under limits
   (runtime/controller/reloadchild.py; a child that fails is a refused reload);
2. in a worker thread, never the scan thread: ``runtime.change.prepare`` (compile, build
   the new Plant on the open drivers) and what each holder of the plant needs built in
   advance (the console's names, the trace columns, the event watcher's flags, the
   retained variables);
3. in the scan thread, between two cycles, in ONE call: ``runtime.change.apply`` (all or
   nothing), and on success every holder switched to the new plant (cheap assignments);
4. outside the scan: drivers that ``apply`` asks to reopen are closed and opened again
   (the charts stand still meanwhile, see ``_reopen``), drivers no longer in the plant are
   put off and closed, the change is logged with the sha256 of every file and kept in the
   history.

A load or compile error, a refusal, or a scan that does not answer: the running program is
untouched and the result says why, one line per reason (each also logged).
"""

from __future__ import annotations

import collections
import gc
import logging
import sys
import threading
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from runtime.change.plan import Applied, Prepared, apply, file_hashes, prepare
from runtime.compiler.codebook import CodeBook
from runtime.controller.reloadchild import INTERNAL, compile_apart, load_apart
from runtime.engine.plant import Plant
from runtime.errors import SoftplcError
from runtime.language.model import PlantDef

if TYPE_CHECKING:
    from runtime.controller.daemon import Daemon

log = logging.getLogger(__name__)

#: applied changes remembered (``status``, ``Reloader.history``); the log keeps them all
HISTORY_KEPT = 20
#: how long the scan thread may take to get to the swap, s (it runs between two cycles:
#: a scan that does not get there in this time is stuck, and the watchdog acts on it)
SWAP_TIMEOUT_S = 30.0
#: what a reload asked while another runs is told
IN_PROGRESS = "reload in progress"

#: a holder of the plant (the console): called in the worker thread with the new plant,
#: returns what to run in the scan thread at the swap (cheap: assignments). What that
#: returns (what the holder replaced, or None) is let go of after the swap by the thread
#: that asked for the reload, never by the scan thread (``let_go``)
ReloadHook = Callable[[Plant], Callable[[], object]]


def let_go(objects: list[object]) -> None:
    """Drop ``objects`` (emptied), one at a time; one that has a ``release`` method and
    that nobody else holds is released first (a Catalogue lets go of its names one at a
    time: dropped whole, its ~4000 names at 100 testers go in one cascade of frees, some
    2 ms during which no other thread can take the GIL). One that another thread still
    holds is only dropped here: it stays whole for that thread, which frees it last."""
    while objects:
        obj = objects.pop()
        # 2: ``obj`` and getrefcount's argument; nobody can reach it from elsewhere then
        if sys.getrefcount(obj) == 2:
            release = getattr(obj, "release", None)
            if release is not None:
                release()
                del release
        del obj


@dataclass
class ReloadResult:
    """What a reload did: ``applied``, or why not (``refusals``, one line per reason)."""

    applied: bool
    lines: list[str] = field(default_factory=list)
    refusals: list[str] = field(default_factory=list)
    restarted: list[str] = field(default_factory=list)
    reopened: list[str] = field(default_factory=list)
    #: instances the change left in fault (no active step), with why
    instance_faults: dict[str, str] = field(default_factory=dict)
    #: one line: what changed ("3 changes: tester1: ...")
    summary: str = ""
    #: file -> sha256 of the program now running
    hashes: dict[str, str] = field(default_factory=dict)
    back: bool = False
    #: time the change took, ms: the load (a child process), the prepare (worker
    #: thread) and the apply with the switch (scan thread, between two cycles)
    load_ms: float = 0.0
    prepare_ms: float = 0.0
    swap_ms: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return {"applied": self.applied, "lines": self.lines, "refusals": self.refusals,
                "restarted": self.restarted, "reopened": self.reopened,
                "instance_faults": self.instance_faults,
                "summary": self.summary, "hashes": self.hashes, "back": self.back,
                "load_ms": round(self.load_ms, 3), "prepare_ms": round(self.prepare_ms, 3),
                "swap_ms": round(self.swap_ms, 3)}


@dataclass(frozen=True)
class Change:
    """One applied change, as the history keeps it."""

    time: float  # wall clock, s
    summary: str
    hashes: dict[str, str]
    back: bool

    def as_dict(self) -> dict[str, Any]:
        return {"time": self.time, "summary": self.summary, "hashes": self.hashes,
                "back": self.back}


class Reloader:
    """The reload flow and history of one daemon (see the module docstring).

    One level of ``back``: the PlantDef that ran before the last applied change (and its
    file hashes) is kept; ``back`` prepares it again and applies it by the same path, and
    then the program it replaced becomes the one ``back`` returns to (two ``back`` in a
    row toggle between the two programs)."""

    def __init__(self, daemon: Daemon) -> None:
        self.daemon = daemon
        self.history: collections.deque[Change] = collections.deque(maxlen=HISTORY_KEPT)
        #: the program ``back`` returns to, with the hashes of its files
        self.previous: tuple[PlantDef, dict[str, str]] | None = None
        #: the sha256 of the running program's files (at the start: as they were on disk
        #: when the daemon was made)
        self.hashes: dict[str, str] = file_hashes(daemon.pdef)
        self._lock = threading.Lock()
        self._hooks: list[ReloadHook] = []
        #: the plant file the controller started with: its identity and runtime directory
        #: stay, whatever file a reload loads
        self.plant_path = daemon.pdef.path

    def add_hook(self, hook: ReloadHook) -> None:
        """Have ``hook`` follow the plant across reloads (see ReloadHook)."""
        self._hooks.append(hook)

    @property
    def busy(self) -> bool:
        return self._lock.locked()

    def reload(self, files: str | None = None, *, restart: Collection[str] = (),
               force: bool = False, back: bool = False) -> ReloadResult:
        """Load the plant again (``files``: another plant file; default the one the
        daemon runs) or go ``back`` to the previous program, and apply it between two
        cycles. Never raises for a refused change: see ReloadResult."""
        if not self._lock.acquire(blocking=False):
            return self._refused([IN_PROGRESS], back)
        try:
            return self._reload(files, tuple(restart), force, back)
        finally:
            self._lock.release()

    # -- the flow ------------------------------------------------------------------------
    def _reload(self, files: str | None, restart: tuple[str, ...], force: bool,
                back: bool) -> ReloadResult:
        daemon = self.daemon
        old_pdef = daemon.pdef
        t_load = time.perf_counter()
        if back:
            if self.previous is None:
                return self._refused(["no previous program to go back to (no change was "
                                      "applied since the start)"], back)
            new_pdef, _ = self.previous
            pdef = new_pdef
            loaded = self._in_worker(lambda: compile_apart(pdef))
        else:
            # the new version's ${RUNTIME_DIR} is the running plant's (its lock's)
            loaded = self._in_worker(lambda: load_apart(files or old_pdef.path,
                                                        self.plant_path))
        if isinstance(loaded, str):
            return self._refused([loaded], back)
        new_pdef, book = loaded
        load_ms = (time.perf_counter() - t_load) * 1e3
        refusals = self._static_refusals(old_pdef, new_pdef, restart)
        if refusals:
            return self._refused(refusals, back)
        t0 = time.perf_counter()
        built = self._in_worker(lambda: self._build(daemon.plant, new_pdef, book))
        prepare_ms = (time.perf_counter() - t0) * 1e3
        if isinstance(built, str):
            return self._refused([built], back)
        prepared, commits = built
        result = self._swap(prepared, new_pdef, commits, restart, force)
        result.back, result.load_ms, result.prepare_ms = back, load_ms, prepare_ms
        if not result.applied:
            for line in result.refusals:
                log.warning("reload refused: %s", line)
            return result
        # back: the files on disk are the changed ones, the hashes kept are the program's
        hashes = dict(self.previous[1]) if back and self.previous else dict(prepared.hashes)
        self.previous = (old_pdef, self.hashes)
        self.hashes = result.hashes = hashes
        self.history.append(Change(time.time(), result.summary, result.hashes, back))
        log.warning("reload%s applied in %.1f ms (loaded in %.0f ms, prepared in %.0f ms): "
                    "%s; %s", " --back" if back else "", result.swap_ms, load_ms,
                    prepare_ms, result.summary,
                    ", ".join(f"{f} sha256 {h}" for f, h in result.hashes.items()))
        for line in result.lines:
            log.info("reload: %s", line)
        for name, why in result.instance_faults.items():
            log.error("FAULT of instance %s: %s: its outputs off until ack or reload "
                      "--restart %s", name, why, name)
        return result

    def _static_refusals(self, old: PlantDef, new: PlantDef,
                         restart: tuple[str, ...]) -> list[str]:
        """``--restart`` names that are no instance, and iocheck on. (The plant settings a
        running controller cannot change are refused by ``runtime.change``'s diff, so
        that ``softplc diff`` says the same.)"""
        out: list[str] = []
        out += [f"--restart {name}: no instance {name} in the new plant"
                for name in restart if name not in new.instances]
        if self.daemon.plant.iocheck:
            out.append("iocheck on: end it first ('iocheck off', then 'ack')")
        return out

    def _build(self, old: Plant, new_pdef: PlantDef, book: CodeBook
               ) -> tuple[Prepared, list[Callable[[], object]]]:
        """Worker thread: the new plant, and each holder's switch, built in advance."""
        sched = self.daemon.scheduler
        sched.gc_held = True
        try:
            prepared = prepare(old, new_pdef, book)
            commits: list[Callable[[], object]] = [
                self.daemon.prepare_switch(prepared.plant, new_pdef)]
            commits += [hook(prepared.plant) for hook in self._hooks]
            if not gc.isenabled():
                # the new plant and its holders live until the next change: out of the
                # collector's sight, like the first plant at start-up (a splice of
                # lists, not a collection); a failed prepare's objects are not frozen
                gc.freeze()
        finally:
            sched.gc_held = False
        log.debug("reload: %d code objects from the child, %d compiled here", book.hits,
                  book.misses)
        return prepared, commits

    def _in_worker(self, fn: Callable[[], Any]) -> Any:
        """Run ``fn`` in a thread of its own (never the scan thread, whoever calls reload);
        an exception comes back as its one-line text."""
        box: list[Any] = []

        def run() -> None:
            try:
                box.append(fn())
            except SoftplcError as exc:
                box.append(f"compile error: {exc}")
            except Exception:  # noqa: BLE001 - a bug: said in one line, logged
                log.exception("reload: preparing the new program failed")
                box.append(f"the new program could not be prepared: {INTERNAL}")
        t = threading.Thread(target=run, name="softplc-reload", daemon=True)
        t.start()
        t.join()
        return box[0]

    def _swap(self, prepared: Prepared, new_pdef: PlantDef,
              commits: list[Callable[[], object]], restart: tuple[str, ...],
              force: bool) -> ReloadResult:
        """Scan thread, between two cycles: apply, and on success switch every holder. If
        the scan does not get to it in SWAP_TIMEOUT_S, it is cancelled untouched (or, if
        it had begun, waited for)."""
        daemon = self.daemon
        old = daemon.plant
        gate = threading.Lock()
        began, cancelled = threading.Event(), [False]
        done = threading.Event()
        out: list[tuple[Applied, float]] = []
        replaced: list[object] = []  # what the holders let go of at the swap

        def swap() -> None:
            with gate:
                if cancelled[0]:
                    return
                began.set()
            try:
                t0 = time.perf_counter_ns()
                applied = apply(old, prepared, restart=restart, force=force)
                if not applied.refusals:
                    if applied.reopened or applied.closed:
                        daemon.set_gap(True)  # no cycle before they are closed/opened
                    daemon.switch_plant(prepared.plant, new_pdef)
                    replaced.extend(commit() for commit in commits)
                out.append((applied, (time.perf_counter_ns() - t0) / 1e6))
            finally:
                done.set()
        try:
            daemon.call(swap, timeout=SWAP_TIMEOUT_S)
        except TimeoutError:
            with gate:
                if not began.is_set():
                    cancelled[0] = True
                    prepared.plant.dispose()
                    return ReloadResult(False, refusals=[
                        "the scan did not answer in time: nothing changed"])
            done.wait()
        if not out:  # apply itself raised: nothing was switched (all or nothing)
            prepared.plant.dispose()
            return ReloadResult(False, refusals=["the change could not be applied (see the "
                                                 "log): nothing changed"])
        applied, swap_ms = out[0]
        lines = list(applied.lines)
        if applied.refusals:
            prepared.plant.dispose()
            return ReloadResult(False, lines=lines, refusals=list(applied.refusals),
                                swap_ms=swap_ms)
        if applied.reopened or applied.closed:
            self._reopen(old, prepared.plant, applied.closed, applied.reopened)
        # what the holders replaced (the console's names of the old plant) goes here, not
        # in the scan thread, where it was freed inside the swap (3.4 ms more there at 100
        # testers, docs/online-change.md)
        let_go(replaced)
        # the old plant is dropped by every holder now: freed by reference counting (it
        # was frozen, out of the collector's sight, at the start or by the last reload)
        old.dispose()
        return ReloadResult(True, lines=lines, restarted=list(applied.restarted),
                            reopened=list(applied.reopened),
                            instance_faults=dict(applied.instance_faults),
                            summary=_summary(lines), swap_ms=swap_ms)

    def _reopen(self, old: Plant, new: Plant, closed: list[str], opened: list[str]) -> None:
        """Outside the scan, during the daemon's ``gap`` (set at the swap: the cycles
        neither scan nor touch a driver): the old plant's drivers that are gone or
        replaced put off and closed, then the new ones opened and written off (as at the
        start). The other drivers' outputs stay as they were for the gap."""
        daemon = self.daemon
        try:
            for name in closed:
                try:
                    old.drivers[name].close()  # outputs off first
                except Exception:  # noqa: BLE001 - the others are still closed
                    log.exception("reload: driver %s not closed", name)
            for name in opened:
                d = new.drivers[name]
                d.open()
                d.safe_state()
                log.warning("reload: driver %s opened (%s)", name, d.health.value)
        finally:
            daemon.call(lambda: daemon.set_gap(False), timeout=SWAP_TIMEOUT_S)

    def _refused(self, reasons: list[str], back: bool) -> ReloadResult:
        for line in reasons:
            log.warning("reload%s refused: %s", " --back" if back else "", line)
        return ReloadResult(False, refusals=reasons, back=back)

    def last(self) -> dict[str, Any] | None:
        """The last applied change (``status``), None if none."""
        return self.history[-1].as_dict() if self.history else None


def _summary(lines: list[str]) -> str:
    """One line for the log and ``status``: the count and the first changes."""
    if not lines:
        return "no change"
    head = "; ".join(lines[:3])
    more = f"; ... ({len(lines) - 3} more)" if len(lines) > 3 else ""
    return f"{len(lines)} change{'s' if len(lines) != 1 else ''}: {head}{more}"
