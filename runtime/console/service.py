"""What every console session shares: the Controller it talks to (a protocol the daemon
fulfils), and the ConsoleService holding the plant's names, the PIN and its lock-out, and
who forced what.

The scan is never disturbed: every read and write of the plant goes through
``Controller.call``, which runs a short function in the scan thread at a scan boundary, so
a reply is one consistent snapshot.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from runtime.console.pin import check_pin
from runtime.console.protocol import LOCKOUT_S, MAX_PIN_TRIES
from runtime.engine.names import Catalogue, CommandError
from runtime.engine.plant import Plant

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
        """state, fault, scans, uptime_s, cycle_ms, faults."""

    def stats(self) -> dict[str, Any]:
        """Cycle statistics (us) and per-driver health."""

    def ack(self) -> str:
        """Acknowledge a fault (restart the charts) or SFCError; returns what was done."""

    def require_ack(self, reason: str) -> None:
        """Hold outputs off and charts stopped until ``ack`` (after iocheck)."""

    def add_listener(self, fn: Callable[[int], None]) -> None:
        """Call ``fn(cycle_number)`` in the scan thread after each cycle."""

    def remove_listener(self, fn: Callable[[int], None]) -> None: ...


class ConsoleService:
    """State shared by every session: the controller, its names, the PIN and its
    lock-out, and who forced what. Sessions run in their own threads: ``lock`` guards the
    lock-out and the force owners."""

    def __init__(self, controller: Controller, pin_hash: str | None = None,
                 release_forces_on_disconnect: bool = False,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.controller = controller
        self.catalogue = Catalogue(controller.plant)
        self.pin_hash = pin_hash
        self.release_on_disconnect = release_forces_on_disconnect
        #: monotonic seconds; injectable so tests step the lock-out instead of sleeping
        self.clock = clock
        self.wrong_pins = 0
        self.locked_until = 0.0
        #: forced name -> the session that forced it last
        self.force_owner: dict[str, Session] = {}
        self.lock = threading.Lock()

    def session(self, name: str, trusted: bool = False, peer: str | None = None) -> Session:
        """A new session of this console (``name`` says where it is, for the log)."""
        from runtime.console.session import Session  # session.py imports this module
        return Session(self, name, trusted, peer)

    # -- the PIN ---------------------------------------------------------------------
    def try_pin(self, pin: str, who: str) -> None:
        """Check a PIN typed at session ``who``; raise CommandError if it is wrong or the
        console is locked out. MAX_PIN_TRIES wrong PINs in a row lock every session out
        for LOCKOUT_S seconds."""
        if self.pin_hash is None:
            raise CommandError("no pin_hash in the plant file: nothing to unlock")
        with self.lock:
            left = self.locked_until - self.clock()
            if left > 0:
                raise CommandError(f"console locked for {left:.0f} s after "
                                   f"{MAX_PIN_TRIES} wrong PINs")
            if not check_pin(pin, self.pin_hash):
                self.wrong_pins += 1
                if self.wrong_pins >= MAX_PIN_TRIES:
                    self.wrong_pins = 0
                    self.locked_until = self.clock() + LOCKOUT_S
                    log.warning("console %s: %d wrong PINs, console locked for %.0f s",
                                who, MAX_PIN_TRIES, LOCKOUT_S)
                    raise CommandError(f"wrong PIN; console locked for {LOCKOUT_S:.0f} s")
                log.warning("console %s: wrong PIN (%d of %d)", who, self.wrong_pins,
                            MAX_PIN_TRIES)
                left_tries = MAX_PIN_TRIES - self.wrong_pins
                raise CommandError(f"wrong PIN ({left_tries} "
                                   f"{'try' if left_tries == 1 else 'tries'} left)")
            self.wrong_pins = 0

    # -- who forced what ---------------------------------------------------------------
    def forced_by(self, name: str, session: Session) -> None:
        """``session`` forced ``name`` (it owns the force until released)."""
        with self.lock:
            self.force_owner[name] = session

    def released(self, name: str | None) -> None:
        """``name`` (None: every name) is no longer forced."""
        with self.lock:
            if name is None:
                self.force_owner.clear()
            else:
                self.force_owner.pop(name, None)

    def take_forces_of(self, session: Session) -> list[str]:
        """The names ``session`` forced last, forgotten here (the session is closing)."""
        with self.lock:
            mine = [n for n, s in self.force_owner.items() if s is session]
            for n in mine:
                del self.force_owner[n]
        return mine
