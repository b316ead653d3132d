"""What ``softplc monitor`` shows, as text lines: ``View``, from the replies to
``status``, ``stats`` and ``get``, and the log of what was typed and answered under it.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from runtime.console.client import LOG_LINES, ConsoleClient, reply_timeout
from runtime.controller.alarms import alarm_lines
from runtime.engine.names import not_applied_lines
from runtime.language.flagtexts import sfcerror_cause

#: two starts of the controller estimated this far apart are two runs of it, seconds (each
#: estimate is exact to the time a ``status`` takes, plus the 1 ms of its rounding)
RESTART_SLACK_S = 0.25


@dataclass
class View:
    """What the screen shows, from the replies to ``status``, ``stats`` and ``get``."""

    target: str = ""
    status: dict[str, Any] = field(default_factory=dict)
    stats: dict[str, Any] = field(default_factory=dict)
    values: dict[str, Any] = field(default_factory=dict)
    roles: dict[str, str] = field(default_factory=dict)
    #: the I/O list of the names shown: name -> unit symbol
    units: dict[str, str] = field(default_factory=dict)
    forced_names: set[str] = field(default_factory=set)
    log: deque[str] = field(default_factory=lambda: deque(maxlen=LOG_LINES))
    problem: str = ""
    updated: float = 0.0
    #: refreshes done
    refreshes: int = 0
    #: the connection is lost: why, and when the next try is (None: connected)
    offline: str | None = None
    #: when the controller started (monotonic seconds, earliest and latest: ``status``
    #: gives its uptime, sampled between sending it and its reply), and its scan count
    started: tuple[float, float] | None = None
    scans: int = 0
    clock: Callable[[], float] = time.monotonic

    def refresh(self, client: ConsoleClient) -> None:
        """Ask for everything the view shows (three commands, three scan boundaries)."""
        sent = self.clock()
        st = client.request("status")
        replied = self.clock()
        sx = client.request("stats")
        if not st.get("ok") or not sx.get("ok"):
            self.problem = str(st.get("error") or sx.get("error"))
            return
        self._note_start(st, sent, replied)
        self.status, self.stats = st, sx["stats"]
        instances = list(st.get("steps", {}))
        if instances:
            got = client.request("get " + " ".join(instances))
            if got.get("ok"):
                self.values, self.roles = got["values"], got.get("roles", {})
                self.forced_names = set(got.get("forced", ()))
                self.units = {n: m["symbol"] for n, m in got.get("meanings", {}).items()
                              if "symbol" in m and self.roles.get(n) != "step time"}
        self.problem = ""
        self.updated = time.time()
        self.refreshes += 1

    def _note_start(self, st: dict[str, Any], sent: float, replied: float) -> None:
        """Say so when the controller is a new run of it: its start moved (the scan
        count going down is the same sign, for a restart sooner than RESTART_SLACK_S)."""
        up, scans = float(st.get("uptime_s", 0.0)), int(st.get("scans", 0))
        if up <= 0.0:
            return  # not scanning yet: nothing to compare
        lo, hi = sent - up, replied - up
        was = self.started
        if was is not None and (scans < self.scans or lo > was[1] + RESTART_SLACK_S
                                or hi < was[0] - RESTART_SLACK_S):
            self.log.append(f"{_now()} controller restarted: up {up:.1f} s, {scans} scans "
                            f"(was {self.scans} scans)")
            self.values, self.roles, self.forced_names = {}, {}, set()
        elif was is not None and was[1] - was[0] < hi - lo:
            lo, hi = was  # the same run: keep the closer estimate
        self.started, self.scans = (lo, hi), scans

    def lost(self, reason: str) -> None:
        """The connection broke (the view keeps what it last showed)."""
        self.log.append(f"{_now()} connection lost: {reason}")
        self.offline = reason

    def connected(self, target: str) -> None:
        self.log.append(f"{_now()} connected again to {target}")
        self.offline = None
        self.problem = ""

    def command(self, client: ConsoleClient, line: str) -> dict[str, Any]:
        """A command typed at the prompt; its reply goes to the log."""
        self.log.append(f"> {line}")
        reply = client.request(line, reply_timeout(line, self.status.get("cycle_ms")))
        if reply.get("ok"):
            self.log.extend(reply.get("text", []))
            self.log.append("ok")
        else:
            self.log.append(f"error {reply.get('error')}")
        return reply

    def stream(self, objs: list[dict[str, Any]]) -> None:
        for obj in objs:
            kind = "watch" if "watch" in obj else "trace" if "trace" in obj else "?"
            values = obj.get(kind, {})
            head = kind + (f" {obj['scan']}" if "scan" in obj else "")
            self.log.append(head + ": " + "  ".join(f"{k}={v}" for k, v in values.items()))

    def lines(self, width: int = 100) -> list[str]:
        """The view as text lines (the top of the screen)."""
        st, sx = self.status, self.stats
        out = []
        state = str(st.get("state", "?")).upper()
        if st.get("fault"):
            state += f" ({st['fault']})"
        if self.offline is not None:
            seen = time.strftime("%H:%M:%S", time.localtime(self.updated)) if self.updated \
                else "never"
            out.append(f"softplc monitor {self.target}   connection lost")
            out.append(f"{self.offline}; q or Ctrl-C leaves. Last seen {seen}: "
                       f"state {state}")
        else:
            out.append(f"softplc monitor {self.target}   state {state}")
        if st:
            out.append(f"cycle {st.get('cycle_ms', 0):g} ms   scans {st.get('scans', 0)}   "
                       f"uptime {st.get('uptime_s', 0):.1f} s   "
                       f"overruns {sx.get('overruns', 0)}")
        # what holds the charts or the outputs (a pause, an instance's SFCPause...),
        # but the condition the state line names already
        out += [f"inhibit  {x}" for x in st.get("inhibits", [])
                if not x.startswith(f"{st.get('state')}: ")]
        for key, label in (("scan_us", "scan    "), ("lateness_us", "lateness")):
            s = sx.get(key)
            if s:
                out.append(f"{label} us  last {s['last']:.0f}  mean {s['mean']:.0f}  "
                           f"p99 {s['p99']:.0f}  max {s['max']:.0f}")
        drivers = sx.get("drivers", {})
        if drivers:
            out.append("drivers  " + "  ".join(
                f"{n} {d['health']}" + (f" ({d['reason']})" if d.get("reason") else "")
                for n, d in drivers.items()))
        said = st.get("descriptions", {})
        for inst, steps in st.get("steps", {}).items():
            out.append("")
            out.append(f"{inst}  {' '.join(steps) or '(no active step)'}")
            # what the plant file says of the instance and its active steps
            about = [said[inst]] if inst in said else []
            about += [f"{s}: {said[f'{inst}.{s}']}" for s in steps if f"{inst}.{s}" in said]
            if about:
                out.append("  " + "; ".join(about))
            for role, label in (("input", "in "), ("output", "out"), ("memory", "mem")):
                cells = [self._cell(n) for n, r in self.roles.items()
                         if r == role and n.startswith(inst + ".")]
                if cells:
                    out += _wrap(f"  {label} ", cells, width)
        for inst, step in st.get("errors", {}).items():
            out.append(f"SFCError {inst}: {sfcerror_cause(step)}")
        forced = st.get("forced", {})
        out.append("")
        out.append("forced   " + (", ".join(f"{k}={v}" for k, v in forced.items())
                                  if forced else "-") + "      (* = forced)")
        # outputs shown as applied (off while held off): what the charts say beside
        out += not_applied_lines(st.get("not_applied", {}), "not applied  ")
        out += alarm_lines(st.get("alarms", []))
        for f in st.get("faults", [])[-3:]:
            when = time.strftime("%H:%M:%S", time.localtime(f["time"]))
            out.append(f"fault {when} {f['reason']}")
        if self.problem:
            out.append(f"!! {self.problem}")
        return [row for x in out for row in fold(x, width)]

    def _cell(self, name: str) -> str:
        short = name.split(".", 1)[1]
        mark = "*" if name in self.forced_names else " "
        unit = self.units.get(name, "")
        return f"{short}={self.values.get(name, '?')}{unit}{mark}"


def _now() -> str:
    return time.strftime("%H:%M:%S")


def fold(text: str, width: int, indent: str = "  ") -> list[str]:
    """``text`` in rows of at most ``width`` characters (at least 20): broken at the last
    space of a row when it is in the row's second half, else at the width; each further
    row begins with ``indent``."""
    width = max(width, 20)
    out, head, rest = [], "", text
    while len(head) + len(rest) > width:
        room = width - len(head)
        cut = rest.rfind(" ", room // 2, room + 1)
        if cut > 0:
            out.append(head + rest[:cut].rstrip())
            rest = rest[cut + 1:]
        else:
            out.append(head + rest[:room])
            rest = rest[room:]
        head = indent
    out.append(head + rest)
    return out


def _wrap(head: str, cells: list[str], width: int) -> list[str]:
    out, cur = [], head
    for c in cells:
        if len(cur) + len(c) + 2 > width and cur.strip():
            out.append(cur)
            cur = " " * len(head)
        cur += c + "  "
    out.append(cur.rstrip())
    return out
