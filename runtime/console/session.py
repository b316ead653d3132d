"""The console protocol (console.md): one command per line, replies ending in ok/error.

Sessions are transport-free: a transport (serial port, Unix socket, TCP on 127.0.0.1)
feeds raw bytes to ``Session.feed`` and writes back the lines it returns, and calls
``Session.poll`` a few times a second for streamed lines (watch, trace).

The scan is never disturbed: every read and write of the plant goes through
``Controller.call``, which runs a short function in the scan thread at a scan boundary, so
a reply is one consistent snapshot. Streams register a listener that copies the process
image (a few list copies) after each cycle; the diffing and formatting happen here, in the
session's own thread.
"""

from __future__ import annotations

import json
import logging
import re
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

from runtime.console.pin import check_pin
from runtime.engine.commands import CommandRefused
from runtime.engine.names import Catalogue, CommandError, Image, Signal, parse_value, printable
from runtime.engine.plant import BindingError, Plant
from runtime.errors import suggest
from runtime.language import ast as A
from runtime.language.parser import format_time, parse_time

log = logging.getLogger(__name__)
R = TypeVar("R")

#: longest accepted line, bytes (console.md)
MAX_LINE = 1024
#: wrong PINs before the console locks, and for how long, seconds (console.md)
MAX_PIN_TRIES = 3
LOCKOUT_S = 60.0
#: a half-typed line left this long (s) is dropped: a cable pulled in mid-line must not
#: leave its fragment in front of the next person's command
PARTIAL_LINE_TIMEOUT_S = 60.0
#: cycles a stream keeps between two polls of its session; older ones are dropped (and
#: counted) when the line cannot carry them
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

READ_ONLY = ("help", "status", "stats", "get", "watch", "trace", "why", "json", "unlock",
             "lock")
CHANGING = ("set", "force", "unforce", "pause", "resume", "cycle", "init", "reset",
            "iocheck", "ack")
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
    "force": "force NAME VALUE : hold a value until unforced *",
    "unforce": "unforce NAME|all *",
    "pause": "stop the evolution of every chart; I/O keeps being scanned *",
    "resume": "restart the evolution *",
    "cycle": "cycle [N] : while paused, run exactly N scans and report what changed *",
    "init": "init INSTANCE : pulse SFCInit for one scan *",
    "reset": "reset INSTANCE : pulse SFCReset for one scan *",
    "iocheck": "iocheck on|off : bench wiring check: charts stopped, outputs off, set "
               "DRIVER.POINT drives one output *",
    "ack": "acknowledge a fault, the end of iocheck, or SFCError *",
    "unlock": "unlock PIN : allow the commands marked *",
    "lock": "forbid them again; releases every force",
    "json": "json on|off : replies as one JSON object per line",
}

_TERMINATOR = re.compile(rb"[\r\n\x03]")
_TIME_LITERAL = re.compile(r"\b(?:\d+(?:d|h|ms|m|s|us|ns))+\b")


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


def _logical(raw: Any, inverted: bool) -> int:
    """The value a chart input bound to a raw point sees: 0 or 1."""
    return int((raw != 0) != inverted)


def _round_times(text: str) -> str:
    """Time literals in an engine message rounded to ms (``1s234ms567us`` -> ``1s235ms``)."""
    def one(m: re.Match[str]) -> str:
        ns = parse_time(m.group(0))
        return m.group(0) if ns is None else format_time(round(ns / 1e6) * 1_000_000)
    return _TIME_LITERAL.sub(one, text)


def _clock_text(t: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t))


def _uptime_text(s: float) -> str:
    return f"{s:.1f} s" if s < 60 else format_time(int(s) * 1_000_000_000)


# -- the service: shared by every session -----------------------------------------------
class ConsoleService:
    """State shared by every session: the controller, its names, the PIN and its
    lock-out, and who forced what."""

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

    def session(self, name: str, trusted: bool = False) -> Session:
        return Session(self, name, trusted)


