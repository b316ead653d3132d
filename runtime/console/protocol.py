"""The console's line protocol (console.md): its limits, its commands and their help text,
and the line framer that turns the bytes of a line into lines.

Nothing here knows the plant: a transport feeds bytes to a ``LineFramer`` and gets back
complete lines (CR, LF or CRLF), Ctrl-C and too-long lines as events; ``apply_editing_keys``
applies the backspace and Ctrl-U typed on a raw terminal.
"""

from __future__ import annotations

import enum
import logging
import re
from collections.abc import Callable
from typing import Any

log = logging.getLogger(__name__)

#: longest accepted line, bytes (console.md)
MAX_LINE = 1024
#: wrong PINs in a row from one peer before its ``unlock`` is locked out (console.md)
MAX_PIN_TRIES = 3
#: the first lock-out of a peer, seconds; each further one doubles, up to LOCKOUT_MAX_S.
#: A correct PIN, or LOCKOUT_MAX_S without a lock-out, starts again from the first.
LOCKOUT_MIN_S = 30.0
LOCKOUT_MAX_S = 900.0
#: a half-typed line left this long (s) is dropped: a cable pulled in mid-line must not
#: leave its fragment in front of the next person's command
PARTIAL_LINE_TIMEOUT_S = 60.0
#: cycles a stream may hold, a backstop: the scan thread keeps only the newest
#: STREAM_LINES_PER_POLL (streams.Stream.drop_oldest); older ones are dropped and counted
STREAM_SCANS = 2000
#: stream lines sent per poll at most: on a slow line the older cycles are skipped (and
#: counted) rather than queued, so a line typed to stop the stream is read soon
STREAM_LINES_PER_POLL = 20
#: ``cycle N`` limits, and the cycles reported one by one
MAX_CYCLE = 10_000
CYCLE_DETAIL_LINES = 40
#: faults shown by ``status``
STATUS_FAULTS = 5
#: shortest ``watch ... every MS``, ms
MIN_EVERY_MS = 10

#: commands any session may run
READ_ONLY = ("help", "status", "stats", "get", "watch", "trace", "why", "json", "unlock",
             "lock", "web")
#: commands that change the plant: they need ``unlock PIN`` or a trusted console
CHANGING = ("set", "force", "unforce", "pause", "resume", "cycle", "init", "reset",
            "iocheck", "ack", "reload")
HELP = {
    "help": "help [COMMAND] : lists commands",
    "status": "state, cycle time, scan count, uptime, active steps, forced values, faults",
    "stats": "cycle time and lateness (last min mean p50 p99 max, us), overruns, drivers",
    "get": "get NAME... : current values (inst.var, inst.step.X, inst.step.T, "
           "driver.point; an instance or driver name alone: all its signals)",
    "watch": "watch [NAME...] [every MS] : stream values until the next line (no NAME: "
             "every physical input with its logical value)",
    "trace": "trace on|off : one line per scan of the values that changed",
    "why": "why INSTANCE : each active step's transitions, their terms, what blocks them",
    "set": "set NAME VALUE : write once at the next scan boundary *",
    "force": "force NAME VALUE : hold a value until unforced, at most max_force (forcing "
             "again restarts it) *",
    "unforce": "unforce NAME|all *",
    "pause": "stop the evolution of every chart; I/O keeps being scanned; after max_pause "
             "(pausing again restarts it) the controller halts until ack *",
    "resume": "restart the evolution *",
    "cycle": "cycle [N] : while paused, run exactly N scans and report what changed *",
    "init": "init INSTANCE : pulse SFCInit for one scan *",
    "reset": "reset INSTANCE : pulse SFCReset for one scan *",
    "iocheck": "iocheck on|off : bench wiring check: charts stopped, outputs off, set "
               "DRIVER.POINT drives one output *",
    "ack": "acknowledge a fault, a halt (end of iocheck, of a session holding a pause or "
           "forces), or SFCError; releases every force *",
    "reload": "reload [--force] [--restart INSTANCE]... [--back] : load the changed plant "
              "and charts into the running controller between two scans (online change; "
              "--back: the program before the last change) *",
    "unlock": "unlock PIN : allow the commands marked *",
    "lock": "forbid them again; releases every force",
    "json": "json on|off : replies as one JSON object per line",
    "web": "web USER ADDRESS : (softplc web only: root or the controller's own user on a "
           "Unix socket, a plant with web:) this session acts for USER's page from ADDRESS",
}

