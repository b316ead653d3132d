"""A console session (console.md): one connection's line framing -> dispatch -> permission
check -> reply, and its stream.

Sessions are transport-free: a transport (serial port, Unix socket, TCP on 127.0.0.1)
feeds raw bytes to ``Session.feed`` and writes back the lines it returns, and calls
``Session.poll`` a few times a second for streamed lines (watch, trace), the time limits
(service.tick) and the relock after an idle time, and ``Session.close(reason)`` when the
connection ends. A command whose reply comes later (``cycle N``) leaves ``pending`` set:
the transport hands the session no other line until ``pending.ready()``, then writes
``Session.finish()``. The commands themselves are in commands.py and changing.py, the
stream's lines in streams.py.

Activity is a command: a line that gets a reply (run, refused or unknown).
``last_command`` is its time; empty lines, spaces and Ctrl-C (what a client sends to look
alive) get no reply and do not count, neither for the relock after an idle time nor for
the transports' idle limits.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from typing import Any, TypeVar

from runtime.console.commands import COMMANDS
from runtime.console.protocol import (
    CHANGING,
    HELP,
    MAX_LINE,
    READ_ONLY,
    LineEvent,
    LineFramer,
    Pending,
    Reply,
    apply_editing_keys,
)
from runtime.console.service import ConsoleService
from runtime.console.streams import Stream
from runtime.engine.commands import CommandRefused
from runtime.engine.names import Catalogue, CommandError, printable
from runtime.engine.plant import BindingError, Plant
from runtime.errors import suggest

log = logging.getLogger(__name__)

R = TypeVar("R")


class Session:
    """One console connection: line framing, permissions, replies and streams.

    The commands change ``unlocked`` (unlock, lock) and ``json`` (json on|off), and start
    a stream with ``start_stream``; any line, Ctrl-C or the end of the connection stops it.
    A session is always created locked, and locks itself again after
    ``relock_after_idle`` without input.
    """

    def __init__(self, service: ConsoleService, name: str, trusted: bool,
                 peer: str | None = None) -> None:
        self.service = service
        self.ctl = service.controller
        #: where the session is (``serial:/dev/ttyS0``), for the log
        self.name = name
        #: who is at the other end (``serial:/dev/ttyS0``, ``uid:1000``, ``tcp``): wrong
        #: PINs lock out this peer only
        self.peer = peer if peer is not None else name
        #: a trusted console may change the plant without a PIN
        self.trusted = trusted
        self.unlocked = False
        #: the service's ``pin_generation`` when the session was unlocked
        self.unlocked_with = 0
        #: service clock seconds of the last command (a line that got a reply): the idle
        #: time counts from it, not from empty lines or Ctrl-C
        self.last_command = service.clock()
        #: the command whose reply comes later (``cycle N``), None when there is none
        self.pending: Pending | None = None
        #: set by ``close``: the session takes nothing more, and why it ended
        self.closed = False
        self.close_reason = ""
        #: replies as one JSON object per line
        self.json = False
        self.stream: Stream | None = None
        self._framer = LineFramer(name, service.clock)
        #: the plant the running command acts on: read when the command starts, checked
        #: again in the scan thread by ``call`` (an online change may replace it meanwhile)
        self.plant: Plant = self.ctl.plant

    def call(self, fn: Callable[[], R]) -> R:
        """Run ``fn`` in the scan thread between two cycles, on the plant the command read
        (``self.plant``): if an online change replaced it since the command started,
        nothing runs and the command fails ("try again"), so that no force, pause or
        iocheck lands on a plant that no longer runs."""
        plant, ctl = self.plant, self.ctl

        def guarded() -> R:
            if ctl.plant is not plant:
                raise CommandError("the program was reloaded meanwhile: nothing done; "
                                   "try again")
            return fn()
        return ctl.call(guarded)

    @property
    def cat(self) -> Catalogue:
        """The plant's names (a new catalogue after each reload)."""
        return self.service.catalogue

    @property
    def _buf(self) -> bytes:
        """The half-typed line (tests wait for it)."""
        return self._framer.pending

    # -- framing ---------------------------------------------------------------------
    def feed(self, data: bytes) -> list[str]:
        """Bytes from the line -> reply lines (each without its line terminator).

        A line ends at CR, LF or CRLF. Ctrl-C drops the half-typed line and stops a
        stream. A line longer than MAX_LINE bytes is dropped whole (an error reply when
        its end arrives)."""
        out: list[str] = []
        for item in self._framer.feed(data):
            if isinstance(item, bytes):
                out += self.handle(item)
            elif item is LineEvent.INTERRUPT:
                self._stop_stream()
            else:  # LineEvent.OVERLONG
                self._stop_stream()
                self.last_command = self.service.clock()
                out += self._reply_error(f"line longer than {MAX_LINE} bytes: ignored")
        return out

    def handle(self, raw: bytes) -> list[str]:
        """One line (without terminator) -> reply lines (none for an empty line, and none
        yet for a command left ``pending``)."""
        self._stop_stream()
        reply = self._handle(raw)
        if reply or self.pending is not None:
            self.last_command = self.service.clock()
        return reply

    def _handle(self, raw: bytes) -> list[str]:
        if self.pending is not None:  # the transports never do this: they wait for it
            return self._reply_error(f"'{self.pending.command}' is still running: its "
                                     "reply comes first (Ctrl-C stops it)")
        if len(raw) > MAX_LINE:
            return self._reply_error(f"line longer than {MAX_LINE} bytes: ignored")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            return self._reply_error("line is not valid UTF-8: ignored")
        line = apply_editing_keys(text)
        bad = next((c for c in line if not c.isprintable() and c != "\t"), None)
        if bad is not None:
            return self._reply_error(f"control character {bad!r} in the line (arrow or "
                                     "function key?): ignored")
        words = line.split()
        if not words:
            return []  # an empty line only stops a stream
        cmd, args = words[0].lower(), words[1:]
        if cmd not in READ_ONLY and cmd not in CHANGING:
            return self._reply_error(f"unknown command '{printable(words[0])}' (try help)"
                                     f"{suggest(cmd, HELP)}")
        if cmd in CHANGING and not self.may_change() and not (
                cmd == "reload" and self.service_account()):
            if self.service.pin_hash is None:
                return self._reply_error("changing commands are disabled on this console: "
                                         "no pin_hash in the plant file and the console is "
                                         "not trusted")
            return self._reply_error("locked: 'unlock PIN' first")
        self.plant = self.ctl.plant
        return self._reply(lambda: COMMANDS[cmd](self, args), line)

    def _reply(self, run: Callable[[], Reply | Pending], line: str) -> list[str]:
        """The reply lines of ``run()`` (a command, or the end of a pending one): its
        result, or its error; none when it left a command pending."""
        try:
            result = run()
        except (CommandError, CommandRefused, BindingError) as exc:
            # a refusal with reasons (reload) lists them before its error line
            return self._reply_error(str(exc), getattr(exc, "lines", []),
                                     getattr(exc, "data", {}))
        except TimeoutError:
            return self._reply_error("the scan did not answer in time")
        except Exception as exc:  # noqa: BLE001 - a bug must not end the session
            log.exception("console %s: '%s' failed", self.name, printable(line, 80))
            return self._reply_error(f"internal error: {type(exc).__name__}: {exc}")
        if isinstance(result, Pending):
            self.pending = result
            return []
        lines, data = result if isinstance(result, tuple) else (result, {})
        return self._reply_ok(lines, data)

    def finish(self) -> list[str]:
        """The reply of the pending command (once ``pending.ready()``)."""
        pending, self.pending = self.pending, None
        if pending is None:
            return []
        return self._reply(pending.finish, pending.command)

    def service_account(self) -> bool:
        """Whether the peer is root or the controller's own user on a Unix socket: they
        may ``reload`` without a PIN (systemd's ExecReload runs as the service's user;
        docs/online-change.md)."""
        return self.name.startswith("socket:") and self.peer in ("uid:0",
                                                                 f"uid:{os.getuid()}")

    def may_change(self) -> bool:
        """May this session run the changing commands (marked * in help)?"""
        return self.trusted or (self.unlocked
                                and self.unlocked_with == self.service.pin_generation)

    # -- replies ---------------------------------------------------------------------
    def _reply_ok(self, lines: list[str], data: dict[str, Any]) -> list[str]:
        if self.json:
            made = self.service.json_reply
            if made is not None and made[0] is data and made[1] is lines:
                return [made[2]]  # a shared reply (``stats``), encoded once
            text = json.dumps({"ok": True, **data, "text": lines}, ensure_ascii=False)
            self.service.json_reply = (data, lines, text)
            return [text]
        return [*lines, "ok"]

    def _reply_error(self, reason: str, lines: list[str] | None = None,
                     data: dict[str, Any] | None = None) -> list[str]:
        if self.json:
            return [json.dumps({"ok": False, **(data or {}), "error": reason},
                               ensure_ascii=False)]
        return [*(lines or []), f"error {reason}"]

    # -- streams -----------------------------------------------------------------------
    def start_stream(self, stream: Stream) -> None:
        """Show ``stream`` from now until the next line."""
        self._stop_stream()
        self.stream = stream
        self.ctl.call(lambda: stream.begin(self.ctl))
        self.service.tap.add(stream)

    def _stop_stream(self) -> None:
        stream, self.stream = self.stream, None
        if stream is not None:
            self.service.tap.remove(stream)
            stream.release()

    def poll(self, more: Callable[[], bool] | None = None) -> list[str]:
        """Lines due now: notices (time limits, relock) and streamed lines (watch,
        trace); call it a few times a second. ``more``: whether there is time left to
        compare a stream's next image (``Stream.poll``)."""
        notices = self.service.tick(self)
        idle = self.service.limits.relock_after_idle_s
        if self.unlocked and self.service.clock() - self.last_command >= idle:
            self.unlocked = False
            log.info("console %s locked after %.0f s idle", self.name, idle)
            notices.append(f"locked after {idle:.0f} s idle: 'unlock PIN' to change the "
                           "machine")
        out = [json.dumps({"notice": n}, ensure_ascii=False) if self.json else n
               for n in notices]
        stream = self.stream
        if stream is not None:
            out += stream.poll(self.service.clock, self.json, more)
            if stream.catalogue is not self.service.catalogue:  # the plant was reloaded
                self._stop_stream()
                out.append(json.dumps({"notice": "reloaded"}) if self.json else "reloaded")
        return out

    def close(self, reason: str = "connection closed") -> None:
        """The connection ended (``reason``: "peer disconnected", "hang-up", "idle
        timeout", "server stopping"...): stop streams; its forces are released and, if it
        held the pause, stepping, iocheck or forces, the controller halts until ``ack``
        (ConsoleService.session_ended). Idempotent."""
        if self.closed:
            return
        self.close_reason = reason
        self.closed = True
        self.unlocked = False
        self._stop_stream()
        if self.pending is not None:
            self.pending.abandon()
            self.pending = None
        self.service.session_ended(self, reason)