@dataclass
class _Stream:
    """A running watch or trace: what it shows and where it stands."""

    kind: str  # "watch" | "trace"
    names: list[Signal]
    every_s: float | None = None
    last: dict[str, Any] | None = None
    last_scan: int | None = None
    next_due: float = 0.0
    images: deque[Image] = field(default_factory=lambda: deque(maxlen=STREAM_SCANS))


class Session:
    """One console connection: line framing, permissions, replies and streams."""

    def __init__(self, service: ConsoleService, name: str, trusted: bool) -> None:
        self.service = service
        self.ctl = service.controller
        self.cat = service.catalogue
        self.name = name
        self.trusted = trusted
        self.unlocked = False
        self.json = False
        self.stream: _Stream | None = None
        self._buf = b""
        self._discarding = False
        self._skip_lf = False
        self._last_rx = 0.0
        self._listening = False

    # -- framing ---------------------------------------------------------------------
    def feed(self, data: bytes) -> list[str]:
        """Bytes from the line -> reply lines (each without its line terminator).

        A line ends at CR, LF or CRLF. Ctrl-C drops the half-typed line and stops a
        stream. A line longer than MAX_LINE bytes is dropped whole (an error reply when
        its end arrives)."""
        if not data:
            return []
        out: list[str] = []
        now = self.service.clock()
        if (self._buf or self._discarding) and now - self._last_rx > PARTIAL_LINE_TIMEOUT_S:
            log.info("console %s: half-typed line dropped after %.0f s", self.name,
                     now - self._last_rx)
            self._buf, self._discarding = b"", False
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
                self._buf, self._discarding = b"", False
                self._stop_stream()
                continue
            if ch == 0x0D:  # CR: a following LF belongs to it, even in the next chunk
                if pos < len(data):
                    if data[pos] == 0x0A:
                        pos += 1
                else:
                    self._skip_lf = True
            out += self._line()
        return out

    def _append(self, chunk: bytes) -> None:
        if self._discarding or not chunk:
            return
        if len(self._buf) + len(chunk) > MAX_LINE:
            self._buf, self._discarding = b"", True
        else:
            self._buf += chunk

    def _line(self) -> list[str]:
        raw, self._buf = self._buf, b""
        if self._discarding:
            self._discarding = False
            self._stop_stream()
            return self._reply_error(f"line longer than {MAX_LINE} bytes: ignored")
        return self.handle(raw)

    def handle(self, raw: bytes) -> list[str]:
        """One line (without terminator) -> reply lines."""
        self._stop_stream()
        if len(raw) > MAX_LINE:
            return self._reply_error(f"line longer than {MAX_LINE} bytes: ignored")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            return self._reply_error("line is not valid UTF-8: ignored")
        line = _edit(text)
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
        if cmd in CHANGING and not self.may_change():
            if self.service.pin_hash is None:
                return self._reply_error("changing commands are disabled on this console: "
                                         "no pin_hash in the plant file and the console is "
                                         "not trusted")
            return self._reply_error("locked: 'unlock PIN' first")
        try:
            result = getattr(self, f"cmd_{cmd}")(args)
        except (CommandError, CommandRefused, BindingError) as exc:
            return self._reply_error(str(exc))
        except TimeoutError:
            return self._reply_error("the scan did not answer in time")
        except Exception as exc:  # noqa: BLE001 - a bug must not end the session
            log.exception("console %s: '%s' failed", self.name, printable(line, 80))
            return self._reply_error(f"internal error: {type(exc).__name__}: {exc}")
        lines, data = result if isinstance(result, tuple) else (result, {})
        return self._reply_ok(lines, data)

    def may_change(self) -> bool:
        return self.trusted or self.unlocked

    # -- replies ---------------------------------------------------------------------
    def _reply_ok(self, lines: list[str], data: dict[str, Any]) -> list[str]:
        if self.json:
            return [json.dumps({"ok": True, **data, "text": lines}, ensure_ascii=False)]
        return [*lines, "ok"]

    def _reply_error(self, reason: str) -> list[str]:
        if self.json:
            return [json.dumps({"ok": False, "error": reason}, ensure_ascii=False)]
        return [f"error {reason}"]

    # -- streams -----------------------------------------------------------------------
    def _start_stream(self, stream: _Stream) -> None:
        self.stream = stream
        self.ctl.call(lambda: self._first_image(stream))
        if not self._listening:
            self.ctl.add_listener(self._on_scan)
            self._listening = True

    def _first_image(self, stream: _Stream) -> None:
        """Scan thread: the values when the stream starts, and the cycle count then."""
        stream.images.append(self.cat.capture(-1))
        stream.last_scan = int(self.ctl.status()["scans"])

    def _stop_stream(self) -> None:
        self.stream = None
        if self._listening:
            self._listening = False
            self.ctl.remove_listener(self._on_scan)

    def _on_scan(self, scan: int) -> None:
        """Scan thread, after each cycle: copy the image, nothing more."""
        stream = self.stream
        if stream is not None:
            stream.images.append(self.cat.capture(scan))

    def poll(self) -> list[str]:
        """Streamed lines due now (watch, trace); call it a few times a second."""
        stream = self.stream
        if stream is None or not stream.images:
            return []
        images: list[Image] = []
        while stream.images:
            images.append(stream.images.popleft())
        out = []
        if stream.last is None:  # the snapshot taken when the stream started
            first = images.pop(0)
            stream.last = {n.text: n.read(first) for n in stream.names}
            if stream.kind == "watch":
                out.append(self._stream_line("watch", stream.last, -1, 0))
            if stream.every_s is not None:
                stream.next_due = self.service.clock() + stream.every_s
        if stream.every_s is not None:
            now = self.service.clock()
            if not images or now < stream.next_due:
                stream.images.extendleft(images[-1:])  # the newest waits for its time
                return out
            stream.next_due = now + stream.every_s
            values = {n.text: n.read(images[-1]) for n in stream.names}
            stream.last_scan = images[-1].scan
            return [*out, self._stream_line("watch", values, images[-1].scan, 0)]
        # the first image kept is compared with the last one shown: no change is lost,
        # only the cycles in between are not shown one by one
        for img in images[-STREAM_LINES_PER_POLL:]:
            skipped = (max(0, img.scan - stream.last_scan - 1) if stream.last_scan is not None
                       else 0)
            stream.last_scan = img.scan
            values = {n.text: n.read(img) for n in stream.names}
            last = stream.last
            if stream.kind == "trace":
                changed = {k: v for k, v in values.items() if last.get(k) != v}
                if changed:
                    out.append(self._stream_line("trace", changed, img.scan, skipped))
            elif values != last:
                out.append(self._stream_line("watch", values, img.scan, skipped))
            stream.last = values
        return out

    def _stream_line(self, kind: str, values: dict[str, Any], scan: int,
                     skipped: int) -> str:
        names = self.cat.names
        if self.json:
            obj: dict[str, Any] = {kind: {k: names[k].plain(v) for k, v in values.items()}}
            logical = {sig: _logical(v, inv) for k, v in values.items()
                       for sig, inv in names[k].feeds}
            if logical and kind == "watch":
                obj["logical"] = logical
            if scan >= 0:
                obj["scan"] = scan
            if skipped:
                obj["skipped"] = skipped
            return json.dumps(obj, ensure_ascii=False)
        parts = []
        for k, v in values.items():
            part = f"{k}={names[k].show(v)}"
            if kind == "watch" and names[k].feeds:
                part += " (" + ", ".join(f"{sig}={_logical(v, inv)}" + (" inverted" if inv
                                                                          else "")
                                         for sig, inv in names[k].feeds) + ")"
            parts.append(part)
        head = kind + (f" {scan}" if scan >= 0 else "")
        if skipped:
            head += f" ({skipped} scans not shown: the line is too slow)"
        return head + ": " + "  ".join(parts)

    def close(self) -> None:
        """The connection ended: stop streams; release this session's forces if the plant
        says ``release_forces_on_disconnect: true``."""
        self._stop_stream()
        svc = self.service
        with svc.lock:
            mine = [n for n, s in svc.force_owner.items() if s is self]
            for n in mine:
                del svc.force_owner[n]
        if not (svc.release_on_disconnect and mine):
            return
        plant = self.ctl.plant

        def release() -> None:
            for n in mine:
                if plant.is_forced(n):
                    plant.unforce(n)
        try:
            self.ctl.call(release)
        except TimeoutError:
            log.error("console %s closed: its forces could not be released (the scan did "
                      "not answer)", self.name)
            return
        log.warning("console %s closed: released its forces %s", self.name, ", ".join(mine))

    # -- read-only commands ----------------------------------------------------------
    def cmd_help(self, args: list[str]) -> Any:
        if args:
            key = args[0].lower()
            if key not in HELP:
                raise CommandError(f"no command '{printable(args[0])}'{suggest(key, HELP)}")
            return [f"{key:8} {HELP[key]}"], {"commands": {key: HELP[key]}}
        lines = [f"{k:8} {v}" for k, v in HELP.items()]
        lines.append("* needs 'unlock PIN' (or a trusted console); names: inst.var, "
                     "inst.step.X, inst.step.T, inst.SFCPause, driver.point")
        return lines, {"commands": HELP}

    def cmd_json(self, args: list[str]) -> Any:
        if args not in (["on"], ["off"]):
            raise CommandError("usage: json on|off")
        self.json = args[0] == "on"
        return []

    def cmd_status(self, args: list[str]) -> Any:
        plant, cat = self.ctl.plant, self.cat

        def read() -> dict[str, Any]:
            forced = {k: cat.names[k].plain(v) if k in plant.forced else v
                      for k, v in plant.forced_values().items()}
            return {**self.ctl.status(),
                    "steps": {n: i.active_steps() for n, i in plant.instances.items()},
                    "forced": forced,
                    "errors": {n: i.get("SFCErrorStep") for n, i in plant.instances.items()
                               if i.get("SFCError")}}
        try:
            data = self.ctl.call(read)
        except TimeoutError:  # say what can be said without the scan thread
            data = {**self.ctl.status(), "steps": {}, "forced": {}, "errors": {},
                    "note": "the scan thread did not answer"}
        data["faults"] = data.get("faults", [])[-STATUS_FAULTS:]
        state = data["state"] + (f" ({data['fault']})" if data.get("fault") else "")
        lines = [f"state {state}",
                 f"cycle time {data['cycle_ms']:g} ms, scans {data['scans']}, uptime "
                 f"{_uptime_text(data['uptime_s'])}"]
        if "note" in data:
            lines.append(data["note"])
        lines += [f"{n}: {' '.join(s) or '(no active step)'}" for n, s in data["steps"].items()]
        lines += [f"SFCError {n}: step {s}" for n, s in data["errors"].items()]
        lines += [f"forced {k}={v}" for k, v in data["forced"].items()]
        lines += [f"fault at {_clock_text(f['time'])}: {f['reason']}" for f in data["faults"]]
        return lines, data

    def cmd_stats(self, args: list[str]) -> Any:
        s = self.ctl.stats()  # ScanStats sorts its window here, never in the scan thread
        cols = ("last", "min", "mean", "p50", "p99", "max")
        lines = [f"cycle time {s['cycle_us'] / 1000:g} ms: {s['cycles']} cycles, "
                 f"{s['overruns']} overruns, {s['skipped']} deadlines skipped",
                 f"{'(us)':10}" + "".join(f"{c:>9}" for c in cols)]
        for key, label in (("scan_us", "scan"), ("lateness_us", "lateness")):
            lines.append(f"{label:10}" + "".join(f"{s[key][c]:>9.1f}" for c in cols))
        lines.append(f"gc {s['gc_runs']} runs in the idle time, {s['gc_ms']} ms in all")
        for name, d in s.get("drivers", {}).items():
            reason = f": {d['reason']}" if d.get("reason") else ""
            lines.append(f"driver {name}: {d['health']} (on_fault {d['on_fault']}){reason}")
        return lines, {"stats": s}

    def cmd_get(self, args: list[str]) -> Any:
        if not args:
            raise CommandError("usage: get NAME...")
        names = self.cat.expand(args)
        plant, cat = self.ctl.plant, self.cat

        def read() -> tuple[dict[str, Any], dict[str, Any]]:
            img = cat.live()
            values = {n.text: n.read(img) for n in names}
            forced = {k: v for k, v in plant.forced_values().items() if k in values}
            return values, forced
        values, forced = self.ctl.call(read)
        lines, shown = [], {}
        for n in names:
            v = values[n.text]
            if n.text in forced and n.role == "point in":
                # a forced input masks the driver during the cycle only: show both
                note = f" (forced; the driver reads {n.show(v)})"
                v = forced[n.text]
            else:
                note = " (forced)" if n.text in forced else ""
            shown[n.text] = n.plain(v)
            text = f"{n.text}={n.show(v)}{note}"
            if n.feeds:
                text += "  " + ", ".join(f"{sig}={_logical(v, inv)}" + (" inverted" if inv
                                                                          else "")
                                         for sig, inv in n.feeds)
            if n.binding and len(names) > 1:
                text += f"  {n.binding}"
            lines.append(text)
        return lines, {"values": shown, "forced": sorted(forced),
                       "roles": {n.text: n.role for n in names}}

    def cmd_watch(self, args: list[str]) -> Any:
        every = None
        if len(args) >= 2 and args[-2] == "every":
            try:
                every = max(int(args[-1]), MIN_EVERY_MS) / 1000
            except ValueError:
                raise CommandError(f"bad value '{printable(args[-1])}' after 'every': "
                                   "expected a number of ms") from None
            args = args[:-2]
        names = self.cat.expand(args) if args else self.cat.physical_inputs()
        if not names:
            raise CommandError("nothing to watch: this plant has no physical input")
        self._start_stream(_Stream("watch", names, every))
        return [f"watching {len(names)} value(s) "
                + (f"every {every * 1000:g} ms" if every else "on every change")
                + " until the next line"], {"watch": [n.text for n in names]}

    def cmd_trace(self, args: list[str]) -> Any:
        if args not in (["on"], ["off"]):
            raise CommandError("usage: trace on|off")
        if args[0] == "off":
            return []
        self._start_stream(_Stream("trace", self.cat.traced))
        return ["tracing every scan's changes until the next line"], {}

    def cmd_why(self, args: list[str]) -> Any:
        plant = self.ctl.plant
        if len(args) != 1 or args[0] not in plant.instances:
            given = f" '{printable(args[0])}'" if args else ""
            raise CommandError(f"usage: why INSTANCE; no instance{given} (one of "
                               f"{' '.join(plant.instances)})")
        name = args[0]
        whys = self.ctl.call(lambda: plant.explain(name))
        lines, data = [], []
        for sw in whys:
            lines.append(f"{sw.step} active for {_round_times(format_time(sw.time_ns))}")
            for tw in sw.transitions:
                state = ("fires" if tw.condition and not tw.blocked else
                         "blocked" if tw.condition else "false")
                lines.append(f"  [{state}] {tw.text}")
                for b in tw.blocked:
                    lines.append(f"      blocked by: {_round_times(b)}")
                for term in tw.terms:
                    lines.append(f"      {'  ' * term.depth}{term.text} = {term.value}")
            data.append({"step": sw.step, "time_ms": round(sw.time_ns / 1e6),
                         "transitions": [
                             {"text": t.text, "condition": t.condition,
                              "blocked": [_round_times(b) for b in t.blocked],
                              "terms": [{"text": x.text, "depth": x.depth, "value": x.value}
                                        for x in t.terms]} for t in sw.transitions]})
        if not whys:
            lines.append("no active step")
        return lines, {"instance": args[0], "why": data}

    def cmd_unlock(self, args: list[str]) -> Any:
        svc = self.service
        if svc.pin_hash is None:
            raise CommandError("no pin_hash in the plant file: nothing to unlock"
                               + (" (this console is trusted)" if self.trusted else ""))
        if len(args) != 1:
            raise CommandError("usage: unlock PIN")
        with svc.lock:
            left = svc.locked_until - svc.clock()
            if left > 0:
                raise CommandError(f"console locked for {left:.0f} s after "
                                   f"{MAX_PIN_TRIES} wrong PINs")
            if not check_pin(args[0], svc.pin_hash):
                svc.wrong_pins += 1
                if svc.wrong_pins >= MAX_PIN_TRIES:
                    svc.wrong_pins = 0
                    svc.locked_until = svc.clock() + LOCKOUT_S
                    log.warning("console %s: %d wrong PINs, console locked for %.0f s",
                                self.name, MAX_PIN_TRIES, LOCKOUT_S)
                    raise CommandError(f"wrong PIN; console locked for {LOCKOUT_S:.0f} s")
                log.warning("console %s: wrong PIN (%d of %d)", self.name, svc.wrong_pins,
                            MAX_PIN_TRIES)
                left_tries = MAX_PIN_TRIES - svc.wrong_pins
                raise CommandError(f"wrong PIN ({left_tries} "
                                   f"{'try' if left_tries == 1 else 'tries'} left)")
            svc.wrong_pins = 0
        self.unlocked = True
        log.info("console %s unlocked", self.name)
        return ["unlocked"]

    def cmd_lock(self, args: list[str]) -> Any:
        if not self.may_change():
            return ["already locked"]
        self.unlocked = False
        released = self._unforce_all()
        return ["locked" + (f"; released {', '.join(released)}" if released else "")
                + ("; this console is trusted: changing commands stay allowed"
                   if self.trusted else "")], {"released": released}

    # -- changing commands ------------------------------------------------------------
    def _state(self) -> str:
        return str(self.ctl.status()["state"])

    def _two(self, args: list[str], usage: str) -> tuple[Signal, Any]:
        if len(args) != 2:
            raise CommandError(f"usage: {usage}")
        name = self.cat.resolve(args[0])
        return name, parse_value(name, args[1])

    def cmd_set(self, args: list[str]) -> Any:
        name, value = self._two(args, "set NAME VALUE")
        plant = self.ctl.plant
        if name.binding.startswith("<-"):
            raise CommandError(f"{name.text} is copied from {name.binding[3:]} before every "
                               f"scan: set that point, or force {name.text}")
        writer = self.cat.written_by.get(name.text)

        def write() -> None:
            state = self._state()
            if writer is not None and state in ("running", "stepping"):
                raise CommandError(f"{name.text} is written by {writer} every scan: force "
                                   "it, or pause or 'iocheck on' first")
            if name.role == "point out" and state in ("fault", "halted"):
                raise CommandError(f"the controller is {state}: outputs are held off until "
                                   "'ack'")
            plant.set(name.text, value)
        self.ctl.call(write)
        return [f"{name.text} set to {name.show(value)}"]

    def cmd_force(self, args: list[str]) -> Any:
        name, value = self._two(args, "force NAME VALUE")
        if name.role in ("step", "step time", "driver health") or name.type is A.Type.STRING:
            raise CommandError(f"{name.text} cannot be forced (a {name.role}); force "
                               "inputs, outputs and variables")
        plant = self.ctl.plant

        def force() -> None:
            plant.force(name.text, value)
            if name.role not in ("point in", "point out"):
                plant.set(name.text, value)  # visible at once, even while paused
        self.ctl.call(force)
        with self.service.lock:
            self.service.force_owner[name.text] = self
        return [f"{name.text} forced to {name.show(value)}"]

    def cmd_unforce(self, args: list[str]) -> Any:
        if len(args) != 1:
            raise CommandError("usage: unforce NAME|all")
        if args[0] == "all":
            released = self._unforce_all()
            return [f"released {', '.join(released)}" if released else "nothing was forced"
                    ], {"released": released}
        name = self.cat.resolve(args[0])
        plant = self.ctl.plant
        self.ctl.call(lambda: plant.unforce(name.text))
        with self.service.lock:
            self.service.force_owner.pop(name.text, None)
        return [f"{name.text} released"], {"released": [name.text]}

    def _unforce_all(self) -> list[str]:
        plant = self.ctl.plant

        def release() -> list[str]:
            names = plant.forced_names()
            plant.unforce(None)
            return names
        released = self.ctl.call(release)
        with self.service.lock:
            self.service.force_owner.clear()
        if released:
            log.warning("console %s: every force released (%s)", self.name,
                        ", ".join(released))
        return released

    def cmd_pause(self, args: list[str]) -> Any:
        plant = self.ctl.plant

        def do() -> str:
            state = self._state()
            if state == "iocheck":
                raise CommandError("iocheck on: the charts are stopped already")
            return "already paused" if plant.pause() else "paused"
        return [self.ctl.call(do) + ": charts hold, I/O still scanned; 'cycle N' steps, "
                "'resume' goes on"]

    def cmd_resume(self, args: list[str]) -> Any:
        plant = self.ctl.plant

        def do() -> str:
            return "resumed" if plant.resume() else "not paused"
        return [self.ctl.call(do)]

    def cmd_cycle(self, args: list[str]) -> Any:
        if len(args) > 1:
            raise CommandError("usage: cycle [N]")
        try:
            n = int(args[0]) if args else 1
        except ValueError:
            raise CommandError(f"bad value '{printable(args[0])}': expected a number of "
                               "scans") from None
        if not 1 <= n <= MAX_CYCLE:
            raise CommandError(f"bad value {n}: cycle N runs 1 to {MAX_CYCLE} scans")
        plant, cat = self.ctl.plant, self.cat
        images: list[Image] = []
        done = threading.Event()

        def on_scan(scan: int) -> None:  # scan thread
            images.append(cat.capture(scan))
            if not plant.stepping:
                done.set()

        def start() -> Image:
            state = self._state()
            if state != "paused":
                raise CommandError(f"cycle runs while paused; the controller is {state}"
                                   + (": pause first" if state == "running" else ""))
            plant.step(n)
            self.ctl.add_listener(on_scan)
            return cat.capture(-1)
        before = self.ctl.call(start)
        try:
            if not done.wait(2.0 + 2 * n * plant.cycle_ns / 1e9):
                self.ctl.call(lambda: plant.step(0))
                raise CommandError(f"the scans did not run (controller {self._state()}); "
                                   "stepping cancelled")
        finally:
            self.ctl.remove_listener(on_scan)
        return self._cycle_report(n, before, images[:n])

    def _cycle_report(self, n: int, before: Image, images: list[Image]) -> Any:
        names = self.cat.traced
        steps = [x for x in names if x.role == "step"]
        prev = {x.text: x.read(before) for x in names}
        first = prev
        lines = [f"ran {n} scan(s)" + (f" ({images[0].scan}..{images[-1].scan})"
                                       if images else "")]
        per_scan = []
        for img in images:
            cur = {x.text: x.read(img) for x in names}
            changed = {k: v for k, v in cur.items() if prev[k] != v}
            per_scan.append({"scan": img.scan, "changed": {
                k: self.cat.names[k].plain(v) for k, v in changed.items()}})
            if changed and len(lines) < CYCLE_DETAIL_LINES:
                lines.append(f"scan {img.scan}: " + self._changes(changed, prev, steps))
            elif changed and len(lines) == CYCLE_DETAIL_LINES:
                lines.append("... (more scans changed; the total follows)")
            prev = cur
        total = {k: v for k, v in prev.items() if first[k] != v}
        if sum(1 for p in per_scan if p["changed"]) > 1 and total:
            lines.append("in all: " + self._changes(total, first, steps))
        if not total and not any(p["changed"] for p in per_scan):
            lines.append("nothing changed")
        return lines, {"scans": n, "per_scan": per_scan,
                       "changed": {k: self.cat.names[k].plain(v) for k, v in total.items()}}

    def _changes(self, changed: dict[str, Any], before: dict[str, Any],
                 steps: list[Signal]) -> str:
        """``tester1 gsParado -> gsAbrir; tester1.oAbrir 0 -> 1, ...``"""
        parts = []
        for inst in self.cat.groups:
            mine = [x.text for x in steps if x.text.startswith(inst + ".")]
            if not any(k in changed for k in mine):
                continue
            was = [k.split(".")[1] for k in mine if before[k]]
            now = [k.split(".")[1] for k in mine if changed.get(k, before[k])]
            parts.append(f"{inst} {','.join(was) or '-'} -> {','.join(now) or '-'}")
        names = self.cat.names
        others = [f"{k} {names[k].show(before[k])} -> {names[k].show(v)}"
                  for k, v in changed.items() if names[k].role != "step"]
        return "; ".join(parts + ([", ".join(others)] if others else []))

    def _pulse(self, args: list[str], flag: str) -> Any:
        plant = self.ctl.plant
        if len(args) != 1 or args[0] not in plant.instances:
            given = f"; no instance '{printable(args[0])}'" if args else ""
            raise CommandError(f"usage: {flag[3:].lower()} INSTANCE{given} (one of "
                               f"{' '.join(plant.instances)})")

        def do() -> str:
            state = self._state()
            if state == "iocheck":
                raise CommandError("iocheck on: the charts are stopped")
            plant.pulse(args[0], flag)
            return state
        state = self.ctl.call(do)
        when = " at the next scan" if state != "paused" else " at the next scan ('cycle' " \
                                                              "or 'resume': paused now)"
        return [f"{flag} pulsed on {args[0]}{when}"]

    def cmd_init(self, args: list[str]) -> Any:
        return self._pulse(args, "SFCInit")

    def cmd_reset(self, args: list[str]) -> Any:
        return self._pulse(args, "SFCReset")

    def cmd_iocheck(self, args: list[str]) -> Any:
        if args not in (["on"], ["off"]):
            raise CommandError("usage: iocheck on|off")
        plant, ctl = self.ctl.plant, self.ctl
        if args[0] == "on":
            def enter() -> list[str]:
                state = self._state()
                if state == "fault":
                    raise CommandError("the controller is in fault: 'ack' it first")
                if state == "iocheck":
                    return []
                released = plant.forced_names()
                plant.unforce(None)  # outputs all off means forced ones too
                if state == "halted":
                    # back to the bench after a previous iocheck: the charts were waiting
                    # for ack; acknowledge and re-enter in the same boundary, so no scan runs
                    was = plant.pause()
                    ctl.ack()
                    if not was:
                        plant.resume()
                plant.step(0)
                plant.set_iocheck(True)
                return released
            released = self.ctl.call(enter)
            with self.service.lock:
                self.service.force_owner.clear()
            lines = ["iocheck: charts stopped, every output off. 'set DRIVER.POINT 1' drives "
                     "one output, 'watch' shows physical inputs with their logical value, "
                     "'iocheck off' ends"]
            if released:
                lines.append(f"released forces: {', '.join(released)}")
            return lines, {"released": released}

        def leave() -> None:
            if not plant.iocheck:
                raise CommandError("not in iocheck")
            plant.set_iocheck(False)
            # the same boundary: no scan may run the charts between the two
            ctl.require_ack("iocheck ended: 'ack' restarts the charts from their initial "
                            "situation")
        self.ctl.call(leave)
        return ["iocheck off: every output off; 'ack' restarts the charts from their "
                "initial situation"]

    def cmd_ack(self, args: list[str]) -> Any:
        return [self.ctl.ack()]


def _edit(text: str) -> str:
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
