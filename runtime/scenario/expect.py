"""Expectations checked against the trace of a scenario's run, each failure as one line
(docs/testing-charts.md, "Failures"): the place of the expectation, the scan, what was
expected and what the trace holds, and the nearest scan where it would have held."""

from __future__ import annotations

import operator
from collections.abc import Callable
from dataclasses import dataclass
from itertools import repeat
from typing import Any

from drivers.durations import format_ns
from runtime.errors import Loc, SourceError
from runtime.scenario.spec import OPS, Check, Expectation


@dataclass
class Trace:
    """The columns a scenario reads, one value per scan from cycle 0, as far as the run
    went (``fault``: why it stopped early, a scan fault's line)."""

    cols: dict[str, list[Any]]
    cycle_ns: int
    scans: int
    fault: str | None = None

    def at(self, k: int) -> str:
        return f"cycle {k} (t = {format_ns(k * self.cycle_ns)})"

    def mask(self, checks: tuple[Check, ...], first: int = 0, last: int | None = None
             ) -> list[bool]:
        """Whether every check holds, for each scan of ``first``..``last`` (default: the
        whole run), computed a column at a time."""
        last = self.scans - 1 if last is None else last
        out: list[bool] | None = None
        for c in checks:
            col = self.cols[c.column][first:last + 1]
            m = list(map(OPS[c.op], col, repeat(c.value, len(col))))
            out = m if out is None else list(map(operator.and_, out, m))
        return out or []

    def holds(self, checks: tuple[Check, ...]) -> Callable[[int], bool]:
        """Whether every check holds in scan k (the whole run's mask, made once)."""
        return self.mask(checks).__getitem__

    def rises(self, column: str, first: int, last: int, falls: bool = False) -> list[int]:
        """The scans of ``first``..``last`` where the bool ``column`` goes from 0 to 1
        (``falls``: 1 to 0) since the scan before (never in cycle 0)."""
        col = self.cols[column]
        start = max(first, 1)
        pairs = zip(col[start - 1:last], col[start:last + 1], strict=True)
        if falls:
            return [start + i for i, (a, b) in enumerate(pairs) if a and not b]
        return [start + i for i, (a, b) in enumerate(pairs) if b and not a]


def failure(e: Expectation, tr: Trace) -> str | None:
    """None if ``e`` holds in ``tr``; else its failure, one line (``FILE:LINE:COL: error:
    ...``)."""
    if e.last >= tr.scans:
        return str(SourceError(e.loc, f"{e.named}{e.title}: not checked: the run stopped "
                                      f"at {tr.at(tr.scans - 1)} "
                                      f"({tr.fault or 'no more scans'})"))
    check = {"at": _at, "within": _within, "never": _never, "always": _always,
             "on_rise": _on_edge, "on_fall": _on_edge, "rises": _rises}[e.kind]
    found = check(e, tr)
    return None if found is None else str(SourceError(found[0], e.named + found[1]))


Found = tuple[Loc, str] | None


def _expected(checks: tuple[Check, ...]) -> str:
    return ", ".join(c.text() for c in checks)


def _holds_text(checks: tuple[Check, ...], tr: Trace, k: int) -> str:
    return ", ".join(f"{c.name} = {c.show(tr.cols[c.column][k])}" for c in checks)


def _first_false(checks: tuple[Check, ...], tr: Trace, k: int) -> Check:
    return next((c for c in checks if not c.test(tr.cols[c.column][k])), checks[0])


def nearest(holds: Callable[[int], bool], first: int, last: int, tr: Trace) -> str:
    """Where it would have held: the scan outside ``first``..``last`` nearest to it (the
    earlier one on a tie), or that none of the run does."""
    for d in range(1, tr.scans):
        before, after = first - d, last + d
        if before >= 0 and holds(before):
            return f"it holds at {tr.at(before)}, {_scans(d)} earlier"
        if after < tr.scans and holds(after):
            return f"it holds at {tr.at(after)}, {_scans(d)} later"
        if before < 0 and after >= tr.scans:
            break
    return "it holds in no scan of the run"


def _scans(n: int) -> str:
    return f"{n} scan{'s' if n != 1 else ''}"


def _at(e: Expectation, tr: Trace) -> Found:
    k = e.first
    if all(c.test(tr.cols[c.column][k]) for c in e.checks):
        return None
    holds = tr.holds(e.checks)
    return (_first_false(e.checks, tr, k).loc,
            f"{tr.at(k)}: expected {_expected(e.checks)}; the trace holds "
            f"{_holds_text(e.checks, tr, k)}; {nearest(holds, k, k, tr)}")


