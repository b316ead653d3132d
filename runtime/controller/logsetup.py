"""Logging for the daemon: the journal's format under systemd, readable lines otherwise,
and a rate limit so that a fault repeating every scan cannot flood the log."""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Callable
from typing import TextIO

#: syslog priorities of the journal's ``<N>`` line prefix (sd-daemon.h)
PRIORITY = {logging.CRITICAL: 2, logging.ERROR: 3, logging.WARNING: 4, logging.INFO: 6,
            logging.DEBUG: 7}


def under_journal(stream: TextIO = sys.stderr, environ: dict[str, str] | None = None) -> bool:
    """True when ``stream`` is connected to the journal ($JOURNAL_STREAM names its
    device:inode, as systemd sets it for a service's stdout/stderr)."""
    env = os.environ if environ is None else environ
    value = env.get("JOURNAL_STREAM", "")
    try:
        dev, ino = (int(x) for x in value.split(":"))
        st = os.fstat(stream.fileno())
    except (ValueError, OSError, AttributeError):
        return False
    return st.st_dev == dev and st.st_ino == ino


class JournalFormatter(logging.Formatter):
    """``<3>driver rio: fault: ...``: the journal reads the priority from the prefix and
    stamps the time itself."""

    def format(self, record: logging.LogRecord) -> str:
        prio = PRIORITY.get(record.levelno, 6 if record.levelno < logging.WARNING else 3)
        text = super().format(record)
        return "\n".join(f"<{prio}>{line}" for line in text.splitlines())


class RateLimit(logging.Filter):
    """At most ``burst`` records of one message template per ``period_s``; when the
    period ends, one line says how many were suppressed. Per template, not per text: a
    fault whose reason carries a changing number is still one template."""

    def __init__(self, burst: int = 5, period_s: float = 10.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.burst = burst
        self.period_s = period_s
        self.clock = clock
        self._windows: dict[tuple[str, str], list[float]] = {}  # key -> [start, count]

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.name, str(record.msg))
        now = self.clock()
        w = self._windows.get(key)
        if w is None or now - w[0] >= self.period_s:
            if w is not None and w[1] > self.burst:
                record.msg = f"{record.msg} ({int(w[1] - self.burst)} similar messages " \
                             f"suppressed in the last {self.period_s:g} s)"
            self._windows[key] = [now, 1]
            if len(self._windows) > 1000:  # bounded: forget the oldest templates
                for k in list(self._windows)[:500]:
                    del self._windows[k]
            return True
        w[1] += 1
        return w[1] <= self.burst


def setup_logging(verbose: bool = False, stream: TextIO = sys.stderr) -> None:
    """Configure the root logger once, for the CLI."""
    root = logging.getLogger()
    if root.handlers:
        return
    handler = logging.StreamHandler(stream)
    if under_journal(stream):
        handler.setFormatter(JournalFormatter("%(name)s: %(message)s"))
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: "
                                               "%(message)s", "%H:%M:%S"))
    handler.addFilter(RateLimit())
    root.addHandler(handler)
    root.setLevel(logging.DEBUG if verbose else logging.INFO)
