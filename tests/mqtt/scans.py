"""The controller's scans by phases of a test, read from its trace (``softplc run --trace
FILE``: one JSON line per cycle, its number and its wake-up time in ms since the start):
how many cycles ran against the phase's span, and how many woke up late. A test runs a
quiet control phase and its attack in the same minute and holds the attack to the quiet
phase's counts (ratios, never absolute times: the machine is shared)."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

#: a wake-up this much later than the cycle's period after the previous one is late, ms
#: (the trace's clock counts whole ms: 3 ms is more than 2 ms late, a fifth of a 10 ms cycle)
LATE_MS = 3


@dataclass(frozen=True)
class Scans:
    """One phase: cycles traced, cycles its span should hold, late wake-ups, the longest
    period between two wake-ups (ms)."""

    cycles: int
    expected: float
    late: int
    worst_ms: int

    @property
    def missed(self) -> float:
        """Cycles the span should hold that did not run."""
        return max(0.0, self.expected - self.cycles)

    def within(self, quiet: Scans) -> bool:
        """No more cycles missed than twice the quiet phase's plus 5 % of its (every cycle
        ran, as the console flood test holds it), and no more late wake-ups than twice
        the quiet phase's plus 5; both per quiet phase's length (a shared machine's own
        allowance: its host takes the processors away now and then, for tens of ms,
        whatever runs)."""
        scale = max(1.0, self.cycles / max(1, quiet.cycles))
        return (self.missed <= (2 * quiet.missed + 0.05 * quiet.expected) * scale
                and self.late <= (2 * quiet.late + 5) * scale)


@dataclass
class Phase:
    """What ``TraceWatch.phase`` measured (``scans`` once the phase ended)."""

    scans: Scans | None = None
    rows: list[tuple[int, int]] = field(default_factory=list)


class TraceWatch:
    """Follows the trace file ``path`` of a controller whose cycle is ``cycle_ms``."""

    def __init__(self, path: Path, cycle_ms: float = 10.0) -> None:
        self.path = path
        self.cycle_ms = cycle_ms
        self._offset = 0
        self._rest = b""
        #: (cycle, wake-up ms) of every row read so far
        self.rows: list[tuple[int, int]] = []

    def read(self) -> list[tuple[int, int]]:
        """The rows written since the last read."""
        if not self.path.exists():
            return []
        with open(self.path, "rb") as f:
            f.seek(self._offset)
            data = f.read()
        self._offset += len(data)
        lines = (self._rest + data).split(b"\n")
        self._rest = lines.pop()
        new = []
        for line in lines:
            row = json.loads(line)
            new.append((int(row["cycle"]), int(row["t_ms"])))
        self.rows += new
        return new

    def last(self, timeout: float = 20.0) -> int:
        """The last cycle traced (waits for the first rows)."""
        end = time.monotonic() + timeout
        while True:
            self.read()
            if self.rows:
                return self.rows[-1][0]
            if time.monotonic() > end:
                size = self.path.stat().st_size if self.path.exists() else None
                raise AssertionError(f"no trace rows in {self.path} ({size} bytes)")
            time.sleep(0.05)

    @contextmanager
    def phase(self) -> Iterator[Phase]:
        """The scans between the start and the end of the ``with`` block (the trace is
        written a few tenths of a second behind: both ends are, alike)."""
        first = self.last()
        p = Phase()
        yield p
        last = self.last()
        p.rows = [r for r in self.rows if first < r[0] <= last]
        p.scans = self.summary(p.rows)

    def summary(self, rows: list[tuple[int, int]]) -> Scans:
        if len(rows) < 2:
            return Scans(len(rows), float(len(rows)), 0, 0)
        periods = [b[1] - a[1] for a, b in zip(rows, rows[1:], strict=False)]
        span = rows[-1][1] - rows[0][1]
        return Scans(cycles=len(rows), expected=span / self.cycle_ms + 1,
                     late=sum(p >= self.cycle_ms + LATE_MS for p in periods),
                     worst_ms=max(periods))
