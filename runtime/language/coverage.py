"""SFC coverage of a chart: which steps were active, which transitions fired, which actions
ran and which branches of each divergence were taken, over the scenarios of ``softplc
test`` (docs/testing-charts.md, "Coverage").

A chart's items are named by what they are (a step's name; a transition's
``SOURCES -> TARGETS when CONDITION``; an action's step, qualifier and text), not by their
position, so that a coverage file (``softplc test --coverage-file``) still shades the right
elements of a chart drawn later (``softplc draw --coverage``, ``softplc web --coverage``);
an element the file does not name is drawn as not measured. The counts come from a program
compiled with coverage (``compile_grafcet(coverage=True)``, ``Program.coverage``): its
counters are keyed ``step:NAME``, ``transition:INDEX``, ``action:N`` (the N-th action of
``Grafcet.actions()``), the ``ref`` of each item here.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any

from runtime.errors import Loc, SourceError
from runtime.language.model import Grafcet, Transition
from runtime.language.safefile import UnfitFile, read_bounded
from runtime.language.unparse import transition_text

#: the kinds of item, in the order a report lists them
KINDS = ("step", "transition", "action", "branch")
#: what a report says of an item never reached, per kind
NEVER = {"step": "never active", "transition": "never fired", "action": "never ran",
         "branch": "never taken"}
#: each kind's plural, as a summary counts them
PLURAL = {"step": "steps", "transition": "transitions", "action": "actions",
          "branch": "branches"}
#: the format name and version of a coverage file
FORMAT = "softplc-coverage"
VERSION = 1
#: the largest coverage file read (bytes)
MAX_FILE = 16 << 20


@dataclass
class Item:
    """One element of a chart and how many times the scenarios reached it."""

    kind: str  # step, transition, action, branch
    key: str  # what it is: "gsAbrir", "gsAbrir -> gsCerrar when iAbierto", ...
    line: int
    col: int
    count: int = 0
    #: the program's counter (``step:NAME``, ``transition:I``, ``action:N``); a branch
    #: reads its transition's
    ref: str = ""

    def describe(self) -> str:
        """The item as a report names it."""
        if self.kind == "action":
            step, _, text = self.key.partition(": ")
            return f"action '{text}' of step {step}"
        if self.kind == "branch":
            step, _, branch = self.key.partition(" => ")
            return f"branch '{branch}' of the divergence after {step}"
        return f"{self.kind} {self.key}"


@dataclass
class ChartCoverage:
    """The coverage of one chart file, summed over every instance of it in every scenario."""

    path: str
    grafcet: str
    items: list[Item] = field(default_factory=list)
    #: the scenarios that ran the chart
    scenarios: int = 0

    def add(self, other: ChartCoverage) -> None:
        """Sum ``other`` (the same chart, from another scenario or instance) into this one."""
        mine = {(i.kind, i.key): i for i in self.items}
        for item in other.items:
            if (item.kind, item.key) in mine:
                mine[(item.kind, item.key)].count += item.count
            else:
                self.items.append(Item(item.kind, item.key, item.line, item.col, item.count,
                                       item.ref))
        self.scenarios += other.scenarios

    def of(self, kind: str) -> list[Item]:
        return [i for i in self.items if i.kind == kind]

    def missed(self) -> list[Item]:
        """The items never reached, kind by kind, in file order within a kind."""
        return [i for k in KINDS for i in self.of(k) if i.count == 0]

    def measured(self) -> list[Item]:
        """The items the percentage counts: steps, transitions and actions (a branch is a
        transition: counted once)."""
        return [i for i in self.items if i.kind != "branch"]

    def percent(self) -> float:
        items = self.measured()
        return 100.0 * sum(1 for i in items if i.count) / len(items) if items else 100.0


def _numbered(keys: list[str]) -> list[str]:
    """``keys`` with a repeated one numbered (``KEY #2``): every item keeps its own name."""
    seen: dict[str, int] = {}
    out = []
    for k in keys:
        seen[k] = seen.get(k, 0) + 1
        out.append(k if seen[k] == 1 else f"{k} #{seen[k]}")
    return out


def action_key(step: str, text: str) -> str:
    return f"{step}: {' '.join(text.split())}"


def chart_items(g: Grafcet) -> list[Item]:
    """Every item of ``g`` with a zero count, kind by kind, file order."""
    items = [Item("step", s.name, s.loc.line, s.loc.col, ref=f"step:{s.name}")
             for s in g.steps.values()]
    tkeys = _numbered([transition_text(t) for t in g.transitions])
    items += [Item("transition", k, t.loc.line, t.loc.col, ref=f"transition:{t.index}")
              for t, k in zip(g.transitions, tkeys, strict=True)]
    actions = g.actions()
    akeys = _numbered([action_key(a.step, a.text) for a in actions])
    items += [Item("action", k, a.loc.line, a.loc.col, ref=f"action:{n}")
              for n, (a, k) in enumerate(zip(actions, akeys, strict=True))]
    tkey = {t.index: k for t, k in zip(g.transitions, tkeys, strict=True)}
    for step, leaving in divergences(g).items():
        items += [Item("branch", f"{step} => {tkey[t.index]}", t.loc.line, t.loc.col,
                       ref=f"transition:{t.index}") for t in leaving]
    return items


def divergences(g: Grafcet) -> dict[str, list[Transition]]:
    """The OR divergences: each step (as the transitions name it) that two or more
    transitions leave, with them in priority order. (The branches of an AND divergence
    are entered together by one transition: its firing is their coverage.)"""
    out: dict[str, list[Transition]] = {}
    for t in g.transitions:
        for s in dict.fromkeys(t.sources):
            out.setdefault(s, []).append(t)
    return {s: ts for s, ts in out.items() if len(ts) > 1}


def counted(g: Grafcet, counts: dict[str, int]) -> ChartCoverage:
    """The coverage of one run of ``g``: ``counts`` are a program's counters
    (``Program.coverage``)."""
    items = chart_items(g)
    for i in items:
        i.count = counts.get(i.ref, 0)
    return ChartCoverage(shown_path(g.path), g.name, items, 1)


def shown_path(path: str) -> str:
    """``path`` relative to the working directory when it is under it, else as given."""
    rel = os.path.relpath(path)
    return path if rel.startswith("..") else rel


# -- the report ----------------------------------------------------------------------------
def summary(cov: ChartCoverage) -> str:
    """``NAME (PATH): steps 4/4, transitions 6/7, actions 9/9, branches 4/5: 94.7%``."""
    parts = []
    for kind in KINDS:
        items = cov.of(kind)
        if items:
            parts.append(f"{PLURAL[kind]} {sum(1 for i in items if i.count)}/{len(items)}")
    return f"{cov.grafcet} ({cov.path}): {', '.join(parts)}: {cov.percent():.1f}%"


def report(charts: list[ChartCoverage]) -> list[str]:
    """The lines of ``softplc test --coverage``: per chart its summary, then one line per
    item never reached (``FILE:LINE:COL: step gsAveria never active``), then the total."""
    lines = []
    for cov in charts:
        lines.append(summary(cov))
        lines += [f"  {cov.path}:{i.line}:{i.col}: {i.describe()} {NEVER[i.kind]}"
                  for i in cov.missed()]
    lines.append(f"total: {total(charts):.1f}% of {sum(len(c.measured()) for c in charts)} "
                 "steps, transitions and actions")
    return lines


def total(charts: list[ChartCoverage]) -> float:
    """The percentage of steps, transitions and actions reached, over every chart."""
    items = [i for c in charts for i in c.measured()]
    return 100.0 * sum(1 for i in items if i.count) / len(items) if items else 100.0


# -- the file ------------------------------------------------------------------------------
def dumps(charts: list[ChartCoverage]) -> str:
    """The coverage file's text (JSON)."""
    return json.dumps({"format": FORMAT, "version": VERSION, "charts": [
        {"path": c.path, "grafcet": c.grafcet, "scenarios": c.scenarios,
         "items": [{"kind": i.kind, "key": i.key, "line": i.line, "col": i.col,
                    "count": i.count} for i in c.items]} for c in charts]},
        indent=1, ensure_ascii=False) + "\n"


def load(path: str) -> list[ChartCoverage]:
    """The charts of a coverage file; SourceError (one line) if it is not one."""
    try:
        data = json.loads(read_bounded(path, MAX_FILE, follow_links=True))
    except (OSError, UnfitFile) as exc:
        raise SourceError(Loc(path, 1, 1), f"cannot read the coverage file: "
                                           f"{getattr(exc, 'strerror', None) or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SourceError(Loc(path, getattr(exc, "lineno", 1), getattr(exc, "colno", 1)),
                          f"not a coverage file (bad JSON: {exc})") from None
    if not (isinstance(data, dict) and data.get("format") == FORMAT
            and data.get("version") == VERSION and isinstance(data.get("charts"), list)):
        raise SourceError(Loc(path, 1, 1), f"not a coverage file: expected the JSON that "
                                           f"softplc test --coverage-file writes "
                                           f"(format {FORMAT!r}, version {VERSION})")
    try:
        return [_chart(c) for c in data["charts"]]
    except (KeyError, TypeError, ValueError) as exc:
        raise SourceError(Loc(path, 1, 1), f"not a coverage file: a chart's record is "
                                           f"malformed ({type(exc).__name__}: {exc})") from None


def _chart(c: Any) -> ChartCoverage:
    items = []
    for i in c["items"]:
        kind, key = str(i["kind"]), str(i["key"])
        if kind not in KINDS:
            raise ValueError(f"unknown kind {kind!r}")
        items.append(Item(kind, key, int(i["line"]), int(i["col"]), int(i["count"])))
    return ChartCoverage(str(c["path"]), str(c["grafcet"]), items, int(c["scenarios"]))


def of_chart(charts: list[ChartCoverage], g: Grafcet) -> ChartCoverage | None:
    """The coverage of chart ``g`` in a coverage file: the record of its file (the same
    file, wherever the paths were written from), else the only record of its grafcet name."""
    real = os.path.realpath(g.path)
    for c in charts:
        if os.path.realpath(c.path) == real:
            return c
    named = [c for c in charts if c.grafcet == g.name]
    return named[0] if len(named) == 1 else None


@dataclass
class Shading:
    """What a drawing shades of one chart: per element, reached (True), never reached
    (False); an element absent was not measured (the file is of another version of it)."""

    steps: dict[str, bool] = field(default_factory=dict)
    transitions: dict[int, bool] = field(default_factory=dict)  # by Transition.index
    actions: dict[tuple[str, int], bool] = field(default_factory=dict)  # (step, row)


def shading(g: Grafcet, cov: ChartCoverage) -> Shading:
    """The shading of ``g`` from its coverage, matched element by element by name."""
    counts = {(i.kind, i.key): i.count for i in cov.items}
    out = Shading()
    for item in chart_items(g):
        n = counts.get((item.kind, item.key))
        if n is None:
            continue
        kind, _, ref = item.ref.partition(":")
        if item.kind == "step":
            out.steps[ref] = n > 0
        elif item.kind == "transition":
            out.transitions[int(ref)] = n > 0
        elif item.kind == "action":
            a = g.actions()[int(ref)]
            row = next(k for k, b in enumerate(g.steps[a.step].actions) if b is a)
            out.actions[(a.step, row)] = n > 0
    return out
