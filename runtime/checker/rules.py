"""Seed 000's rules on one loaded chart: the G102-G104 errors and the G2xx warnings.

G102 unreachable step, G103 a transition back to its own source step, G104 unsafe chart;
G201 OR divergence not exclusive, G202 action that never executes, G203 divergence not
closed, G204 same level condition on consecutive transitions, G205 counting statement in a
continuous action, G206 deadlock, G207 bool promoted to a number in a comparison, G208
transition that never fires, G209 analysis cut by its bounds, G210 a stored action that
nothing resets, G211 a timer read stale under ``scan: stable`` (these two in
runtime/checker/traps.py; docs/check.md). The rules that the loader enforces itself (G101,
G105, G106) are the loader's diagnostics, printed by runtime/checker/check.py. Positions
inside a condition or an action come from the model (``Transition.at``, ``Action.at``,
``Statement.at``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Any

from drivers.durations import format_ns
from runtime.checker.diag import Diag, diag
from runtime.checker.logic import Logic, has_edge
from runtime.checker.reach import LIMIT, Reach, Unsafe, reachable, structural_reach
from runtime.checker.traps import latched_targets, stale_timer_reads
from runtime.errors import Loc
from runtime.language import ast as A
from runtime.language.model import Grafcet, Qualifier, Step, Transition
from runtime.language.unparse import ARITH, COMPARE, unparse

T = A.Type
#: pairs of transitions G201 decides (``or_exclusive``): PAIRS_AT_LEAST, and
#: PAIRS_PER_TRANSITION more per transition of the chart
PAIRS_AT_LEAST = 256
PAIRS_PER_TRANSITION = 4


# -- the checks of one chart --------------------------------------------------------------
class ChartChecker:
    def __init__(self, g: Grafcet, limit: int = LIMIT, repaired: Iterable[str] = ()) -> None:
        self.g = g
        self.limit = limit
        self.repaired = set(repaired)
        self.out: list[Diag] = []
        self.logic = Logic(g)
        self.never: set[int] = set()
        self.reach: Reach | None = None
        self.visits = 0  # transitions followed by G203's searches (a work count)
        # indexes built once: the transitions leaving / entering each step, in file order
        self._out: dict[str, list[int]] = {}
        self._in: dict[str, list[int]] = {}
        for k, t in enumerate(g.transitions):
            for s in dict.fromkeys(t.src_steps):
                self._out.setdefault(s, []).append(k)
            for s in dict.fromkeys([*t.dst_steps, *t.targets]):
                self._in.setdefault(s, []).append(k)

    def add(self, loc: Loc, severity: str, code: str, message: str) -> None:
        self.out.append(diag(loc, severity, code, message))

    def run(self) -> list[Diag]:
        self.self_loops()
        self.dead_transitions()
        if "G101" not in self.repaired:
            self.reachability()
        self.or_exclusive()
        self.useless_actions()
        self.unclosed()
        self.same_condition()
        self.counting()
        self.promotions()
        self.out += latched_targets(self.g)
        self.out += stale_timer_reads(self.g, self.logic.defs)
        return self.out

    # -- helpers ------------------------------------------------------------------------
    def tname(self, t: Transition) -> str:
        src = ", ".join(t.sources) or "(source)"
        dst = ", ".join(t.targets) or "(sink)"
        return f"{t.name + ' ' if t.name else ''}{src} → {dst}"

    def outgoing(self, step: str) -> list[int]:
        """Indexes of the transitions leaving ``step`` (one of their source steps), in file
        order."""
        return self._out.get(step, [])

    # -- G103 ---------------------------------------------------------------------------
    def self_loops(self) -> None:
        for t in self.g.transitions:
            same = [s for s in t.sources if s in t.targets] or [
                s for s in t.src_steps if s in t.dst_steps]
            if same:
                self.add(t.loc, "error", "G103", f"transition {self.tname(t)} leads from step "
                         f"'{same[0]}' back to itself: the previous and the next step must "
                         "differ (seed-000 rule I.8); add a step, or keep the step active and "
                         "drive the action with a condition instead")

    # -- G208 ---------------------------------------------------------------------------
    def dead_transitions(self) -> None:
        for k, t in enumerate(self.g.transitions):
            r = self.logic.solve([(t.cond, True)], t.src_steps)
            if r.sat is False:
                self.never.add(k)
                self.add(t.loc, "warning", "G208", f"the condition '{t.text}' of transition "
                         f"{self.tname(t)} can never be true: the transition never fires")

    # -- G102 G104 G206 G209 --------------------------------------------------------------
    def reachability(self) -> None:
        g = self.g
        r = self.reach = reachable(g, self.never, self.limit)
        if r.complete:
            reached = r.reachable_steps
        else:
            reached = structural_reach(g, self.never)
            self.add(g.loc, "warning", "G209", f"exploration of the reachable situations "
                     f"stopped ({r.why_incomplete}; raise it with --limit): only the "
                     "situations explored were checked for unsafe evolutions (G104), "
                     "deadlocks (G206) are not decided, unreachable steps (G102) are checked "
                     "on the links only")
        structural = structural_reach(g, self.never)
        unreachable = [s for s in g.leaf_steps() if s.name not in reached]
        reported_macros: set[str] = set()
        for s in unreachable:
            top = self._outermost_unreachable_macro(s, reached)
            if top is not None:
                if top.name not in reported_macros:
                    reported_macros.add(top.name)
                    self.add(top.loc, "error", "G102", f"macro-step '{top.name}' can never "
                             f"become active{self._why_unreachable(top.name, structural)} "
                             "(seed-000 rule I.4)")
                continue
            self.add(s.loc, "error", "G102", f"step '{s.name}' can never become active"
                     f"{self._why_unreachable(s.name, structural)} (seed-000 rule I.4)")
        for u in r.unsafe:
            self._unsafe(r, u)
        if r.complete and r.reduced and r.dead and not r.back_to_initial:
            self.add(g.loc, "note", "G212", f"the reduced exploration ({len(r.parent)} "
                     f"situations) found {len(r.dead)} situation(s) where no transition can "
                     f"fire, e.g. {r.situation(r.dead[0])}, but did not see the chart come "
                     "back to its initial situation: whether that is a deadlock (G206) is "
                     "not decided; raise --limit above the number of situations to explore "
                     "them all")
        if r.complete and r.back_to_initial:
            for dead in r.dead[:3]:
                path = r.path(dead)
                loc = g.transitions[path[-1][1][-1]].loc if path else g.loc
                self.add(loc, "warning", "G206", f"deadlock: in the situation "
                         f"{r.situation(dead)} no transition can ever fire, while the chart "
                         f"otherwise cycles back to its initial situation; reached by "
                         f"{r.sequence(dead)}")

    def _outermost_unreachable_macro(self, s: Step, reached: set[str]) -> Step | None:
        best = None
        parent = s.parent
        while parent is not None:
            m = self.g.steps[parent]
            assert m.macro is not None
            inner = [n for n in m.macro.steps if self.g.steps[n].macro is None]
            if all(n not in reached for n in inner):
                best = m
            parent = m.parent
        return best

    def _why_unreachable(self, name: str, structural: set[str]) -> str:
        g = self.g
        st = g.steps[name]
        targets = {name}
        if st.macro is not None:
            targets.add(st.macro.entry)
            e = g.steps[st.macro.entry]
            while e.macro is not None:
                targets.add(e.macro.entry)
                e = g.steps[e.macro.entry]
        incoming = [(k, g.transitions[k]) for k in sorted(
            {k for n in targets for k in self._in.get(n, [])})]
        if not incoming:
            return ": no transition leads to it"
        lines = ", ".join(str(t.loc.line) for _, t in incoming)
        if all(k in self.never for k, _ in incoming):
            return f": the transitions leading to it (line {lines}) never fire"
        leaf = targets - {n for n in targets if g.steps[n].macro is not None}
        if leaf & structural:
            return (f": the transitions leading to it (line {lines}) need source steps that "
                    "are never active together")
        return f": no reachable step leads to it (transitions at line {lines})"

    def _unsafe(self, r: Reach, u: Unsafe) -> None:
        g = self.g
        if not u.fired:
            st = g.steps[u.steps[-1]]
            self.add(st.loc, "error", "G104", f"unsafe chart: the initial steps "
                     f"{', '.join(u.steps)} belong to one simple sequence, where at most one "
                     "step may be active (seed-000 rule I.3)")
            return
        culprit = next((k for k in u.fired if set(g.transitions[k].dst_steps) & set(u.steps)),
                       u.fired[-1])
        loc = g.transitions[culprit].loc
        seq = r.sequence(u.before, u.fired)
        if u.kind == "active":
            msg = (f"unsafe chart: step '{u.steps[0]}' is activated while it is already "
                   f"active, by {seq}")
        elif u.kind == "twice":
            msg = (f"unsafe chart: step '{u.steps[0]}' is activated by two transitions at "
                   f"once (an OR convergence fed by parallel branches?), by {seq}")
        else:
            msg = (f"unsafe chart: steps {', '.join(repr(s) for s in u.steps)} of one simple "
                   f"sequence are active together, after {seq}")
        self.add(loc, "error", "G104", msg + " (seed-000 rule I.3; conditions taken as free)")

    # -- G201 ---------------------------------------------------------------------------
    def or_exclusive(self) -> None:
        """Each pair of transitions leaving one step: exclusive, or a witness of both
        true. A transition on the same condition (as written) as an earlier one of the
        divergence is paired with that first one only; the other pairs are decided up to
        PAIRS_AT_LEAST + PAIRS_PER_TRANSITION per transition of the chart, so the rule's
        work grows with the chart, not with the square of a divergence's branches (a note
        says when a divergence is not decided whole)."""
        g = self.g
        seen: set[tuple[int, int]] = set()
        budget = PAIRS_AT_LEAST + PAIRS_PER_TRANSITION * len(g.transitions)
        for s in g.leaf_steps():
            outs = [k for k in self.outgoing(s.name) if k not in self.never]
            first: dict[str, int] = {}
            distinct = []
            for k in outs:
                a = first.setdefault(unparse(g.transitions[k].cond), k)
                if a == k:
                    distinct.append(k)
                elif (a, k) not in seen:
                    seen.add((a, k))
                    self._exclusive(s, a, k)
            pairs = len(distinct) * (len(distinct) - 1) // 2
            decided = 0
            for i, a in enumerate(distinct):
                if budget <= 0:
                    break
                for b in distinct[i + 1:]:
                    if budget <= 0:
                        break
                    decided += 1
                    if (a, b) in seen:
                        continue
                    seen.add((a, b))
                    budget -= 1
                    self._exclusive(s, a, b)
            if decided < pairs:
                self.add(g.transitions[distinct[0]].loc, "note", "G201", f"OR divergence "
                         f"after step '{s.name}' ({len(outs)} transitions): exclusivity "
                         f"decided for {decided} of its {pairs} pairs of distinct conditions "
                         f"(the bound: {PAIRS_AT_LEAST} pairs and {PAIRS_PER_TRANSITION} per "
                         "transition of the chart)")

    def _exclusive(self, s: Step, a: int, b: int) -> None:
        """G201 for transitions ``a`` and ``b`` (file order) leaving step ``s``."""
        ta, tb = self.g.transitions[a], self.g.transitions[b]
        steps = set(ta.src_steps) | set(tb.src_steps)
        r = self.logic.solve([(ta.cond, True), (tb.cond, True)], steps)
        pair = (f"transitions {self.tname(ta)} (line {ta.loc.line}) and "
                f"{self.tname(tb)} (line {tb.loc.line})")
        if r.sat:
            self.add(tb.loc, "warning", "G201", f"OR divergence after step "
                     f"'{s.name}' is not exclusive: {pair} are both true with "
                     f"{r.show()} ('{ta.text}' and '{tb.text}'); the first in "
                     "file order wins: make the conditions mutually exclusive "
                     "(seed-000 rule II.1)")
        elif r.sat is None:
            self.add(tb.loc, "note", "G201", f"could not decide whether {pair} "
                     f"are exclusive: {r.atoms} atoms, no witness found by a "
                     "bounded search")

    # -- G202 ---------------------------------------------------------------------------
    def useless_actions(self) -> None:
        g = self.g
        unreachable: set[str] = set()
        if self.reach is not None and self.reach.complete:
            unreachable = set(self.reach.steps) - self.reach.reachable_steps
        for s in g.leaf_steps():
            if s.name in unreachable:
                continue
            for a in s.actions:
                why = self._never_executes(s, a)
                if why:
                    self.add(a.loc, "warning", "G202", f"action '{a.text}' of step "
                             f"'{s.name}' can never execute: {why} (seed-000 rule II.2)")

    def _never_executes(self, s: Step, a: Any) -> str | None:
        q = a.qualifier
        if q in (Qualifier.L, Qualifier.SL) and a.time_ns == 0:
            return f"{q.value} 0 limits it to no time at all"
        if a.cond is not None:
            r = self.logic.solve([(a.cond, True)], [s.name])
            if r.sat is False:
                return "its condition is never true"
        if a.event is not None:
            r = self.logic.solve([(a.event, True)], [s.name])
            if r.sat is False:
                return "its event never happens"
        if q in (Qualifier.D, Qualifier.DS) and a.time_ns is not None:
            d = a.time_ns
            if s.max_ns is not None and d >= s.max_ns:
                return (f"the delay {format_ns(d)} is not shorter than the step's max time "
                        f"{format_ns(s.max_ns)}")
            outs = [self.g.transitions[k] for k in self.outgoing(s.name)
                    if self.g.transitions[k].src_steps == [s.name] and k not in self.never]
            if outs:
                flag = A.StepFlag(0, 0, s.name, "T")
                flag.type = T.TIME
                lit = A.Lit(0, 0, d, T.TIME)
                lit.type = T.TIME
                ge = A.Binary(0, 0, "GE", flag, lit, ">=")
                ge.type = T.BOOL
                conds = [(ge, True)] + [(t.cond, False) for t in outs]
                r = self.logic.solve(conds, [s.name])
                if r.sat is False:
                    lines = ", ".join(str(t.loc.line) for t in outs)
                    return (f"the step is always left (transition at line {lines}) before "
                            f"the delay {format_ns(d)} has elapsed")
        return None

    # -- G203 ---------------------------------------------------------------------------
    def unclosed(self) -> None:
        """G203. An OR divergence after step S is closed when some step with two or more
        incoming transitions can be reached from every branch (not passing S); an AND
        divergence T is closed when some other AND convergence has a source step reached
        by every branch (not firing T again). Every branch of every divergence is searched
        at once: each step carries a bit set (a Python int), one bit per branch, and the
        bits flow along the transitions (not out of S for S's bits, not along T for T's)
        until nothing changes. The passes follow the links in depth-first order, so a chart
        settles in a few passes (one more per nesting of loops), each reading every
        transition once: linear in the chart for a bounded nesting, where searching each
        divergence alone walked the whole chart for each loop back."""
        g = self.g
        incoming: dict[str, int] = {}
        for t in g.transitions:
            for d in set(t.dst_steps):
                incoming[d] = incoming.get(d, 0) + 1
        ors: list[tuple[Step, list[int]]] = []
        for st in g.leaf_steps():
            outs = [k for k in self.outgoing(st.name) if k not in self.never
                    and st.name not in g.transitions[k].dst_steps]
            if len(outs) >= 2:
                ors.append((st, outs))
        ands = [k for k, t in enumerate(g.transitions) if len(set(t.dst_steps)) >= 2]
        if not ors and not ands:
            return
        width = max([len(o) for _, o in ors] + [len(g.transitions[k].dst_steps) for k in ands])
        blocks = len(ors) + len(ands)  # block i: bits i*width .. i*width + width - 1
        fill = 0  # the bits of the slots a divergence with fewer branches leaves unused
        marks: dict[str, int] = {}
        stop_at: dict[str, int] = {}  # OR divergence S: its bits do not leave S
        stop_on: dict[int, int] = {}  # AND divergence T: its bits do not pass T
        block_mask = (1 << width) - 1
        for i, (st, outs) in enumerate(ors):
            base = i * width
            fill |= (block_mask >> len(outs) << len(outs)) << base
            stop_at[st.name] = stop_at.get(st.name, 0) | block_mask << base
            for b, k in enumerate(outs):
                for d in g.transitions[k].dst_steps:
                    marks[d] = marks.get(d, 0) | 1 << (base + b)
        for i, k in enumerate(ands, len(ors)):
            base = i * width
            dst = g.transitions[k].dst_steps
            fill |= (block_mask >> len(dst) << len(dst)) << base
            stop_on[k] = block_mask << base
            for b, d in enumerate(dst):
                marks[d] = marks.get(d, 0) | 1 << (base + b)
        self._flow(marks, stop_at, stop_on)
        starts = sum(1 << (i * width) for i in range(blocks))

        def complete(x: int) -> int:
            """The first bit of each block whose bits are all set in ``x`` (or unused)."""
            x |= fill
            y = x
            for j in range(1, width):
                y &= x >> j
            return y & starts

        met = 0
        for n, c in incoming.items():
            if c >= 2:
                met |= complete(marks.get(n, 0))
        for i, (st, outs) in enumerate(ors):
            if not met >> (i * width) & 1:
                lines = ", ".join(str(g.transitions[k].loc.line) for k in outs)
                self.add(st.loc, "warning", "G203", f"OR divergence after step '{st.name}' "
                         f"(transitions at line {lines}) is not closed by an OR convergence: "
                         "its branches never meet again (seed 000 recommends closing every "
                         "OR divergence with an OR convergence)")
        synced = 0
        for j, u in enumerate(g.transitions):
            if len(set(u.src_steps)) < 2:
                continue
            x = 0
            for n in set(u.src_steps):
                x |= marks.get(n, 0)
            synced |= complete(x) & ~stop_on.get(j, 0)  # another convergence than T itself
        for i, k in enumerate(ands, len(ors)):
            if not synced >> (i * width) & 1:
                t = g.transitions[k]
                self.add(t.loc, "warning", "G203", f"AND divergence {self.tname(t)} is not "
                         "closed by an AND convergence: its parallel branches never "
                         "synchronise again (seed 000 recommends closing every AND "
                         "divergence with an AND convergence)")

    def _flow(self, marks: dict[str, int], stop_at: dict[str, int],
              stop_on: dict[int, int]) -> None:
        """Let the bits of ``marks`` flow forward along the transitions until nothing
        changes (``stop_at``: bits that do not leave a step, ``stop_on``: bits a
        transition does not carry)."""
        g = self.g
        order: list[str] = []  # reverse postorder of a depth-first search over the steps
        seen: set[str] = set()
        names = [*marks, *g.steps]
        for root in names:
            if root in seen:
                continue
            seen.add(root)
            none: list[str] = []
            stack: list[tuple[str, Iterator[int], Iterator[str]]] = [
                (root, iter(self._out.get(root, [])), iter(none))]
            while stack:
                n, ks, ds = stack[-1]
                d = next(ds, None)
                if d is None:
                    k = next(ks, None)
                    if k is None:
                        order.append(n)
                        stack.pop()
                        continue
                    stack[-1] = (n, ks, iter(g.transitions[k].dst_steps))
                    continue
                if d not in seen:
                    seen.add(d)
                    stack.append((d, iter(self._out.get(d, [])), iter(none)))
        order.reverse()
        changed = True
        while changed:
            changed = False
            for n in order:
                m = marks.get(n, 0) & ~stop_at.get(n, 0)
                if not m:
                    continue
                for k in self._out.get(n, []):
                    self.visits += 1
                    carried = m & ~stop_on.get(k, 0)
                    for d in g.transitions[k].dst_steps:
                        old = marks.get(d, 0)
                        if carried & ~old:
                            marks[d] = old | carried
                            changed = True

    # -- G204 ---------------------------------------------------------------------------
    def same_condition(self) -> None:
        """A transition and, for each of its target steps, the first transition leaving
        that step on the same level condition: looked up by condition, so a step entered
        and left by n transitions each costs n lookups and at most n warnings, not n²."""
        g = self.g
        keys = [unparse(t.cond) for t in g.transitions]
        leaving: dict[str, dict[str, list[int]]] = {}
        for step, outs in self._out.items():
            by_key = leaving[step] = {}
            for j in outs:
                by_key.setdefault(keys[j], []).append(j)
        for i, a in enumerate(g.transitions):
            if has_edge(a.cond) or self.logic.const(a.cond) is not None or isinstance(
                    a.cond, A.Lit):
                continue
            following = sorted({next((j for j in leaving.get(d, {}).get(keys[i], [])[:2]
                                      if j != i), i) for d in a.dst_steps} - {i})
            for j in following:
                b = g.transitions[j]
                mid = sorted(set(a.dst_steps) & set(b.src_steps))[0]
                self.add(b.loc, "warning", "G204", f"transitions {self.tname(a)} (line "
                         f"{a.loc.line}) and {self.tname(b)} have the same level "
                         f"condition '{b.text}': while it holds, step '{mid}' is passed "
                         "through at once; probably needs an edge (↑) (seed 000)")

    # -- G205 ---------------------------------------------------------------------------
    def counting(self) -> None:
        for a in self.g.actions():
            if a.body is None or a.qualifier not in (Qualifier.N, Qualifier.L, Qualifier.D):
                continue
            for stmt, guarded in _statements(a.body, False):
                if guarded or not isinstance(stmt, A.Assign):
                    continue
                name = stmt.target.name
                if _counts(stmt.value, name):
                    loc = a.at(stmt.start)
                    self.add(loc, "warning", "G205", f"counting statement "
                             f"'{a.text[stmt.start:stmt.end]}' in a continuous "
                             f"({a.qualifier.value}) action of step '{a.step}' runs in "
                             "every scan while the step is active, not once: use P1 (on "
                             f"activation), or count an edge ('{name} := {name} + ↑x') "
                             "(seed 000)")

    # -- G207 ---------------------------------------------------------------------------
    def promotions(self) -> None:
        g = self.g
        for t in g.transitions:
            self._promotions([t.cond], t.text, 0, t.at)
        for a in g.actions():
            roots = [x for x in (a.cond, a.event) if x is not None] + list(a.body or [])
            self._promotions(roots, a.text, 0, a.at)
        for st in [*g.pre, *g.post]:
            self._promotions([st.node], st.text, st.node.start, st.at)

    def _promotions(self, roots: list[A.Node], text: str, base: int,
                    locate: Callable[[int], Loc]) -> None:
        def src(n: A.Node) -> str:
            return text[n.start - base:n.end - base]

        def parenthesised(n: A.Node) -> bool:
            return src(n).startswith("(")

        def bools(n: A.Node) -> Iterator[A.Node]:
            assert isinstance(n, A.Binary)
            for c in (n.left, n.right):
                if c.type is T.BOOL and not (isinstance(c, A.Lit)):
                    yield c
                elif isinstance(c, A.Binary) and c.op in ARITH and not parenthesised(c):
                    yield from bools(c)

        for root in roots:
            for n in A.walk(root):
                if not (isinstance(n, A.Binary) and n.op in COMPARE):
                    continue
                for side in (n.left, n.right):
                    if not (isinstance(side, A.Binary) and side.op in ARITH) or (
                            parenthesised(side)):
                        continue
                    for b in bools(side):
                        self.add(locate(b.start), "warning", "G207", f"bool '{src(b)}' is "
                                 f"promoted to a number in '{src(n)}': a comparison binds "
                                 f"looser than '{side.text or ARITH[side.op].strip()}', so "
                                 f"this reads '({src(side)}) {n.text or COMPARE[n.op]} "
                                 f"{src(n.right if side is n.left else n.left)}'; add "
                                 "parentheses around the comparison if that was not meant, "
                                 "or around the sum if it was")
                        break



def _statements(body: list[A.Node], guarded: bool) -> Iterator[tuple[A.Node, bool]]:
    """Every statement in ``body``, with whether an edge guards it (IF ↑x THEN ...)."""
    for s in body:
        yield s, guarded
        if isinstance(s, A.If):
            g2 = guarded
            for cond, inner in s.branches:
                g2 = g2 or has_edge(cond)
                yield from _statements(inner, g2)
            yield from _statements(s.orelse, g2)
        elif isinstance(s, A.Case):
            for _, inner in s.arms:
                yield from _statements(inner, guarded)
            yield from _statements(s.orelse, guarded)
        elif isinstance(s, A.For):
            yield from _statements(s.body, guarded)


def _counts(value: A.Node, name: str) -> bool:
    """``name + ...`` / ``... - name``: a sum holding ``name`` itself, with no edge."""
    if not (isinstance(value, A.Binary) and value.op in ("ADD", "SUB")):
        return False
    if has_edge(value):
        return False

    def terms(n: A.Node) -> Iterator[A.Node]:
        if isinstance(n, A.Binary) and n.op in ("ADD", "SUB"):
            yield from terms(n.left)
            yield from terms(n.right)
        else:
            yield n

    return any(isinstance(x, A.Name) and x.name == name for x in terms(value))


def check_grafcet(g: Grafcet, limit: int = LIMIT, repaired: Iterable[str] = ()) -> list[Diag]:
    """Every diagnostic of one loaded chart."""
    return ChartChecker(g, limit, repaired).run()