def _within(e: Expectation, tr: Trace) -> Found:
    if any(tr.mask(e.checks, e.first, e.last)):
        return None
    holds = tr.holds(e.checks)
    seen = []
    for c in e.checks:
        values = list(dict.fromkeys(tr.cols[c.column][e.first:e.last + 1]))
        shown = (f"= {c.show(values[0])} throughout" if len(values) == 1 else
                 "takes " + ", ".join(c.show(v) for v in values[:6])
                 + (", ..." if len(values) > 6 else ""))
        seen.append(f"{c.name} {shown}")
    return (_first_false(e.checks, tr, e.first).loc,
            f"{tr.at(e.first)} to {tr.at(e.last)}: expected {_expected(e.checks)} in some "
            f"scan; the trace holds {', '.join(seen)}; {nearest(holds, e.first, e.last, tr)}")


def _never(e: Expectation, tr: Trace) -> Found:
    bad = [e.first + i for i, h in enumerate(tr.mask(e.checks, e.first, e.last)) if h]
    if not bad:
        return None
    return (e.checks[0].loc,
            f"{tr.at(bad[0])}: expected never {_expected(e.checks)} {e.span}; the trace "
            f"holds {_holds_text(e.checks, tr, bad[0])} ({_breaks(bad, e)})")


def _always(e: Expectation, tr: Trace) -> Found:
    bad = [e.first + i for i, h in enumerate(tr.mask(e.checks, e.first, e.last)) if not h]
    if not bad:
        return None
    return (_first_false(e.checks, tr, bad[0]).loc,
            f"{tr.at(bad[0])}: expected always {_expected(e.checks)} {e.span}; the trace "
            f"holds {_holds_text(e.checks, tr, bad[0])} ({_breaks(bad, e)})")


def _breaks(bad: list[int], e: Expectation) -> str:
    n = e.last - e.first + 1
    return (f"{_scans(len(bad))} of {n} break it"
            + (f", the last cycle {bad[-1]}" if len(bad) > 1 else ""))


def _on_edge(e: Expectation, tr: Trace) -> Found:
    assert e.trigger is not None
    t = e.trigger
    falls = e.kind == "on_fall"
    edges = tr.rises(t.column, e.first, e.last, falls)
    verb = "fall" if falls else "rise"
    if not edges:
        values = list(dict.fromkeys(tr.cols[t.column][e.first:e.last + 1]))
        return (t.loc, f"never reached: expected {t.name} to {verb} {e.span}; it never "
                       f"does (it is {', then '.join(t.show(v) for v in values[:4])}); "
                       f"nothing was checked")
    ok = tr.mask(e.checks, e.first, e.last)
    bad = [k for k in edges if not ok[k - e.first]]
    if not bad:
        return None
    k = bad[0]
    holds = tr.holds(e.checks)
    of = f" ({len(bad)} of {len(edges)} {verb}s fail)" if len(edges) > 1 else ""
    return (_first_false(e.checks, tr, k).loc,
            f"{tr.at(k)}, where {t.name} {verb}s: expected {_expected(e.checks)}; the "
            f"trace holds {_holds_text(e.checks, tr, k)}; {nearest(holds, k, k, tr)}{of}")


def _rises(e: Expectation, tr: Trace) -> Found:
    for c in e.checks:
        edges = tr.rises(c.column, e.first, e.last)
        if c.test(len(edges)):
            continue
        shown = ", ".join(str(k) for k in edges[:8]) + (", ..." if len(edges) > 8 else "")
        every = tr.rises(c.column, e.first, tr.scans - 1)
        # the window's end nearest to its own at which the count would hold
        ends, seen = [], 0
        for k in range(e.first, tr.scans):
            while seen < len(every) and every[seen] <= k:
                seen += 1
            if c.test(seen):
                ends.append(k)
        best = min(ends, key=lambda k: (abs(k - e.last), k), default=None)
        where = ("no end of the window makes it hold" if best is None else
                 f"it holds for a window ending at {tr.at(best)}")
        want = (f"{c.value} rising edge{'s' if c.value != 1 else ''}" if c.op == "=="
                else f"{c.op} {c.value} rising edges")
        return (c.loc, f"{e.span}: expected {want} of {c.name}; the trace "
                       f"holds {len(edges)}"
                       + (f" (at cycle{'s' if len(edges) > 1 else ''} {shown})" if edges else "")
                       + f"; {where}")
    return None
