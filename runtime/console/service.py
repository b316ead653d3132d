"""What every console session shares: the Controller it talks to (a protocol the daemon
fulfils), and the ConsoleService holding the plant's names, the PIN and its per-peer
lock-out, and what each session holds (pause, stepping, iocheck, forces) with its limits.

The scan is never disturbed: every read and write of the plant goes through
``Controller.call``, which runs a short function in the scan thread at a scan boundary, so
a reply is one consistent snapshot. Who holds what is recorded inside those same calls, so
a session's end and its own commands can never interleave half-way.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from runtime.console.protocol import LOCKOUT_MAX_S, LOCKOUT_MIN_S, MAX_PIN_TRIES, Reply
from runtime.console.streams import StreamTap
from runtime.controller.pin import check_pin
from runtime.engine.names import Catalogue, CommandError
from runtime.engine.plant import Plant
from runtime.language.model import ConsoleLimits

if TYPE_CHECKING:
    from runtime.console.session import Session

log = logging.getLogger(__name__)
R = TypeVar("R")


class Controller(Protocol):
    """What the console needs from the running daemon (runtime.controller.daemon.Daemon)."""

    plant: Plant

    def call(self, fn: Callable[[], R], timeout: float = 2.0) -> R:
        """Run ``fn`` in the scan thread at the next scan boundary; return its result."""

    def status(self) -> dict[str, Any]:
        """state, fault, inhibits, held, scans, uptime_s, cycle_ms, freezes, faults, retain,
        alarms."""

    def next_scan_due(self) -> float:
        """Monotonic seconds at which the next cycle is due (0 before the first)."""

    def stats(self, pause: Callable[[], object] | None = None) -> dict[str, Any]:
        """Cycle statistics (us) and per-driver health; ``pause()`` between the slices of
        a long computation (ScanWindow.pause)."""

    def ack(self) -> str:
        """Acknowledge a fault (restart the charts) or SFCError; returns what was done."""

    def require_ack(self, reason: str) -> None:
        """Hold outputs off and charts stopped until ``ack`` (after iocheck)."""

    def add_listener(self, fn: Callable[[int], None]) -> None:
        """Call ``fn(cycle_number)`` in the scan thread after each cycle."""

    def remove_listener(self, fn: Callable[[int], None]) -> None: ...

    def reload(self, files: str | None = None, *, restart: Collection[str] = (),
               force: bool = False, back: bool = False) -> Any:
        """Online change (Daemon.reload): a ReloadResult (applied, lines, refusals...)."""


#: what a session may hold besides forces ("force NAME"), in the order they are reported
HOLD_ORDER = ("iocheck", "pause", "cycle")
#: the reason the server gives when the daemon stops in order: forces released, no halt
SERVER_STOPPING = "server stopping"
#: how every halt reason of the console ends: what ``ack`` will do
ACK_RESTARTS = "'ack' restarts the charts from their initial situation"


@dataclass
class Hold:
    """Something a session holds: the pause, stepping (``cycle``), iocheck or one force."""

    owner: Session
    #: when it was taken (or taken again), service clock seconds
    since: float
    warned: bool = False
    expiring: bool = False


@dataclass
class _Peer:
    """Wrong PINs from one peer (a serial port, a local uid, TCP)."""

    wrong: int = 0
    locked_until: float = 0.0
    #: the length of its last lock-out, s (0: none yet); the next one doubles it
    lockout_s: float = 0.0
    #: held while one of its PINs is checked
    trying: threading.Lock = field(default_factory=threading.Lock)


class ConsoleService:
    """State shared by every session: the controller, its names, the PIN and its
    per-peer lock-out, and who holds what. Sessions run in their own threads: ``lock``
    guards the lock-out, the holds and the notices; holds change only inside
    ``Controller.call`` (the scan thread), next to the plant change they record."""

    def __init__(self, controller: Controller, pin_hash: str | None = None,
                 release_forces_on_disconnect: bool = False,
                 clock: Callable[[], float] = time.monotonic,
                 limits: ConsoleLimits | None = None) -> None:
        self.controller = controller
        self.catalogue = Catalogue(controller.plant)
        #: the images of the sessions' streams: one copy per scan for all of them
        self.tap = StreamTap(controller)
        self.pin_hash = pin_hash
        #: counts the PIN changes (an online change of ``pin_hash``): a session unlocked
        #: with an older PIN is locked again
        self.pin_generation = 0
        #: a session that held only forces: release them without halting (plant key)
        self.release_on_disconnect = release_forces_on_disconnect
        self.limits = limits if limits is not None else controller.plant.pdef.console_limits
        #: monotonic seconds; injectable so tests step time instead of sleeping
        self.clock = clock
        self._peers: dict[str, _Peer] = {}
        #: "pause", "cycle", "iocheck", "force NAME" -> who holds it since when
        self._holds: dict[str, Hold] = {}
        self._notices: dict[Session, list[str]] = {}
        self._ending: set[Session] = set()
        self._end_failed: set[Session] = set()
        self.lock = threading.Lock()
        #: the last ``stats`` reply and the daemon's figures it shows: the daemon gives
        #: the same object while they have not changed, so a flood of ``stats`` formats
        #: one reply per STATS_MAX_AGE_NS of cycles (commands.cmd_stats)
        self.stats_reply: tuple[object, Reply] | None = None
        #: the last JSON reply built from a reply's data, and that data: a shared reply
        #: (``stats``) is encoded once for every session in JSON mode (Session._reply_ok)
        self.json_reply: tuple[object, object, str] | None = None
        #: called between the slices of a long computation in a session's thread (the
        #: percentiles of ``stats``): the console server's ScanWindow.pause, which holds
        #: it to the window after each scan; None: the controller's own pause
        self.pause: Callable[[], object] | None = None
        on_reload = getattr(controller, "on_reload", None)
        if on_reload is not None:  # a reload gives the sessions the new plant's names
            on_reload(self._reloaded)

    def _reloaded(self, plant: Plant) -> Callable[[], Catalogue]:
        """Reload worker thread: the new plant's names, built now; the returned function
        (scan thread, at the swap) makes them the sessions' names, takes the new plant
        file's PIN, limits and forces policy (a new PIN locks the sessions unlocked with
        the old one), and lets go of the forces the change released; it returns the old
        names, freed by the reload's thread (``reload.let_go``), not the scan thread. A
        running watch or trace then ends ("reloaded")."""
        catalogue = Catalogue(plant)
        pdef = plant.pdef

        def commit() -> Catalogue:
            old, self.catalogue = self.catalogue, catalogue
            if pdef.pin_hash != self.pin_hash:
                self.pin_hash = pdef.pin_hash
                self.pin_generation += 1
            self.release_on_disconnect = pdef.release_forces_on_disconnect
            self.limits = pdef.console_limits
            forced = set(plant.forced_names())
            with self.lock:
                for w in [w for w in self._holds if w.startswith("force ")
                          and w[len("force "):] not in forced]:
                    del self._holds[w]
            return old
        return commit

    def session(self, name: str, trusted: bool = False, peer: str | None = None) -> Session:
        """A new session of this console. ``name`` says where it is (for the log),
        ``peer`` who is at the other end (``serial:/dev/ttyS0``, ``uid:1000``, ``tcp``;
        default: the name): wrong PINs lock out that peer only."""
        from runtime.console.session import Session  # session.py imports this module
        return Session(self, name, trusted, peer)

    # -- the PIN ---------------------------------------------------------------------
    def try_pin(self, pin: str, who: str, peer: str) -> None:
        """Check a PIN typed at session ``who`` by ``peer``; raise CommandError if it is
        wrong or that peer is locked out. MAX_PIN_TRIES wrong PINs in a row lock that
        peer's ``unlock`` out for LOCKOUT_MIN_S, doubling at each further lock-out up to
        LOCKOUT_MAX_S; other peers are not affected."""
        if self.pin_hash is None:
            raise CommandError("no pin_hash in the plant file: nothing to unlock")
        with self.lock:
            p = self._peers.setdefault(peer, _Peer())
        # one try at a time per peer (more connections give no more tries), and the slow
        # hash outside ``lock``, which the scan thread takes to record holds
        with p.trying:
            with self.lock:
                now = self.clock()
                left = p.locked_until - now
            if left > 0:
                raise CommandError(f"console locked for {left:.0f} s after "
                                   f"{MAX_PIN_TRIES} wrong PINs")
            if check_pin(pin, self.pin_hash):
                with self.lock:
                    p.wrong, p.lockout_s = 0, 0.0
                return
            with self.lock:
                p.wrong += 1
                tries_left = MAX_PIN_TRIES - p.wrong
                if not tries_left:
                    recent = p.lockout_s and now - p.locked_until < LOCKOUT_MAX_S
                    p.lockout_s = (min(2 * p.lockout_s, LOCKOUT_MAX_S) if recent
                                   else LOCKOUT_MIN_S)
                    p.wrong, p.locked_until = 0, now + p.lockout_s
        if tries_left:
            log.warning("console %s: wrong PIN (%d of %d)", who, MAX_PIN_TRIES - tries_left,
                        MAX_PIN_TRIES)
            raise CommandError(f"wrong PIN ({tries_left} "
                               f"{'try' if tries_left == 1 else 'tries'} left)")
        log.warning("console %s: %d wrong PINs, unlock refused to %s for %.0f s", who,
                    MAX_PIN_TRIES, peer, p.lockout_s)
        raise CommandError(f"wrong PIN; locked for {p.lockout_s:.0f} s")

    # -- who holds what (called inside Controller.call) --------------------------------
    def hold(self, what: str, session: Session) -> None:
        """``session`` takes ``what`` ("pause", "cycle", "iocheck", "force NAME"), or
        takes it again: its time limit starts again. Call it before the plant change it
        records; CommandError if the session is closing."""
        if session.closed:
            raise CommandError("the session is ending")
        with self.lock:
            self._holds.pop(what, None)  # taken again: reported last, like a new one
            self._holds[what] = Hold(session, self.clock())

    def let_go(self, *what: str) -> None:
        """Nobody holds ``what`` any more (resume, iocheck off, unforce NAME)."""
        with self.lock:
            for w in what:
                self._holds.pop(w, None)

    def let_go_forces(self) -> None:
        """No force is held any more (every force was released)."""
        with self.lock:
            for w in [w for w in self._holds if w.startswith("force ")]:
                del self._holds[w]

    def holdings(self, session: Session | None = None) -> list[str]:
        """What ``session`` (None: anybody) holds: iocheck, pause, cycle, then forces."""
        with self.lock:
            held = [w for w, h in self._holds.items() if session in (None, h.owner)]
        return _ordered(held)

    def _take(self, session: Session) -> list[str]:
        with self.lock:
            mine = [w for w, h in self._holds.items() if h.owner is session]
            for w in mine:
                del self._holds[w]
        return _ordered(mine)

    # -- the end of a session ----------------------------------------------------------
    def session_ended(self, session: Session, reason: str) -> None:
        """``session`` is over (``reason`` as the server gives it). Within one scan
        boundary: release its forces; if it held the pause, stepping or iocheck (or
        forces, unless release_forces_on_disconnect), end them and halt the controller,
        outputs off, until ``ack``. On the daemon's orderly stop, forces only."""
        why = f"console {session.name} ended ({reason})"

        def react() -> tuple[list[str], bool]:
            plant = self.controller.plant  # here: an online change may have replaced it
            held = self._take(session)
            forces = [w[len("force "):] for w in held if w.startswith("force ")]
            for name in forces:
                if plant.is_forced(name):
                    plant.unforce(name)
            if (not held or reason == SERVER_STOPPING
                    or (self.release_on_disconnect and len(forces) == len(held))):
                return held, False
            self._halt(f"{why} while it held: {', '.join(held)}; {ACK_RESTARTS}",
                       iocheck="iocheck" in held)
            return held, True
        with self.lock:
            self._notices.pop(session, None)
            if session in self._ending:
                return
            self._ending.add(session)
        try:
            held, halted = self.controller.call(react)
        except TimeoutError:
            if session not in self._end_failed:  # once: it is tried again at every poll
                self._end_failed.add(session)
                log.error("%s while it held %s, and the scan did not answer: tried again "
                          "at the next poll of any session", why,
                          ", ".join(self.holdings(session)) or "nothing")
            return
        finally:
            with self.lock:
                self._ending.discard(session)
        self._end_failed.discard(session)
        if halted:
            log.error("%s while it held: %s: forces released, every output off, charts "
                      "stopped until ack", why, ", ".join(held))
        elif held:
            log.log(logging.INFO if reason == SERVER_STOPPING else logging.WARNING,
                    "%s while it held: %s: its forces released", why, ", ".join(held))

    def _halt(self, reason: str, iocheck: bool) -> None:
        """Scan thread: end the pause and stepping (whoever held them) and, if asked,
        iocheck, and hold every output off until ``ack``, at this one boundary."""
        plant = self.controller.plant
        plant.step(0)
        plant.resume()
        self.let_go("pause", "cycle")
        if iocheck:
            plant.set_iocheck(False)
        self.controller.require_ack(reason)

    # -- time limits (called by every session's poll) -----------------------------------
    def tick(self, session: Session) -> list[str]:
        """Apply the time limits of pause and forces (warning the owner warn_before
        ahead, then ending them), finish the end of sessions the scan did not answer in
        time, and return the notices for ``session``."""
        lim = self.limits
        now = self.clock()
        due: list[tuple[str, Hold]] = []
        orphans: set[Session] = set()
        warnings: list[tuple[Session, str]] = []
        with self.lock:
            for what, h in self._holds.items():
                if h.owner.closed:
                    orphans.add(h.owner)
                    continue
                limit = (lim.max_pause_s if what == "pause" else
                         lim.max_force_s if what.startswith("force ") else None)
                if limit is None or h.expiring:
                    continue
                if now - h.since >= limit:
                    h.expiring = True
                    due.append((what, h))
                elif now - h.since >= limit - lim.warn_before_s and not h.warned:
                    h.warned = True
                    warnings.append((h.owner, self._warning(what, limit)))
                    self._notify(h.owner, warnings[-1][1])
        for owner, text in warnings:
            log.warning("console %s: %s", owner.name, text)
        for owner in orphans:  # their end found the scan busy: try again
            self.session_ended(owner, owner.close_reason)
        for what, h in due:
            self._expire(what, h)
        with self.lock:
            return self._notices.pop(session, [])

    def _notify(self, session: Session, text: str) -> None:
        """Under ``lock``: a line for ``session``'s next poll."""
        self._notices.setdefault(session, []).append(text)

    def _warning(self, what: str, limit: float) -> str:
        lim = self.limits
        if what == "pause":
            return (f"warning: the pause ends in {lim.warn_before_s:.0f} s (max_pause "
                    f"{limit:.0f} s): the controller then halts until 'ack'; 'pause' "
                    "again keeps it")
        return (f"warning: {what} is released in {lim.warn_before_s:.0f} s (max_force "
                f"{limit:.0f} s); force it again to keep it")

    def _expire(self, what: str, h: Hold) -> None:
        """A pause or a force reached its maximum time: end it at a scan boundary."""
        lim = self.limits

        def end() -> str | None:
            plant = self.controller.plant  # here: an online change may have replaced it
            with self.lock:
                if self._holds.get(what) is not h:
                    return None  # released or taken again meanwhile
                del self._holds[what]
            if what == "pause":
                self._halt(f"the pause of console {h.owner.name} lasted its maximum "
                           f"{lim.max_pause_s:.0f} s (max_pause); {ACK_RESTARTS}",
                           iocheck=False)
                return (f"pause ended after {lim.max_pause_s:.0f} s (max_pause): every "
                        "output off, 'ack' restarts the charts")
            name = what[len("force "):]
            if plant.is_forced(name):
                plant.unforce(name)
            return f"{what} released after {lim.max_force_s:.0f} s (max_force)"
        try:
            text = self.controller.call(end)
        except TimeoutError:
            h.expiring = False  # tried again at the next poll
            log.error("console %s: the end of its %s is due, but the scan did not answer",
                      h.owner.name, what)
            return
        if text is not None:
            log.warning("console %s: %s", h.owner.name, text)
            with self.lock:
                self._notify(h.owner, text)


def _ordered(held: list[str]) -> list[str]:
    """Holds as they are reported: iocheck, pause, cycle, then forces in their order."""
    first = [w for w in HOLD_ORDER if w in held]
    return first + [w for w in held if w not in HOLD_ORDER]
