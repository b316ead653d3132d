"""The console protocol (console.md): one command per line, replies ending in ok/error.

Sessions are transport-free: a transport (serial port, Unix socket, TCP on 127.0.0.1)
feeds raw bytes to ``Session.feed`` and writes back the lines it returns, and calls
``Session.poll`` a few times a second for streamed lines (watch, trace). Every read and
write of the plant goes through ``Controller.call``, which runs it in the scan thread at a
scan boundary: the console never touches the plant during a scan.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Protocol, TypeVar

from runtime.daemon import CommandRefused
from runtime.parser import format_time
from runtime.pin import check_pin
from runtime.plant import BindingError, Plant

log = logging.getLogger(__name__)
R = TypeVar("R")

#: longest accepted line, bytes (console.md)
MAX_LINE = 1024
#: wrong PINs before the console locks, and for how long (seconds)
MAX_PIN_TRIES = 3
LOCKOUT_S = 60.0
#: how often a watch without ``every`` looks for changes, seconds
WATCH_POLL_S = 0.05

READ_ONLY = ("help", "status", "stats", "get", "watch", "trace", "why", "json", "unlock", "lock")
CHANGING = ("set", "force", "unforce", "pause", "resume", "cycle", "init", "reset", "iocheck",
            "ack")
HELP = {
    "help": "lists commands",
    "status": "state, cycle, scan count, uptime, active steps, forced values",
    "stats": "cycle time and lateness: last min mean p99 max, overruns; driver health",
    "get": "get NAME... : current values (instance.var, instance.step.X/.T, driver.point)",
    "watch": "watch NAME... [every MS] : stream values until a new line arrives",
    "trace": "trace on|off : stream one line per scan of changed values",
    "why": "why INSTANCE : why each active step's transitions fire or not",
    "set": "set NAME VALUE : write once at the next scan boundary",
    "force": "force NAME VALUE : hold a value until unforced",
    "unforce": "unforce NAME|all",
    "pause": "stop evolution of every chart (I/O keeps being scanned)",
    "resume": "restart evolution",
    "cycle": "cycle [N] : while paused, run exactly N scans and report what changed",
    "init": "init INSTANCE : pulse SFCInit for one scan",
    "reset": "reset INSTANCE : pulse SFCReset for one scan",
    "iocheck": "iocheck on|off : commissioning, charts stopped and outputs off",
    "ack": "acknowledge a fault or SFCError after its cause is gone",
    "unlock": "unlock PIN : allow changing commands",
    "lock": "lock : forbid changing commands again (releases forces)",
    "json": "json on|off : replies as one JSON object per line",
}


class Controller(Protocol):
    """What the console needs from the running daemon."""

    plant: Plant

    def call(self, fn: Callable[[], R], timeout: float = 2.0) -> R:
        """Run ``fn`` in the scan thread at the next scan boundary; return its result."""

    def status(self) -> dict[str, Any]:
        """state, fault, scans, uptime_s, cycle_ms."""

    def stats(self) -> dict[str, Any]:
        """Cycle statistics (ns) and per-driver health."""

    def ack(self) -> str:
        """Acknowledge a fault (restart the charts) or SFCError; returns what was done."""

    def require_ack(self, reason: str) -> None:
        """Hold outputs off and charts stopped until ``ack`` (after iocheck)."""

    def add_listener(self, fn: Callable[[int], None]) -> None:
        """Call ``fn(scan_number)`` in the scan thread after each cycle."""

    def remove_listener(self, fn: Callable[[int], None]) -> None: ...


class CommandError(Exception):
    """A command that cannot be carried out; the message is the reply's reason."""


def snapshot(plant: Plant) -> dict[str, Any]:
    """Every readable value of the plant, for diffs (call it at a scan boundary)."""
    out: dict[str, Any] = {}
    for name, inst in plant.instances.items():
        for key in inst.names():
            out[f"{name}.{key}"] = _plain(inst.get(key))
    for dname, d in plant.drivers.items():
        for p in (*d.inputs, *d.outputs):
            out[f"{dname}.{p}"] = plant.get(f"{dname}.{p}")
        out[f"{dname}.ok"] = d.ok
    return {k: _plain(v) for k, v in out.items()}


