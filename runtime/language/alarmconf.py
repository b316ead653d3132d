"""The ``alarms:`` section of a plant file (docs/daemon.md, "Alarms"): the severity of each
kind of alarm, and how many overruns in how long make an alarm."""

from __future__ import annotations

from typing import Any

from runtime.errors import Loc, SourceError, suggest
from runtime.language.model import ALARM_SEVERITY, AlarmsDef
from runtime.language.shape import Int, Key, Section, Time, expect_type, time_value
from runtime.language.yamlsrc import YMap

#: each kind of alarm, in the words editors show (the kinds and their defaults:
#: model.ALARM_SEVERITY)
KIND_WORDS = {
    "fault": "A controller fault (watchdog, a scan error)",
    "driver": "A driver's fault (its points off)",
    "sfcerror": "A chart's SFCError",
    "maxtime": "A step active longer than its max:",
    "overruns": "Too many overruns in the window",
}
#: a severity: OPC UA's range
SEVERITY_RANGE = Int(1, 1000)

# -- the shape of ``alarms:`` (runtime/language/shape.py)
SEVERITY = Section(tuple(Key(kind, SEVERITY_RANGE, f"{KIND_WORDS[kind]} (default {n}).")
                         for kind, n in ALARM_SEVERITY.items()),
                   "alarms severity", "kind: severity, 1 to 1000 (OPC UA's range).")
OVERRUNS = Section((
    Key("count", Int(0), "Overruns tolerated in the window (default 10)."),
    Key("window", Time(1_000_000_000, 3_600_000_000_000), "The window, 1s to 1h (default 60s)."),
), "alarms overruns", "An alarm when more than count overruns happen within window.")
ALARMS = Section((
    Key("severity", SEVERITY),
    Key("overruns", OVERRUNS),
), "alarms", "The alarm board (docs/daemon.md, 'Alarms'): the severity of each kind of alarm "
             "and how many overruns in how long make an alarm; every key optional.", null=True)


def load_alarms(value: Any, loc: Loc) -> AlarmsDef:
    """``alarms:`` -> AlarmsDef; SourceError at the faulty key or value."""
    m = expect_type(value, loc, YMap, "a mapping (severity, overruns)")
    ALARMS.check(m)
    a = AlarmsDef(loc=loc)
    if "severity" in m:
        sev = expect_type(m["severity"], m.val_locs["severity"], YMap,
                          f"a mapping kind: severity ({', '.join(ALARM_SEVERITY)})")
        for kind, n in sev.items():
            if kind not in ALARM_SEVERITY:
                raise SourceError(sev.key_locs[kind], f"unknown kind of alarm '{kind}': "
                                  f"expected one of {', '.join(ALARM_SEVERITY)}"
                                  f"{suggest(str(kind), ALARM_SEVERITY)}")
            vloc = sev.val_locs[kind]
            low, high = SEVERITY_RANGE.low, SEVERITY_RANGE.high
            n = expect_type(n, vloc, SEVERITY_RANGE.types, f"a severity from {low} to {high}")
            if not low <= n <= high:
                raise SourceError(vloc, f"alarms severity {kind}: expected {low} to {high} (OPC "
                                        f"UA's range), found {n}")
            a.severity[str(kind)] = n
    if "overruns" in m:
        o = expect_type(m["overruns"], m.val_locs["overruns"], YMap,
                        "a mapping (count, window)")
        OVERRUNS.check(o)
        if "count" in o:
            vloc = o.val_locs["count"]
            n = OVERRUNS.value(o, "count", "a number of overruns")
            if n < OVERRUNS["count"].low:
                raise SourceError(vloc, f"alarms overruns count: expected "
                                        f"{OVERRUNS['count'].low} or more, found {n}")
            a.overrun_count = n
        if "window" in o:
            vloc = o.val_locs["window"]
            ns = time_value(o["window"], vloc, "alarms overruns window")
            if not OVERRUNS["window"].low <= ns <= OVERRUNS["window"].high:
                raise SourceError(vloc, "alarms overruns window: expected 1s to 1h, found "
                                        f"{ns / 1e9:g} s")
            a.overrun_window_ns = ns
    return a
