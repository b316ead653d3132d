"""The ``alarms:`` section of a plant file (docs/daemon.md, "Alarms"): the severity of each
kind of alarm, and how many overruns in how long make an alarm."""

from __future__ import annotations

from typing import Any

from runtime.errors import Loc, SourceError, suggest
from runtime.language.grafcetfile import check_keys, expect_type, time_value
from runtime.language.model import ALARM_SEVERITY, AlarmsDef
from runtime.language.yamlsrc import YMap

ALARMS_KEYS = ("severity", "overruns")
OVERRUNS_KEYS = ("count", "window")
#: the longest overrun window, ns (an hour)
WINDOW_MAX_NS = 3_600_000_000_000


def load_alarms(value: Any, loc: Loc) -> AlarmsDef:
    """``alarms:`` -> AlarmsDef; SourceError at the faulty key or value."""
    m = expect_type(value, loc, YMap, "a mapping (severity, overruns)")
    check_keys(m, ALARMS_KEYS, "alarms")
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
            n = expect_type(n, vloc, int, "a severity from 1 to 1000")
            if not 1 <= n <= 1000:
                raise SourceError(vloc, f"alarms severity {kind}: expected 1 to 1000 (OPC "
                                        f"UA's range), found {n}")
            a.severity[str(kind)] = n
    if "overruns" in m:
        o = expect_type(m["overruns"], m.val_locs["overruns"], YMap,
                        "a mapping (count, window)")
        check_keys(o, OVERRUNS_KEYS, "alarms overruns")
        if "count" in o:
            vloc = o.val_locs["count"]
            n = expect_type(o["count"], vloc, int, "a number of overruns")
            if n < 0:
                raise SourceError(vloc, f"alarms overruns count: expected 0 or more, found {n}")
            a.overrun_count = n
        if "window" in o:
            vloc = o.val_locs["window"]
            ns = time_value(o["window"], vloc, "alarms overruns window")
            if not 1_000_000_000 <= ns <= WINDOW_MAX_NS:
                raise SourceError(vloc, "alarms overruns window: expected 1s to 1h, found "
                                        f"{ns / 1e9:g} s")
            a.overrun_window_ns = ns
    return a