def _plain(v: Any) -> Any:
    return int(v) if isinstance(v, bool) else v


def _fmt(name: str, v: Any) -> str:
    if name.endswith(".T") and isinstance(v, int):
        return format_time(v)
    return str(v)


class ConsoleService:
    """State shared by every session: the controller, the PIN and its lock-out."""

    def __init__(self, controller: Controller, pin_hash: str | None = None,
                 release_forces_on_disconnect: bool = False,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.controller = controller
        self.pin_hash = pin_hash
        self.release_on_disconnect = release_forces_on_disconnect
        self.clock = clock
        self.wrong_pins = 0
        self.locked_until = 0.0
        self.lock = threading.Lock()

    def session(self, name: str, trusted: bool = False) -> Session:
        return Session(self, name, trusted)


class Session:
    """One console connection: line framing, permissions, replies and streams."""

    def __init__(self, service: ConsoleService, name: str, trusted: bool) -> None:
        self.service = service
        self.ctl = service.controller
        self.name = name
        self.trusted = trusted
        self.unlocked = False
        self.json = False
        self._buf = b""
        self._discarding = False
        self.forced: set[str] = set()
        self.watch: tuple[list[str], float | None] | None = None
        self._watch_last: dict[str, Any] = {}
        self._watch_next = 0.0
        self.tracing = False
        self._trace_q: deque[int] = deque(maxlen=1000)
        self._trace_last: dict[str, Any] | None = None

    # -- framing ---------------------------------------------------------------------
    def feed(self, data: bytes) -> list[str]:
        """Bytes from the line -> reply lines (each without line terminator)."""
        out: list[str] = []
        self._buf += data
        while True:
            cut = min((i for i in (self._buf.find(b"\r"), self._buf.find(b"\n")) if i >= 0),
                      default=-1)
            if cut < 0:
                if len(self._buf) > MAX_LINE:
                    self._buf = b""
                    self._discarding = True
                return out
            raw, self._buf = self._buf[:cut], self._buf[cut + 1:]
            if self._discarding:
                self._discarding = False
                out += self._reply_error(f"line longer than {MAX_LINE} bytes")
                continue
            if not raw and self._buf[:1] == b"\n" and data:  # CRLF
                pass
            out += self.handle(raw)

    def handle(self, raw: bytes) -> list[str]:
        """One line (without terminator) -> reply lines."""
        self._stop_streams()
        if len(raw) > MAX_LINE:
            return self._reply_error(f"line longer than {MAX_LINE} bytes")
        try:
            line = raw.decode("utf-8")
        except UnicodeDecodeError:
            return self._reply_error("line is not valid UTF-8")
        words = line.split()
        if not words:
            return []
        cmd, args = words[0].lower(), words[1:]
        if cmd not in READ_ONLY and cmd not in CHANGING:
            return self._reply_error(f"unknown command '{words[0][:40]}' (try help)")
        if cmd in CHANGING and not self.may_change():
            if self.service.pin_hash is None and not self.trusted:
                return self._reply_error("changing commands are disabled: no PIN is set in "
                                         "the plant file and this console is not trusted")
            return self._reply_error("locked: unlock PIN first")
        try:
            result = getattr(self, f"cmd_{cmd}")(args)
        except (CommandError, CommandRefused) as exc:
            return self._reply_error(str(exc))
        except BindingError as exc:
            return self._reply_error(str(exc))
        except TimeoutError:
            return self._reply_error("the scan did not answer in time")
        lines, data = result if isinstance(result, tuple) else (result, {})
        return self._reply_ok(lines, data)

    def may_change(self) -> bool:
        return self.trusted or self.unlocked

    # -- replies ---------------------------------------------------------------------
    def _reply_ok(self, lines: list[str], data: dict[str, Any]) -> list[str]:
        if self.json:
            return [json.dumps({"ok": True, **data}, ensure_ascii=False)]
        return [*lines, "ok"]

    def _reply_error(self, reason: str) -> list[str]:
        if self.json:
            return [json.dumps({"ok": False, "error": reason}, ensure_ascii=False)]
        return [f"error {reason}"]

    # -- streams -----------------------------------------------------------------------
    def _stop_streams(self) -> None:
        self.watch = None
        if self.tracing:
            self.tracing = False
            self.ctl.remove_listener(self._on_scan)

    def _on_scan(self, scan: int) -> None:  # scan thread: keep it tiny
        self._trace_q.append(scan)

    def poll(self) -> list[str]:
        """Streamed lines due now (watch, trace); call a few times a second."""
        out: list[str] = []
        now = self.service.clock()
        if self.watch is not None and now >= self._watch_next:
            names, every = self.watch
            values = self.ctl.call(lambda: {n: _plain(self.ctl.plant.get(n)) for n in names})
            self._watch_next = now + (every if every is not None else WATCH_POLL_S)
            if every is not None or values != self._watch_last:
                out.append(self._stream_line("watch", values))
            self._watch_last = values
        if self.tracing and self._trace_q:
            scans = list(self._trace_q)
            self._trace_q.clear()
            snap = self.ctl.call(lambda: snapshot(self.ctl.plant))
            last = self._trace_last or {}
            changed = {k: v for k, v in snap.items() if last.get(k) != v}
            self._trace_last = snap
            if changed:
                out.append(self._stream_line("trace", changed, scan=scans[-1]))
        return out

    def _stream_line(self, kind: str, values: dict[str, Any], scan: int | None = None) -> str:
        if self.json:
            obj: dict[str, Any] = {kind: values}
            if scan is not None:
                obj["scan"] = scan
            return json.dumps(obj, ensure_ascii=False)
        head = f"{kind}" + (f" {scan}" if scan is not None else "")
        return head + " " + " ".join(f"{k}={_fmt(k, v)}" for k, v in values.items())

    def close(self) -> None:
        """The connection ended: stop streams; release this session's forces if asked."""
        self._stop_streams()
        if self.service.release_on_disconnect and self.forced:
            names = list(self.forced)
            self.ctl.call(lambda: [self._unforce_quiet(n) for n in names])
            log.info("console %s closed: released forces %s", self.name, ", ".join(names))
            self.forced.clear()

    def _unforce_quiet(self, name: str) -> None:
        try:
            self.ctl.plant.unforce(name)
        except BindingError:
            pass

    # -- read-only commands ----------------------------------------------------------
    def cmd_help(self, args: list[str]) -> Any:
        lines = [f"{k:8} {v}" for k, v in HELP.items()]
        return lines, {"commands": HELP}

    def cmd_json(self, args: list[str]) -> Any:
        if args not in (["on"], ["off"]):
            raise CommandError("usage: json on|off")
        self.json = args[0] == "on"
        return []

    def cmd_status(self, args: list[str]) -> Any:
        st = self.ctl.status()
        plant = self.ctl.plant

        def read() -> dict[str, Any]:
            return {"steps": {n: i.active_steps() for n, i in plant.instances.items()},
                    "forced": {**{k: _plain(v[2]) for k, v in plant.forced.items()},
                               **{k: v[3] for k, v in plant.forced_points.items()}},
                    "errors": {n: i.get("SFCErrorStep") for n, i in plant.instances.items()
                               if i.get("SFCError")}}
        data = {**st, **self.ctl.call(read)}
        lines = [f"state {data['state']}" + (f" ({data['fault']})" if data.get("fault")
                                             else ""),
                 f"cycle {data['cycle_ms']} ms, scans {data['scans']}, "
                 f"uptime {data['uptime_s']:.1f} s"]
        lines += [f"{n}: {' '.join(s) or '-'}" for n, s in data["steps"].items()]
        lines += [f"SFCError {n}: {s}" for n, s in data["errors"].items()]
        lines += [f"forced {k}={v}" for k, v in data["forced"].items()]
        return lines, data

    def cmd_stats(self, args: list[str]) -> Any:
        s = self.ctl.stats()
        lines = [f"{k} {v}" for k, v in s.items() if not isinstance(v, dict)]
        for name, d in s.get("drivers", {}).items():
            lines.append(f"driver {name} {d}")
        return lines, {"stats": s}

    def cmd_get(self, args: list[str]) -> Any:
        if not args:
            raise CommandError("usage: get NAME...")
        plant = self.ctl.plant

        def read() -> tuple[dict[str, Any], set[str]]:
            return ({n: _plain(plant.get(n)) for n in args},
                    set(plant.forced) | set(plant.forced_points))
        values, forced = self.ctl.call(read)
        lines = [f"{n}={_fmt(n, v)}" + (" (forced)" if n in forced else "")
                 for n, v in values.items()]
        return lines, {"values": values, "forced": sorted(forced & set(values))}

    def cmd_watch(self, args: list[str]) -> Any:
        every = None
        if len(args) >= 2 and args[-2] == "every":
            try:
                every = max(int(args[-1]), 10) / 1000
            except ValueError:
                raise CommandError(f"expected a number of ms after 'every', found "
                                   f"'{args[-1]}'") from None
            args = args[:-2]
        if not args:
            raise CommandError("usage: watch NAME... [every MS]")
        self.ctl.call(lambda: [self.ctl.plant.get(n) for n in args])  # validate names
        self.watch = (args, every)
        self._watch_last = {}
        self._watch_next = 0.0
        return ["watching until the next line"]

    def cmd_trace(self, args: list[str]) -> Any:
        if args not in (["on"], ["off"]):
            raise CommandError("usage: trace on|off")
        if args[0] == "on":
            self._trace_last = None
            self.tracing = True
            self.ctl.add_listener(self._on_scan)
            return ["tracing until the next line"]
        return []

    def cmd_why(self, args: list[str]) -> Any:
        if len(args) != 1 or args[0] not in self.ctl.plant.instances:
            raise CommandError(f"usage: why INSTANCE (one of "
                               f"{' '.join(self.ctl.plant.instances)})")
        inst = self.ctl.plant.instances[args[0]]
        plant = self.ctl.plant

        def explain() -> Any:
            inst.last_up = plant.last_up
            return inst.explain()
        whys = self.ctl.call(explain)
        lines, data = [], []
        for sw in whys:
            lines.append(f"{sw.step} active for {format_time(sw.time_ns)}")
            for tw in sw.transitions:
                state = "fires" if tw.condition and not tw.blocked else "blocked"
                lines.append(f"  [{state}] {tw.text}")
                for b in tw.blocked:
                    lines.append(f"    blocked by: {b}")
                for term in tw.terms:
                    lines.append(f"    {'  ' * term.depth}{term.text} = {term.value}")
            data.append({"step": sw.step, "time_ms": sw.time_ns // 1_000_000, "transitions": [
                {"text": t.text, "condition": t.condition, "blocked": t.blocked,
                 "terms": [{"text": x.text, "depth": x.depth, "value": x.value}
                           for x in t.terms]} for t in sw.transitions]})
        if not whys:
            lines.append("no active step")
        return lines, {"why": data}

    def cmd_unlock(self, args: list[str]) -> Any:
        svc = self.service
        if svc.pin_hash is None:
            raise CommandError("no PIN is set in the plant file")
        with svc.lock:
            left = svc.locked_until - svc.clock()
            if left > 0:
                raise CommandError(f"console locked for {left:.0f} s after wrong PINs")
            if len(args) != 1 or not check_pin(args[0], svc.pin_hash):
                svc.wrong_pins += 1
                if svc.wrong_pins >= MAX_PIN_TRIES:
                    svc.wrong_pins = 0
                    svc.locked_until = svc.clock() + LOCKOUT_S
                    log.warning("console %s: %d wrong PINs, locked for %.0f s", self.name,
                                MAX_PIN_TRIES, LOCKOUT_S)
                    raise CommandError(f"wrong PIN; console locked for {LOCKOUT_S:.0f} s")
                raise CommandError("wrong PIN")
            svc.wrong_pins = 0
        self.unlocked = True
        return ["unlocked"]

    def cmd_lock(self, args: list[str]) -> Any:
        self.unlocked = False
        plant = self.ctl.plant
        self.ctl.call(lambda: plant.unforce(None))
        self.forced.clear()
        return ["locked; every force released"]

    # -- changing commands ------------------------------------------------------------
    def _value(self, args: list[str], usage: str) -> tuple[str, str]:
        if len(args) != 2:
            raise CommandError(f"usage: {usage}")
        return args[0], args[1]

    def cmd_set(self, args: list[str]) -> Any:
        name, value = self._value(args, "set NAME VALUE")
        plant = self.ctl.plant
        try:
            self.ctl.call(lambda: plant.set(name, value))
        except ValueError as exc:
            raise CommandError(f"bad value for {name}: {exc}") from None
        return []

    def cmd_force(self, args: list[str]) -> Any:
        name, value = self._value(args, "force NAME VALUE")
        plant = self.ctl.plant
        try:
            self.ctl.call(lambda: plant.force(name, value))
        except ValueError as exc:
            if isinstance(exc, BindingError):
                raise
            raise CommandError(f"bad value for {name}: {exc}") from None
        self.forced.add(name)
        return [f"{name} forced to {value}"]

    def cmd_unforce(self, args: list[str]) -> Any:
        if len(args) != 1:
            raise CommandError("usage: unforce NAME|all")
        plant = self.ctl.plant
        name = None if args[0] == "all" else args[0]
        self.ctl.call(lambda: plant.unforce(name))
        if name is None:
            self.forced.clear()
        else:
            self.forced.discard(name)
        return []

    def cmd_pause(self, args: list[str]) -> Any:
        plant = self.ctl.plant

        def do() -> None:
            plant.hold = True
            plant.steps_left = 0
        self.ctl.call(do)
        return ["paused: charts hold, I/O still scanned"]

    def cmd_resume(self, args: list[str]) -> Any:
        plant = self.ctl.plant

        def do() -> None:
            plant.hold = False
        self.ctl.call(do)
        return []

    def cmd_cycle(self, args: list[str]) -> Any:
        plant = self.ctl.plant
        try:
            n = int(args[0]) if args else 1
        except ValueError:
            raise CommandError(f"expected a number of scans, found '{args[0]}'") from None
        if n < 1 or n > 10_000:
            raise CommandError("cycle N: N from 1 to 10000")
        if not plant.hold:
            raise CommandError("cycle works while paused: pause first")
        before = self.ctl.call(lambda: snapshot(plant))
        self.ctl.call(lambda: plant.step(n))
        deadline = time.monotonic() + 2.0 + 2 * n * plant.cycle_ns / 1e9
        while self.ctl.call(lambda: plant.steps_left) > 0:
            if time.monotonic() > deadline:
                raise CommandError("the scans did not run in time")
            time.sleep(plant.cycle_ns / 1e9)
        after = self.ctl.call(lambda: snapshot(plant))
        changed = {k: v for k, v in after.items() if before.get(k) != v and not k.endswith(".T")}
        lines = [f"ran {n} scan(s)"] + [f"{k}: {_fmt(k, before.get(k))} -> {_fmt(k, v)}"
                                       for k, v in changed.items()]
        return lines, {"scans": n, "changed": changed}

    def _pulse(self, args: list[str], flag: str) -> Any:
        plant = self.ctl.plant
        if len(args) != 1 or args[0] not in plant.instances:
            raise CommandError(f"usage: {flag[3:].lower()} INSTANCE (one of "
                               f"{' '.join(plant.instances)})")
        self.ctl.call(lambda: plant.pulse(args[0], flag))
        return [f"{flag} pulsed on {args[0]}"]

    def cmd_init(self, args: list[str]) -> Any:
        return self._pulse(args, "SFCInit")

    def cmd_reset(self, args: list[str]) -> Any:
        return self._pulse(args, "SFCReset")

    def cmd_iocheck(self, args: list[str]) -> Any:
        if args not in (["on"], ["off"]):
            raise CommandError("usage: iocheck on|off")
        plant = self.ctl.plant
        on = args[0] == "on"
        self.ctl.call(lambda: plant.set_iocheck(on))
        if on:
            return ["iocheck: charts stopped, every output off; set DRIVER.POINT 0|1 drives "
                    "one output, watch shows raw inputs"]
        self.ctl.require_ack("iocheck ended: acknowledge to restart the charts")
        return ["iocheck off: every output off; ack restarts the charts from their initial "
                "situation"]

    def cmd_ack(self, args: list[str]) -> Any:
        return [self.ctl.ack()]
