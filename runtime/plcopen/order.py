"""The order of an imported chart's steps and transitions, whatever the order of the file's
elements: the order softplc wrote in its additional data when it is there for every
element, else a walk of the chart from its initial steps, top to bottom and left to right.

Transitions that leave one step keep their priority order in any case: the ``priority``
attribute (or CODESYS's), the lowest first (IEC 61131-3), and without one the left one
first (IEC 61131-3's default); the chart's order of transitions is their priority
(docs/semantics.md), so the order found is sorted again under those constraints.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable

from runtime.errors import SourceError
from runtime.plcopen.interface import softplc_data
from runtime.plcopen.sfcgraph import GTransition, Level, position
from runtime.plcopen.vendor import codesys_attributes
from runtime.plcopen.xmltree import Element

SiblingKey = tuple[tuple[int, int], float, float, int]


def priority(t: GTransition) -> int | None:
    """A transition's priority: its ``priority`` attribute, else CODESYS's, else None."""
    raw = t.e.get("priority") or codesys_attributes(t.e).get("priority")
    if raw is None or not raw.strip():
        return None
    if not raw.strip().isdigit():
        raise SourceError(t.e.loc, f"expected a priority (an unsigned integer), found '{raw}'")
    return int(raw)


def sibling_key(t: GTransition) -> SiblingKey:
    """How transitions that leave one step are ordered: priority (lowest first; those without
    one after those with one), then from left to right, top to bottom."""
    p = priority(t)
    x, y = position(t.e)
    return ((0, p) if p is not None else (1, 0)), x, y, t.id


def _stored(e: Element, tag: str) -> int | None:
    sp = softplc_data(e, tag)
    raw = sp.get("order") if sp is not None else None
    return int(raw) if raw is not None and raw.isdigit() else None


def order(level: Level, initial: Callable[[str], bool]) -> tuple[list[str], list[GTransition]]:
    """(step names, transitions) of a level in the chart's order; ``initial(name)`` tells
    the initial steps (where the walk starts)."""
    steps = list(level.steps.values())
    stored = {s.name: _stored(s.e, "step") for s in steps}
    walk_steps, walk_trans = _walk(level, initial)
    if steps and all(v is not None for v in stored.values()):
        names = sorted(stored, key=lambda n: (stored[n], n))
    else:
        names = walk_steps
    ts = level.transitions
    rank = {t.id: i for i, t in enumerate(walk_trans)}
    tstored = {t.id: _stored(t.e, "transition") for t in ts}
    if ts and all(v is not None for v in tstored.values()):
        rank = {i: v for i, v in tstored.items() if v is not None}
    return names, _constrained(level, rank)


def _walk(level: Level, initial: Callable[[str], bool]) -> tuple[list[str], list[GTransition]]:
    """Depth first from the initial steps (top to bottom, left to right), each step's
    transitions in their priority order, each transition's targets left to right; then what
    the walk did not reach, by position."""
    outs: dict[str, list[GTransition]] = {n: [] for n in level.steps}
    for t in sorted(level.transitions, key=sibling_key):
        for s in t.sources:
            outs[s].append(t)

    def where(name: str) -> tuple[float, float, str]:
        x, y = position(level.steps[name].e)
        return y, x, name

    starts = sorted((n for n in level.steps if initial(n)), key=where)
    starts += sorted((n for n in level.steps if not initial(n)), key=where)
    seen: set[str] = set()
    seen_t: set[int] = set()
    names: list[str] = []
    trans: list[GTransition] = []
    for start in starts:
        stack = [start]
        while stack:
            n = stack.pop()
            if n in seen:
                continue
            seen.add(n)
            names.append(n)
            nxt: list[str] = []
            for t in outs[n]:
                if t.id in seen_t:
                    continue
                seen_t.add(t.id)
                trans.append(t)
                nxt += sorted(t.targets, key=lambda d: where(d)[1::-1])
            stack += reversed([d for d in nxt if d not in seen])
    trans += sorted((t for t in level.transitions if t.id not in seen_t), key=sibling_key)
    return names, trans


def _constrained(level: Level, rank: dict[int, int]) -> list[GTransition]:
    """The transitions sorted by ``rank`` under the constraint that those leaving one step
    keep their priority order (Kahn's algorithm, the lowest rank first)."""
    by_id = {t.id: t for t in level.transitions}
    after: dict[int, set[int]] = {i: set() for i in by_id}
    pending = dict.fromkeys(by_id, 0)
    groups: dict[str, list[GTransition]] = {}
    for t in sorted(level.transitions, key=sibling_key):
        for s in t.sources:
            groups.setdefault(s, []).append(t)
    for group in groups.values():
        for a, b in zip(group, group[1:], strict=False):
            if b.id not in after[a.id]:
                after[a.id].add(b.id)
                pending[b.id] += 1
    heap = [(rank[i], i) for i, n in pending.items() if n == 0]
    heapq.heapify(heap)
    out: list[GTransition] = []
    while heap:
        _, i = heapq.heappop(heap)
        out.append(by_id[i])
        for j in after[i]:
            pending[j] -= 1
            if pending[j] == 0:
                heapq.heappush(heap, (rank[j], j))
    return out