#: what a command returns: its reply lines, and with them the data of its JSON reply
Reply = list[str] | tuple[list[str], dict[str, Any]]


class Pending:
    """A command whose reply comes later (``cycle N``: once its scans have run), returned
    by the command instead of its Reply. The thread serving the session goes on serving
    the other sessions meanwhile; this session takes no other line until the reply has
    been given: its transport asks ``ready()`` now and then, then ``finish()`` for the
    reply. ``interrupt()`` (Ctrl-C on the line) asks it to stop early; ``abandon()``
    (the session ended) lets go of what it watches without a reply."""

    #: the command's name, for the error a line sent meanwhile would get
    command = ""

    def ready(self) -> bool:
        """Whether ``finish()`` may be called now (done, interrupted or out of time)."""
        raise NotImplementedError

    def interrupt(self) -> None:
        """Stop early: ``ready()`` is true from now on."""
        raise NotImplementedError

    def finish(self) -> Reply:
        """The reply (raises CommandError for an error reply). Called once."""
        raise NotImplementedError

    def abandon(self) -> None:
        """The session ended: no reply will be asked for."""
        raise NotImplementedError

_TERMINATOR = re.compile(rb"[\r\n\x03]")


class LineEvent(enum.Enum):
    """What the framer reports besides complete lines."""

    #: Ctrl-C: the half-typed line was dropped (a stream stops)
    INTERRUPT = "interrupt"
    #: a line longer than MAX_LINE bytes ended; its bytes were dropped
    OVERLONG = "overlong"


class LineFramer:
    """Bytes from the line -> complete lines, in order, without their terminators.

    A line ends at CR, LF or CRLF (a CR's LF may come in the next chunk). Ctrl-C drops
    the half-typed line. A line longer than MAX_LINE bytes is dropped whole and reported
    when its end arrives. A half-typed line older than PARTIAL_LINE_TIMEOUT_S is dropped
    when the next bytes come.
    """

    def __init__(self, name: str, clock: Callable[[], float]) -> None:
        #: the session's name, for the log
        self.name = name
        #: monotonic seconds
        self.clock = clock
        #: the half-typed line
        self.pending = b""
        self._discarding = False
        self._skip_lf = False
        self._last_rx = 0.0

    def feed(self, data: bytes) -> list[bytes | LineEvent]:
        """Bytes from the line -> the lines and events they complete."""
        if not data:
            return []
        out: list[bytes | LineEvent] = []
        now = self.clock()
        if (self.pending or self._discarding) and now - self._last_rx > PARTIAL_LINE_TIMEOUT_S:
            log.info("console %s: half-typed line dropped after %.0f s", self.name,
                     now - self._last_rx)
            self.pending, self._discarding = b"", False
        self._last_rx = now
        pos = 0
        if self._skip_lf and data[:1] == b"\n":
            pos = 1
        self._skip_lf = False
        while pos < len(data):
            m = _TERMINATOR.search(data, pos)
            if m is None:
                self._append(data[pos:])
                break
            self._append(data[pos:m.start()])
            ch = data[m.start()]
            pos = m.end()
            if ch == 0x03:  # Ctrl-C
                self.pending, self._discarding = b"", False
                out.append(LineEvent.INTERRUPT)
                continue
            if ch == 0x0D:  # CR: a following LF belongs to it, even in the next chunk
                if pos < len(data):
                    if data[pos] == 0x0A:
                        pos += 1
                else:
                    self._skip_lf = True
            out.append(self._end_line())
        return out

    def _append(self, chunk: bytes) -> None:
        if self._discarding or not chunk:
            return
        if len(self.pending) + len(chunk) > MAX_LINE:
            self.pending, self._discarding = b"", True
        else:
            self.pending += chunk

    def _end_line(self) -> bytes | LineEvent:
        raw, self.pending = self.pending, b""
        if self._discarding:
            self._discarding = False
            return LineEvent.OVERLONG
        return raw


def apply_editing_keys(text: str) -> str:
    """Apply a terminal's editing keys typed on a raw line: backspace/DEL erase the
    character before, Ctrl-U the whole line."""
    if not any(c in text for c in "\b\x7f\x15"):
        return text
    out: list[str] = []
    for c in text:
        if c in "\b\x7f":
            if out:
                out.pop()
        elif c == "\x15":
            out.clear()
        else:
            out.append(c)
    return "".join(out)
