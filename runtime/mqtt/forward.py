"""Store and forward: the changes the primary host has not had yet, kept to be sent as
history after the next births.

- ``Buffer``: the reports of the time nothing could be published (no broker, the primary
  host offline), at most ``bound`` metric values, the oldest reports dropped first.
- ``Journal``: the reports of the session's data messages that the broker has not been
  seen to take yet. A Sparkplug data message goes out at QoS 0 (the specification's
  rule), so nothing acknowledges it; the broker answers a request sent after it on the
  same connection (runtime/mqtt/session.py sends one), and since a broker reads a
  connection in order, its answer confirms every message before that request. When the
  session ends, what is not confirmed goes back to the front of the buffer: nothing
  handed to a broker that stalled or vanished is lost (values the broker did take may
  then reach the host twice, once live and once as history).
"""

from __future__ import annotations

import collections
from dataclasses import dataclass
from typing import Any

from runtime.mqtt.payload import DataType


@dataclass(slots=True)
class Report:
    """The changes of one report: (device, metric name, type, value, time in ms) each;
    the report's time (ms)."""

    timestamp: int
    changes: list[tuple[str, str, DataType, Any, int]]


class Buffer:
    """Reports kept in order, at most ``bound`` metric values in all; beyond it the oldest
    reports are dropped whole."""

    def __init__(self, bound: int) -> None:
        self.bound = bound
        self.reports: collections.deque[Report] = collections.deque()
        self.values = 0
        #: metric values dropped since the process started
        self.dropped = 0

    def add(self, report: Report) -> None:
        if self.bound <= 0:
            self.dropped += len(report.changes)
            return
        self.reports.append(report)
        self.values += len(report.changes)
        self._trim()

    def add_front(self, reports: list[Report]) -> None:
        """``reports`` (in order) before every report kept: they are older."""
        if self.bound <= 0:
            self.dropped += sum(len(r.changes) for r in reports)
            return
        self.reports.extendleft(reversed(reports))
        self.values += sum(len(r.changes) for r in reports)
        self._trim()

    def _trim(self) -> None:
        while self.values > self.bound and self.reports:
            old = self.reports.popleft()
            self.values -= len(old.changes)
            self.dropped += len(old.changes)

    def take(self) -> list[Report]:
        out = list(self.reports)
        self.reports.clear()
        self.values = 0
        return out


class Journal:
    """The reports of a session's data messages not yet confirmed by the broker, in order,
    each at a position (1, 2, 3 ... in the order they were queued)."""

    def __init__(self) -> None:
        self.entries: collections.deque[tuple[int, Report]] = collections.deque()
        self.last = 0

    def add(self, report: Report) -> int:
        """``report`` queued for the broker: its position."""
        self.last += 1
        self.entries.append((self.last, report))
        return self.last

    def confirm(self, upto: int) -> None:
        """The broker took every message up to position ``upto``."""
        while self.entries and self.entries[0][0] <= upto:
            self.entries.popleft()

    def take(self) -> list[Report]:
        """Every report not confirmed, in order (the journal is then empty)."""
        out = [r for _k, r in self.entries]
        self.entries.clear()
        return out
