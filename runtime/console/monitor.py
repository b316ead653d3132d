"""``softplc monitor PORT|SOCKET``: a live terminal view of a running controller.

The laptop side of the console: it speaks the JSON mode of the console protocol
(console.md) over a Unix socket, a 127.0.0.1 TCP port or a serial line, refreshes a view
of the plant a few times a second (state, active steps per instance, inputs and outputs
with forced marks, cycle statistics, last faults) and has a prompt for console commands.

The controller may go away under it (restarted, rebooted, unplugged, or the console
closing an idle connection): the monitor says so, keeps the last view, tries again with
back-off (RETRY_MIN_S doubling to RETRY_MAX_S, ``client.py``), and says when the controller
it finds again is a new run of it (its start, from ``status``'s uptime, moved).

Layers, so all but the last are testable without a terminal: ``Link`` (bytes, ``links.py``),
``ConsoleClient`` (JSON requests and replies) and ``Connection`` (a client, opened again
after a loss) in ``client.py``, ``View`` (what the screen shows, as text lines,
``view.py``), ``Monitor`` (the screen's logic: refreshes, commands, streams, reconnection)
here; ``run_screen`` draws it with curses from the standard library, which is on every
Linux laptop and needs nothing more for a few lines of text and a prompt.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections.abc import Callable
from typing import Any

from runtime.console.client import Connection, ConsoleClient
from runtime.console.links import LinkKind, MonitorError, Target, console_of
from runtime.console.view import View, fold
from runtime.errors import SourceError

log = logging.getLogger(__name__)

#: view refresh period, seconds; slower on a serial line, where a refresh (~2.5 kB) takes
#: about 0.2 s at 115200 baud
REFRESH_S = 0.25
SERIAL_REFRESH_S = 1.0
#: the shortest refresh period, seconds: a refresh is three lines, and the console runs at
#: most 50 lines/s per session (30 here, the rest for what is typed)
MIN_REFRESH_S = 0.1


# -- the screen's logic ------------------------------------------------------------------
#: what typed alone on the prompt leaves the monitor
QUIT = ("q", "quit", "exit")


class Monitor:
    """What the screen does, without the screen: keeps the view fresh, runs what is typed,
    shows streams, and survives the loss of the controller (``Connection``)."""

    def __init__(self, target: Target, view: View, refresh_s: float = REFRESH_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.connection = Connection(target, clock)
        self.view = view
        self.refresh_s = refresh_s
        self.clock = clock
        #: a ``watch`` or ``trace on`` is streaming: no refresh until it stops
        self.streaming = False
        #: an ``unlock`` worked in this session (a new session is locked again)
        self.unlocked = False
        self._next_refresh = 0.0

    def connect(self) -> None:
        """The first connection (MonitorError when the controller cannot be reached)."""
        self.connection.connect()

    def tick(self) -> None:
        """One round: a try to connect again when due, else a refresh or the streams."""
        conn = self.connection
        client = conn.client
        if client is None:
            client = conn.retry()
            if client is None:
                self.view.offline = self._offline()
                return
            self.view.connected(conn.target.address)
            if self.unlocked:
                self.view.log.append("(a new session: locked again, type unlock PIN)")
                self.unlocked = False
            self._next_refresh = 0.0
        now = self.clock()
        try:
            if self.streaming:
                self.view.stream(client.poll_streams(0.0))
            elif now >= self._next_refresh:
                self._next_refresh = now + self.refresh_s
                self.view.refresh(client)
        except MonitorError as exc:
            self._lost(exc)

    def enter(self, line: str) -> bool:
        """A line typed at the prompt; False: leave."""
        cmd = line.strip()
        if cmd in QUIT:
            return False
        client = self.connection.client
        if client is None:
            if cmd:
                self.view.log += [f"> {cmd}", "(not connected: not sent)"]
            return True
        try:
            if self.streaming:
                self.streaming = False
                if not cmd:
                    client.send_line("")  # stops the stream; no reply
                    self.view.log.append("(stream stopped)")
                    return True
            if cmd:
                reply = self.view.command(client, cmd)
                words = cmd.split()
                ok = bool(reply.get("ok"))
                self.streaming = ok and (words[0] == "watch" or words[:2] == ["trace", "on"])
                if ok and words[0] in ("unlock", "lock"):
                    self.unlocked = words[0] == "unlock"
                self._next_refresh = 0.0
        except MonitorError as exc:
            self._lost(exc)
        return True

    def _lost(self, exc: MonitorError) -> None:
        if self.streaming:
            self.view.log.append("(stream ended)")
            self.streaming = False
        self.view.lost(str(exc))
        self.connection.lost(str(exc))
        self.view.offline = self._offline()

    def _offline(self) -> str:
        conn = self.connection
        wait = max(conn.next_try - self.clock(), 0.0)
        tried = f"try {conn.attempts}: {conn.reason}; " if conn.attempts else ""
        return f"{tried}trying again in {wait:.1f} s"

    def close(self) -> None:
        self.connection.close()


# -- the screen ------------------------------------------------------------------------------
def run_screen(mon: Monitor) -> int:
    """The live view and its prompt until ``q``/``quit`` (or Ctrl-C); ``q`` alone leaves
    at once while the controller is away."""
    import curses

    def main(scr: Any) -> int:
        curses.curs_set(1)
        scr.timeout(50)
        scr.keypad(True)
        line = ""
        while True:
            mon.tick()
            _draw(scr, mon.view, line, mon.streaming)
            try:
                ch = scr.get_wch()
            except curses.error:
                continue
            if ch == "\x03" or (ch in ("q", "Q") and not line
                                 and mon.connection.client is None):
                return 0
            if ch in ("\n", "\r", curses.KEY_ENTER):
                cmd, line = line, ""
                if not mon.enter(cmd):
                    return 0
            elif ch in (curses.KEY_BACKSPACE, "\b", "\x7f"):
                line = line[:-1]
            elif ch == "\x15":
                line = ""
            elif ch == curses.KEY_RESIZE:
                scr.clear()
            elif isinstance(ch, str) and ch.isprintable():
                line += ch

    try:
        return int(curses.wrapper(main))
    except KeyboardInterrupt:
        return 0
    except curses.error as exc:  # a terminal curses does not know (TERM), too small...
        raise MonitorError(f"the terminal cannot show the screen ({exc}): use --once") \
            from None


def _draw(scr: Any, view: View, line: str, streaming: bool) -> None:
    import curses

    h, w = scr.getmaxyx()
    scr.erase()
    top = view.lines(max(w - 1, 20))
    room_for_log = max(h - len(top) - 3, 0)
    rows = top[:max(h - 3, 0)]
    rows.append("-" * (w - 1) + "")
    if room_for_log:
        # the newest replies, each folded to the width: as many as fit
        log: list[str] = []
        for entry in reversed(view.log):
            log[:0] = fold(entry, max(w - 1, 20))
            if len(log) >= room_for_log:
                break
        rows += log[-room_for_log:]
    for y, text in enumerate(rows[:h - 1]):
        try:
            scr.addnstr(y, 0, text, w - 1)
        except curses.error:
            pass
    hint = "(streaming: Enter stops) " if streaming else ""
    prompt = f"{hint}> {line}"
    if len(prompt) > w - 1:  # a long line being typed: its end, where the cursor is
        prompt = prompt[len(prompt) - (w - 1):]
    try:
        scr.addnstr(h - 1, 0, prompt, w - 1)
        scr.move(h - 1, min(len(prompt), w - 1))
    except curses.error:
        pass
    scr.refresh()


# -- command line ------------------------------------------------------------------------
def cmd_monitor(args: argparse.Namespace) -> int:
    try:
        address = console_of(args.target)
    except SourceError as exc:  # the target's own text, or the plant file named
        said = exc.message if exc.loc.file == "SOCKET|PORT" else str(exc)
        sys.stderr.write(f"softplc monitor: error: {said}\n")
        return 2
    interval = args.interval
    if interval is not None and interval < MIN_REFRESH_S:
        sys.stderr.write(f"softplc monitor: error: --interval {interval:g} is under "
                         f"{MIN_REFRESH_S:g} s (the console runs at most 50 lines/s)\n")
        return 2
    if not args.once and not (sys.stdin.isatty() and sys.stdout.isatty()):
        sys.stderr.write("softplc monitor: error: not a terminal (a screen needs one): use "
                         "--once\n")
        return 2
    try:
        target = Target.parse(address, args.baudrate)
        view = View(target=address)
        if args.once:
            client = ConsoleClient(target.open())
            try:
                client.start()
                view.refresh(client)
            finally:
                client.close()
            sys.stdout.write("\n".join(view.lines(args.width)) + "\n")
            return 0 if not view.problem else 1
        if interval is None:
            interval = SERIAL_REFRESH_S if target.kind is LinkKind.SERIAL else REFRESH_S
        mon = Monitor(target, view, interval)
        mon.connect()
        try:
            return run_screen(mon)
        finally:
            mon.close()
    except MonitorError as exc:
        sys.stderr.write(f"softplc monitor: error: {exc}\n")
        return 1


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    m = sub.add_parser("monitor", help="live view of a running controller, with a command "
                                       "prompt",
                       description="Watch a running controller through its console: a Unix "
                                   "socket path, HOST:PORT (TCP), or a serial port. Type "
                                   "console commands at the prompt; 'q' leaves. If the "
                                   "controller goes away, the monitor waits for it and "
                                   "connects again.")
    m.add_argument("target", metavar="PLANT|SOCKET|PORT",
                   help="the plant file (its console), /run/softplc/NAME/console.sock, "
                        "127.0.0.1:5020 or /dev/ttyUSB0")
    m.add_argument("--baudrate", type=int, default=115200, help="serial speed (115200)")
    m.add_argument("--interval", type=float, metavar="S",
                   help=f"refresh period in seconds ({REFRESH_S}; {SERIAL_REFRESH_S} on a "
                        f"serial line; at least {MIN_REFRESH_S})")
    m.add_argument("--once", action="store_true",
                   help="print the view once as text and exit (scripts, dumb terminals)")
    m.add_argument("--width", type=int, default=100, help="line width for --once")
    m.set_defaults(func=cmd_monitor)
