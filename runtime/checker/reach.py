"""Reachable situations of a chart, conditions treated as free (``softplc check``).

The chart is read as a Petri net over its leaf steps. From a situation X, the transitions
*enabled* are those whose source steps are all active (source transitions always are),
minus those whose condition can never be true. Under the firing rule of semantics.md (file
order, a step taken by an earlier firing transition is not available to a later one, the
first true transition of an OR divergence wins), any set F of enabled transitions with
pairwise disjoint sources can fire in one scan (make exactly their conditions true), giving
``(X - sources(F)) | targets(F)``.

Firing one transition at a time is enough to find every reachable step, every unsafe
evolution and every reachable situation up to the first unsafe one: fired in an order where
a transition whose target feeds another's source comes after it, the single firings of F
pass through legal situations and end in F's situation; such an order exists unless the
transitions of F feed each other in a cycle, and then each of them, fired alone, activates
a step that is already active, which is reported. Steps that two transitions of one F
activate at once are checked on pairs. The graph is explored breadth first, so the firing
sequence reported is a shortest one.

Unsafe evolutions (seed-000 rule I.3) are recorded on the way: a step activated while
already active (and not deactivated by the same evolution), a step activated by two
transitions at once, two steps of one simple sequence active together. Re-activating
the target of a *source* transition is not reported: a source transition is always enabled,
activating an active step is what it does while its condition holds.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from runtime.language.model import Grafcet, Transition

LIMIT = 100_000
FULL_FIRST = 10_000  # situations explored in full before the reduced exploration is tried
UNSAFE_REPORTS = 5  # root causes reported per chart


@dataclass
class Unsafe:
    kind: str  # "active" | "twice" | "sequence"
    steps: tuple[str, ...]
    before: int  # situation before the evolution (mask)
    fired: tuple[int, ...]  # transitions (positions in Reach.trans)


@dataclass
class Reach:
    g: Grafcet
    steps: list[str]
    trans: list[Transition]
    initial: int
    parent: dict[int, tuple[int, tuple[int, ...]] | None] = field(default_factory=dict)
    dead: list[int] = field(default_factory=list)
    back_to_initial: bool = False  # the initial situation has a predecessor
    complete: bool = True
    why_incomplete: str = ""
    tested: int = 0  # (situation, transition) pairs tested for being enabled (a work count)
    reduced: bool = False  # explored with the reduction of explore(reduce=True)
    unsafe: list[Unsafe] = field(default_factory=list)
    groups: list[int] = field(default_factory=list)  # masks of simple sequences

    def names(self, mask: int) -> list[str]:
        return [s for i, s in enumerate(self.steps) if mask >> i & 1]

    def situation(self, mask: int) -> str:
        return "{" + ", ".join(self.names(mask)) + "}"

    def label(self, k: int) -> str:
        t = self.trans[k]
        src = ",".join(t.sources) or "(source)"
        dst = ",".join(t.targets) or "(sink)"
        name = f"{t.name} " if t.name else ""
        return f"{name}{src}→{dst} (line {t.loc.line})"

    def path(self, mask: int) -> list[tuple[int, tuple[int, ...]]]:
        """Firing sequence from the initial situation: [(situation before, fired)]."""
        out = []
        cur = mask
        while True:
            p = self.parent.get(cur)
            if p is None:
                break
            out.append(p)
            cur = p[0]
        out.reverse()
        return out

    def sequence(self, mask: int, last: tuple[int, ...] | None = None) -> str:
        """``{gsA} -[gsA→gsB (line 9)]-> {gsB} ...`` down to ``mask`` (then ``last``)."""
        steps = self.path(mask)
        parts = [self.situation(self.initial)]
        cur = self.initial
        for before, fired in steps:
            cur = self.successor(before, fired)
            parts.append(f"-[{' + '.join(self.label(k) for k in fired)}]->")
            parts.append(self.situation(cur))
        if last is not None:
            parts.append(f"-[{' + '.join(self.label(k) for k in last)}]->")
            parts.append(self.situation(self.successor(mask, last)))
        return " ".join(parts)

    def successor(self, mask: int, fired: tuple[int, ...]) -> int:
        src = dst = 0
        for k in fired:
            src |= self._src[k]
            dst |= self._dst[k]
        return (mask & ~src) | dst

    # filled by explore()
    _src: list[int] = field(default_factory=list)
    _dst: list[int] = field(default_factory=list)

    @property
    def reachable_steps(self) -> set[str]:
        m = 0
        for x in self.parent:
            m |= x
        return set(self.names(m))


def simple_sequences(g: Grafcet, index: dict[str, int]) -> list[int]:
    """Masks of the simple sequences: steps chained by simple links (a step with one
    outgoing transition, to one step with one incoming transition). At most one step of a
    simple sequence may be active (seed-000 rule I.3)."""
    parent = list(range(len(index)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    outs: dict[str, int] = {}
    ins: dict[str, int] = {}
    for t in g.transitions:
        for s in set(t.src_steps):
            outs[s] = outs.get(s, 0) + 1
        for s in set(t.dst_steps):
            ins[s] = ins.get(s, 0) + 1
    for t in g.transitions:
        # a simple link: one step, one transition, one step (no divergence, no convergence)
        if len(t.src_steps) == 1 and len(t.dst_steps) == 1 and outs[t.src_steps[0]] == 1 and (
                ins[t.dst_steps[0]] == 1):
            a, b = find(index[t.src_steps[0]]), find(index[t.dst_steps[0]])
            if a != b:
                parent[a] = b
    groups: dict[int, int] = {}
    for i in range(len(index)):
        groups[find(i)] = groups.get(find(i), 0) | (1 << i)
    return [m for m in groups.values() if m & (m - 1)]


def reachable(g: Grafcet, never: set[int] | None = None, limit: int = LIMIT) -> Reach:
    """The exploration ``softplc check`` reports on: in full (every interleaving, shortest
    sequences) when the chart has at most ``FULL_FIRST`` situations; beyond, the reduced
    exploration when it completes within ``limit``; else the full one cut at ``limit``."""
    r = explore(g, never, min(limit, FULL_FIRST))
    if r.complete:
        return r
    red = explore(g, never, limit, reduce=True)
    if red.complete or limit <= FULL_FIRST:
        return red if red.complete else r
    return explore(g, never, limit)


def explore(g: Grafcet, never: set[int] | None = None, limit: int = LIMIT,
            reduce: bool = False) -> Reach:
    """Breadth-first exploration of the reachable situations (at most ``limit``).

    ``reduce``: where an enabled transition is a link inside a simple sequence (one source
    step that no other transition leaves, one target step that no other transition enters,
    not active), fire it alone: it stays enabled whatever else fires and commutes with
    every other firing, so the other orders reach nothing more (steps, deadlocks, unsafe
    evolutions: a step activated again while its sequence moved on is two steps of one
    simple sequence active together). Parallel branches then advance one at a time, not
    in every interleaving. Not when the next situation was already seen (a branch looping
    alone would starve the others): all the enabled transitions then fire."""
    steps = [s.name for s in g.leaf_steps()]
    index = {s: i for i, s in enumerate(steps)}
    trans = list(g.transitions)
    never = never or set()
    src = [sum(1 << index[s] for s in set(t.src_steps)) for t in trans]
    dst = [sum(1 << index[s] for s in set(t.dst_steps)) for t in trans]
    initial = sum(1 << index[s.name] for s in g.leaf_steps() if s.initial)
    r = Reach(g, steps, trans, initial)
    r._src, r._dst = src, dst
    r.groups = simple_sequences(g, index)
    r.parent[initial] = None
    reported: set[tuple[str, tuple[str, ...]]] = set()
    # situations reached through an unsafe evolution: what follows is a consequence, not
    # reported again
    tainted: set[int] = set()
    bad = False
    depth = {initial: 0}

    def record(kind: str, names: tuple[str, ...], before: int, fired: tuple[int, ...]) -> None:
        nonlocal bad
        bad = True
        key = (kind if kind != "twice" else "active", names)
        if key in reported or before in tainted or len(r.unsafe) >= UNSAFE_REPORTS:
            return
        if r.unsafe and depth[before] > depth[r.unsafe[0].before]:
            return  # a later evolution: most likely a consequence of the first one
        reported.add(key)
        r.unsafe.append(Unsafe(kind, names, before, fired))

    group_of = [0] * len(steps)
    for gm in r.groups:
        for i in active(gm):
            group_of[i] = gm

    def group_check(mask: int, before: int, fired: tuple[int, ...]) -> None:
        for gm in sorted({group_of[i] for i in active(mask) if group_of[i]},
                         key=r.groups.index):
            both = mask & gm
            if both & (both - 1):
                names = tuple(r.names(both))
                if not any(("active", (n,)) in reported for n in names):
                    record("sequence", names, before, fired)

    group_check(initial, initial, ())
    queue = deque([initial])
    outs_n: dict[int, int] = {}
    ins_n: dict[int, int] = {}
    for k in range(len(trans)):
        for i in active(src[k]):
            outs_n[i] = outs_n.get(i, 0) + 1
        for i in active(dst[k]):
            ins_n[i] = ins_n.get(i, 0) + 1
    # links inside simple sequences: one source step left only by it, one target step
    # entered only by it
    simple = [k not in never and len(active(src[k])) == 1 and len(active(dst[k])) == 1
              and src[k] != dst[k] and outs_n[active(src[k])[0]] == 1
              and ins_n[active(dst[k])[0]] == 1 for k in range(len(trans))]
    r.reduced = reduce
    # the transitions that may fire, by source step (source transitions: always enabled)
    always = [k for k in range(len(trans)) if k not in never and not src[k]]
    leaving: list[list[int]] = [[] for _ in steps]
    for k in range(len(trans)):
        if k not in never:
            for s in set(trans[k].src_steps):
                leaving[index[s]].append(k)
    while queue:
        x = queue.popleft()
        candidates = set(always)
        for i in active(x):
            candidates.update(leaving[i])
        r.tested += len(candidates)
        enabled = [k for k in sorted(candidates) if src[k] & x == src[k]]
        if not enabled:
            r.dead.append(x)
            continue
        # two transitions that can fire together and activate the same step
        seen = 0
        for k in enabled:
            if dst[k] & seen and src[k]:
                for k2 in enabled:
                    if k2 == k:
                        break
                    both = dst[k] & dst[k2] & ~x
                    if both and src[k2] and not src[k] & src[k2]:
                        for n in r.names(both):
                            record("twice", (n,), x, (k2, k))
            seen |= dst[k]
        if reduce:
            alone = next((k for k in enabled if simple[k] and not dst[k] & x
                          and (x & ~src[k]) | dst[k] not in r.parent), None)
            if alone is not None:
                enabled = [alone]
        # one transition at a time is enough (see the module's docstring)
        for k in enabled:
            bad = x in tainted
            again = dst[k] & x & ~src[k]
            if again and src[k]:
                for n in r.names(again):
                    record("active", (n,), x, (k,))
            y = (x & ~src[k]) | dst[k]
            if y == initial:
                r.back_to_initial = True
            if y not in r.parent:
                r.parent[y] = (x, (k,))
                depth[y] = depth[x] + 1
                group_check(y, x, (k,))
                if bad:
                    tainted.add(y)
                if len(r.parent) >= limit:
                    r.complete = False
                    r.why_incomplete = f"more than {limit} reachable situations"
                    return r
                queue.append(y)
    return r


def structural_reach(g: Grafcet, never: set[int] | None = None) -> set[str]:
    """Steps reachable when AND convergences need their sources only *some* time (an
    over-approximation of the reachable steps, used when the exploration is cut)."""
    never = never or set()
    reach = {s.name for s in g.leaf_steps() if s.initial}
    missing: dict[int, int] = {}  # transition -> its source steps not reached yet
    waiting: dict[str, list[int]] = {}  # step -> the transitions it is missing for
    todo: list[int] = []
    for k, t in enumerate(g.transitions):
        if k in never:
            continue
        srcs = set(t.src_steps) - reach
        missing[k] = len(srcs)
        for s in srcs:
            waiting.setdefault(s, []).append(k)
        if not srcs:
            todo.append(k)
    while todo:
        for d in g.transitions[todo.pop()].dst_steps:
            if d not in reach:
                reach.add(d)
                for j in waiting.get(d, []):
                    missing[j] -= 1
                    if not missing[j]:
                        todo.append(j)
    return reach


def active(mask: int) -> list[int]:
    """Indexes of the bits set in ``mask``."""
    out = []
    while mask:
        low = mask & -mask
        out.append(low.bit_length() - 1)
        mask ^= low
    return out
