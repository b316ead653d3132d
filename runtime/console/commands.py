"""The console's commands, and the table the session dispatches through (``COMMANDS``).

Each command is a plain function ``(session, args) -> Reply``: its reply lines, and the
data of its JSON reply; it raises CommandError with the reply's error text. A command
whose reply comes later (``cycle N``) returns a ``Pending`` instead. The read-only
commands are here; the ones that change the plant (marked * in help) are in changing.py.
Plant reads go through ``Controller.call``: one consistent snapshot at a scan boundary.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from drivers.durations import LITERAL_IN_TEXT, format_ns, parse_literal
from runtime.console import changing
from runtime.console.protocol import HELP, MIN_EVERY_MS, STATUS_FAULTS, Pending, Reply
from runtime.console.streams import Stream, feeds_text
from runtime.controller.alarms import alarm_lines
from runtime.engine.names import CommandError, not_applied_lines, printable, same
from runtime.errors import suggest
from runtime.language import ast as A
from runtime.language.flagtexts import sfcerror_cause
from runtime.language.iolist import Meaning

if TYPE_CHECKING:
    from runtime.console.session import Session

log = logging.getLogger(__name__)

#: a command: the session it runs in, the words after its name -> its reply
Command = Callable[["Session", list[str]], Reply | Pending]
#: the types whose values ``get`` follows with their unit (a time is shown as 1s500ms)
NUMBERS = (A.Type.INT, A.Type.REAL)


def round_times(text: str) -> str:
    """Time literals in an engine message rounded to ms (``1s234ms567us`` -> ``1s235ms``)."""
    def one(m: re.Match[str]) -> str:
        ns = parse_literal(m.group(0))
        return m.group(0) if ns is None else format_ns(round(ns / 1e6) * 1_000_000)
    return LITERAL_IN_TEXT.sub(one, text)


def _clock_text(t: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t))


def _uptime_text(s: float) -> str:
    return f"{s:.1f} s" if s < 60 else format_ns(int(s) * 1_000_000_000)


def cmd_help(session: Session, args: list[str]) -> Reply:
    if args:
        key = args[0].lower()
        if key not in HELP:
            raise CommandError(f"no command '{printable(args[0])}'{suggest(key, HELP)}")
        return [f"{key:8} {HELP[key]}"], {"commands": {key: HELP[key]}}
    lines = [f"{k:8} {v}" for k, v in HELP.items()]
    lines.append("* needs 'unlock PIN' (or a trusted console); names: inst.var, "
                 "inst.step.X, inst.step.T, inst.SFCPause, driver.point")
    return lines, {"commands": HELP}


def cmd_json(session: Session, args: list[str]) -> Reply:
    if args not in (["on"], ["off"]):
        raise CommandError("usage: json on|off")
    session.json = args[0] == "on"
    return []


def cmd_status(session: Session, args: list[str]) -> Reply:
    plant, cat = session.plant, session.cat

    def read() -> dict[str, Any]:
        forced = {k: cat.names[k].plain(v) if k in plant.forced else v
                  for k, v in plant.forced_values().items()}
        return {**session.ctl.status(),
                "steps": {n: i.active_steps() for n, i in plant.instances.items()},
                "forced": forced,
                "errors": {n: i.get("SFCErrorStep") for n, i in plant.instances.items()
                           if i.get("SFCError")},
                "not_applied": {s.text: {"chart": s.plain(chart), "applied": s.plain(applied),
                                         "point": s.point,
                                         "holds": cat.names[s.point].plain(holds)}
                                for s, chart, applied, holds in cat.not_applied(cat.live())}}
    try:
        data = session.call(read)
    except TimeoutError:  # say what can be said without the scan thread
        data = {**session.ctl.status(), "steps": {}, "forced": {}, "errors": {},
                "not_applied": {}, "note": "the scan thread did not answer"}
    data["faults"] = data.get("faults", [])[-STATUS_FAULTS:]
    # what the instances and their active steps are, for a view such as the monitor
    said = {n: cat.iolist.meaning(n).description
            for inst, steps in data["steps"].items() for n in (inst, *(
                f"{inst}.{s}" for s in steps))}
    data["descriptions"] = {n: d for n, d in said.items() if d}
    held = data.get("held", {})
    state = data["state"] + (f" ({data['fault']})" if data.get("fault") else "")
    if held and data["state"] == "running":  # running, yet some charts do not evolve
        state += " (" + "; ".join(f"{n} held by {', '.join(f)}" for n, f in held.items()) + ")"
    lines = [f"state {state}",
             f"cycle time {data['cycle_ms']:g} ms, scans {data['scans']}, uptime "
             f"{_uptime_text(data['uptime_s'])}"]
    if "note" in data:
        lines.append(data["note"])
    lines += [f"inhibit: {x}" for x in data.get("inhibits", [])
              if not x.startswith(f"{data['state']}: ")]  # the state line says that one
    lines += [f"{n}: {' '.join(s) or '(no active step)'}"
              + (f" (held by {', '.join(held[n])})" if n in held else "")
              for n, s in data["steps"].items()]
    lines += [f"SFCError {n}: {sfcerror_cause(s)}" for n, s in data["errors"].items()]
    lines += [f"forced {k}={v}" for k, v in data["forced"].items()]
    lines += not_applied_lines(data["not_applied"])
    lines += alarm_lines(data.get("alarms", []))
    lines += [f"fault at {_clock_text(f['time'])}: {f['reason']}" for f in data["faults"]]
    if data.get("reload"):
        lines.append(changing.last_reload_text(data["reload"]))
    if data.get("retain") and data["retain"]["state"] != "ok":
        lines.append(f"retain {data['retain']['state']}: {data['retain']['text']}")
    return lines, data


def cmd_stats(session: Session, args: list[str]) -> Reply:
    svc = session.service
    s = session.ctl.stats(svc.pause)  # computed here, never in the scan thread
    made = svc.stats_reply
    if made is not None and made[0] is s:  # the same figures: the same reply (no work)
        return made[1]
    reply = _stats_reply(s)
    svc.stats_reply = (s, reply)
    return reply


def _stats_reply(s: dict[str, Any]) -> Reply:
    cols = ("last", "min", "mean", "p50", "p99", "max")
    lines = [f"cycle time {s['cycle_us'] / 1000:g} ms: {s['cycles']} cycles, "
             f"{s['overruns']} overruns, {s['skipped']} deadlines skipped",
             f"{'(us)':10}" + "".join(f"{c:>9}" for c in cols)]
    for key, label in (("scan_us", "scan"), ("lateness_us", "lateness")):
        lines.append(f"{label:10}" + "".join(f"{s[key][c]:>9.1f}" for c in cols))
    lines.append(f"gc {s['gc_runs']} runs in the idle time, {s['gc_ms']} ms in all; "
                 f"{s['gc_full_runs']} full, the last {s['gc_full_ms']} ms (longest "
                 f"{s['gc_full_max_ms']}), {s['gc_full_deferred']} waited for idle time")
    for name, d in s.get("drivers", {}).items():
        reason = f": {d['reason']}" if d.get("reason") else ""
        lines.append(f"driver {name}: {d['health']} (on_fault {d['on_fault']}){reason}")
    return lines, {"stats": s}


def cmd_get(session: Session, args: list[str]) -> Reply:
    if not args:
        raise CommandError("usage: get NAME...")
    names = session.cat.expand(args)
    plant, cat = session.plant, session.cat

    def read() -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
        img = cat.live()
        values = {n.text: n.read(img) for n in names}
        # a chart output reads as applied (its point); what the chart says beside it
        charts = {n.text: n.chart(img) for n in names if n.chart is not None}
        forced = {k: v for k, v in plant.forced_values().items() if k in values}
        return values, forced, charts
    values, forced, charts = session.call(read)
    lines, shown, meanings, not_applied = [], {}, {}, {}
    for n in names:
        v = values[n.text]
        m = cat.iolist.meaning(n.text)
        unit = f" {m.unit.symbol}" if m.unit is not None and n.type in NUMBERS else ""
        if n.text in forced and n.role == "point in":
            # a forced input masks the driver during the cycle only: show both
            note = f" (forced; the driver reads {n.show(v)}{unit})"
            v = forced[n.text]
        else:
            note = " (forced)" if n.text in forced else ""
        if n.text in charts and not same(charts[n.text], v):  # held off, a forced point
            note += f" (not applied: the chart's value is {n.show(charts[n.text])}{unit})"
            not_applied[n.text] = n.plain(charts[n.text])
        shown[n.text] = n.plain(v)
        text = f"{n.text}={n.show(v)}{unit}{note}"
        if n.feeds:
            text += "  " + feeds_text(n, v)
        if n.binding and len(names) > 1:
            text += f"  {n.binding}"
        said = m.description
        if n.role.startswith("point"):  # what is wired there, as the binding says
            said = "; ".join(r.meaning.description for r in cat.iolist.bound_to(n.text)
                             if r.meaning.description)
        if said:
            text += f'  "{said}"'
        lines.append(text)
        if m != Meaning():
            meanings[n.text] = meaning_data(m)
    return lines, {"values": shown, "forced": sorted(forced),
                   "roles": {n.text: n.role for n in names}, "meanings": meanings,
                   "not_applied": not_applied}


def meaning_data(m: Meaning) -> dict[str, Any]:
    """What the I/O list says of a name, for JSON: description, unit (code and symbol),
    range [low, high]; only what is known."""
    out: dict[str, Any] = {}
    if m.description:
        out["description"] = m.description
    if m.unit is not None:
        out["unit"], out["symbol"] = m.unit.code, m.unit.symbol
    if m.range is not None:
        out["range"] = list(m.range)
    return out


def cmd_watch(session: Session, args: list[str]) -> Reply:
    every = None
    if len(args) >= 2 and args[-2] == "every":
        try:
            every = max(int(args[-1]), MIN_EVERY_MS) / 1000
        except ValueError:
            raise CommandError(f"bad value '{printable(args[-1])}' after 'every': "
                               "expected a number of ms") from None
        args = args[:-2]
    names = session.cat.expand(args) if args else session.cat.physical_inputs()
    if not names:
        raise CommandError("nothing to watch: this plant has no physical input")
    session.start_stream(Stream("watch", names, session.cat, every))
    return [f"watching {len(names)} value(s) "
            + (f"every {every * 1000:g} ms" if every else "on every change")
            + " until the next line"], {"watch": [n.text for n in names]}


def cmd_trace(session: Session, args: list[str]) -> Reply:
    if args not in (["on"], ["off"]):
        raise CommandError("usage: trace on|off")
    if args[0] == "off":
        return []
    session.start_stream(Stream("trace", session.cat.traced, session.cat))
    return ["tracing every scan's changes until the next line"], {}


def cmd_why(session: Session, args: list[str]) -> Reply:
    plant = session.plant
    if len(args) != 1 or args[0] not in plant.instances:
        given = f" '{printable(args[0])}'" if args else ""
        raise CommandError(f"usage: why INSTANCE; no instance{given} (one of "
                           f"{' '.join(plant.instances)})")
    name = args[0]
    whys = session.call(lambda: plant.explain(name))
    iolist = session.cat.iolist
    lines, data = [], []
    for sw in whys:
        said = iolist.meaning(f"{name}.{sw.step}").description
        lines.append(f"{sw.step} active for {round_times(format_ns(sw.time_ns))}"
                     + (f'  "{said}"' if said else ""))
        for tw in sw.transitions:
            state = ("fires" if tw.condition and not tw.blocked else
                     "blocked" if tw.condition else "false")
            lines.append(f"  [{state}] {tw.text}")
            for b in tw.blocked:
                lines.append(f"      blocked by: {round_times(b)}")
            for term in tw.terms:
                lines.append(f"      {'  ' * term.depth}{term.text} = {term.value}")
        data.append({"step": sw.step, "time_ms": round(sw.time_ns / 1e6),
                     "description": said,
                     "transitions": [
                         {"text": t.text, "condition": t.condition,
                          "blocked": [round_times(b) for b in t.blocked],
                          "terms": [{"text": x.text, "depth": x.depth, "value": x.value}
                                    for x in t.terms]} for t in sw.transitions]})
    if not whys:
        lines.append("no active step")
    return lines, {"instance": args[0], "why": data}


def cmd_unlock(session: Session, args: list[str]) -> Reply:
    svc = session.service
    if svc.pin_hash is None:
        raise CommandError("no pin_hash in the plant file: nothing to unlock"
                           + (" (this console is trusted)" if session.trusted else ""))
    if len(args) != 1:
        raise CommandError("usage: unlock PIN")
    svc.try_pin(args[0], session.name, session.peer)
    session.unlocked, session.unlocked_with = True, svc.pin_generation
    log.info("console %s unlocked", session.name)
    return ["unlocked"]


def cmd_lock(session: Session, args: list[str]) -> Reply:
    if not session.may_change():
        return ["already locked"]
    session.unlocked = False
    released = changing.unforce_all(session)
    return ["locked" + (f"; released {', '.join(released)}" if released else "")
            + ("; this console is trusted: changing commands stay allowed"
               if session.trusted else "")], {"released": released}


#: what ``web`` accepts as a user name and an address (they go into log lines)
_WEB_WORD = re.compile(r"^[A-Za-z0-9_.:\[\]@-]{1,64}$")


def cmd_web(session: Session, args: list[str]) -> Reply:
    """``web USER ADDRESS``: ``softplc web`` says that this session acts for the page of a
    user it logged in (docs/web.md). Only from root or the controller's own user on a Unix
    socket (the web view runs as the controller's user), and only on a plant with a
    ``web:`` section. The session may then change the machine without a PIN; what it
    holds is owned and ended as any session's (it is named ``web:USER@ADDRESS`` in the
    log and in ``status``)."""
    if session.plant.pdef.web is None:
        raise CommandError("web: the plant has no web: section")
    if session.name.startswith("web:"):
        raise CommandError(f"web: this session already acts for {session.name}")
    if not session.service_account():
        raise CommandError("web: only the web view may say whom it acts for (root or the "
                           "controller's own user, on a Unix socket)")
    if len(args) != 2 or not all(_WEB_WORD.match(a) for a in args):
        raise CommandError("usage: web USER ADDRESS")
    before = session.name
    session.name = f"web:{args[0]}@{args[1]}"
    session.trusted = True
    log.info("console %s: acts for %s", before, session.name)
    return [f"acting for {session.name}"]


#: every command by name (protocol.READ_ONLY and protocol.CHANGING name the same ones)
COMMANDS: dict[str, Command] = {
    "help": cmd_help, "status": cmd_status, "stats": cmd_stats, "get": cmd_get,
    "watch": cmd_watch, "trace": cmd_trace, "why": cmd_why, "json": cmd_json,
    "unlock": cmd_unlock, "lock": cmd_lock, "web": cmd_web,
    "set": changing.cmd_set, "force": changing.cmd_force, "unforce": changing.cmd_unforce,
    "pause": changing.cmd_pause, "resume": changing.cmd_resume, "cycle": changing.cmd_cycle,
    "init": changing.cmd_init, "reset": changing.cmd_reset, "iocheck": changing.cmd_iocheck,
    "ack": changing.cmd_ack, "reload": changing.cmd_reload,
}
