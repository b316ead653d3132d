"""``softplc check FILE...``: static checks of seed 000's rules on grafcet and plant files.

Diagnostics are one line each, ``FILE:LINE:COL: error|warning|note GCODE: message``
(docs/check.md lists every code with an example and its fix). Exit status: 2 if a file does
not load (its error line is printed), else 1 if any error was found, else 0.

Errors (seed 000, "Reglas de sintaxis y ejecución (I)"):
G101 no initial step, G102 unreachable step, G103 a transition back to its own source step,
G104 unsafe chart, G105 continuous action on activation/deactivation/event, G106 edge in the
condition of a conditional action. Warnings (rules II and the recommendations): G201 OR
divergence not exclusive, G202 action that never executes, G203 divergence not closed,
G204 same level condition on consecutive transitions, G205 counting statement in a
continuous action, G206 deadlock, G207 bool promoted to a number in a comparison, G208
transition that never fires, G209 analysis cut by its bounds. Plant files: G300 (note)
plant not checked further because a chart of it breaks a rule above, G301 unbound
signal, G302 physical output bound twice, G303 driver point that does not exist (or wrong
direction or type), G304 bad driver configuration, G305 (note) point not checked because the
driver's library is missing.

A simulation script (``duration:``/``cycles:``, ``set:``) is checked against its plant
(``--plant``, or the one plant file of its directory), so that ``softplc check
configs/*/*.yaml`` checks everything: an error in it is a loading error (exit status 2),
and G400 (note) says when no plant could be found for it.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

from runtime import ast as A
from runtime.check_logic import ARITH, COMPARE, Logic, has_edge, unparse
from runtime.check_reach import LIMIT, Reach, Unsafe, explore, structural_reach
from runtime.errors import Loc, SourceError
from runtime.model import Grafcet, PlantDef, Qualifier, Step, Transition
from runtime.parser import format_time
from runtime.yamlsrc import YList, YMap, YStr, load_yaml

T = A.Type
SEVERITY_ORDER = {"error": 0, "warning": 1, "note": 2}


@dataclass(frozen=True, order=True)
class Diag:
    file: str
    line: int
    col: int
    severity: str  # error | warning | note
    code: str
    message: str

    def __str__(self) -> str:
        return f"{_show_path(self.file)}:{self.line}:{self.col}: {self.severity} {self.code}: " \
               f"{self.message}"


def _show_path(path: str) -> str:
    if os.path.isabs(path):
        rel = os.path.relpath(path)
        if not rel.startswith(".."):
            return rel
    return path


def diag(loc: Loc, severity: str, code: str, message: str) -> Diag:
    return Diag(loc.file, loc.line, loc.col, severity, code, message)


# -- where things are in the YAML text ---------------------------------------------------
class Where:
    """Finds the file place of a character inside a condition or a statement."""

    def __init__(self, path: str, doc: Any = None) -> None:
        self.path = path
        self._doc = doc
        self._strings: list[YStr] | None = None
        self._whens: dict[tuple[int, int], Any] | None = None

    def _load(self) -> None:
        if self._strings is not None:
            return
        self._strings, self._whens = [], {}
        try:
            doc = self._doc if self._doc is not None else load_yaml(self.path)
        except SourceError:
            return

        def walk(node: Any) -> None:
            assert self._strings is not None and self._whens is not None
            if isinstance(node, YStr):
                self._strings.append(node)
            elif isinstance(node, YMap):
                if "when" in node:
                    self._whens[(node.loc.line, node.loc.col)] = node["when"]
                for v in node.values():
                    walk(v)
            elif isinstance(node, YList):
                for v in node:
                    walk(v)

        walk(doc)

    def _string_at(self, loc: Loc, offset: int) -> YStr | None:
        self._load()
        assert self._strings is not None
        for s in self._strings:
            if offset < len(s) and s.pos(offset) == Loc(s.loc.file, loc.line, loc.col):
                return s
        return None

    def in_text(self, start: Loc, base: int, offset: int) -> Loc:
        """Place of character ``offset`` of a text whose character ``base`` is at ``start``."""
        s = self._string_at(start, base)
        if s is not None:
            return s.pos(offset)
        return Loc(start.file, start.line, start.col + offset - base)

    def in_condition(self, t: Transition, offset: int) -> Loc:
        self._load()
        assert self._whens is not None
        w = self._whens.get((t.loc.line, t.loc.col))
        if isinstance(w, YStr):
            return w.pos(offset)
        return t.loc


# -- loading, with the loader's rule errors turned into diagnostics -----------------------
def _grafcet_code(exc: SourceError) -> str | None:
    m = exc.message
    if "no initial step" in m:
        return "G101"
    if "rule I.6" in m:
        return "G105"
    if "without edges in a conditional action" in m:
        return "G106"
    return None


def _plant_code(exc: SourceError) -> str | None:
    m = exc.message
    if " unbound" in m and "leaves" in m:
        return "G301"
    if "is bound twice" in m:
        return "G302"
    return None


def _before(a: Loc, b: Loc) -> bool:
    return (a.line, a.col) <= (b.line, b.col)


def _remove_action(node: Any, loc: Loc) -> bool:
    """Delete the action string of the YAML document that contains ``loc``."""
    if isinstance(node, YMap):
        acts = node.get("actions")
        if isinstance(acts, YStr) and _contains(acts, loc):
            node["actions"] = None
            return True
        if isinstance(acts, YList):
            for i, a in enumerate(acts):
                if isinstance(a, YStr) and _contains(a, loc):
                    del acts[i]
                    del acts.locs[i]
                    return True
        return any(_remove_action(v, loc) for v in node.values())
    if isinstance(node, YList):
        return any(_remove_action(v, loc) for v in node)
    return False


def _contains(s: YStr, loc: Loc) -> bool:
    if not s:
        return False
    first, last = s.pos(0), s.pos(len(s) - 1)
    return _before(first, loc) and _before(loc, Loc(loc.file, last.line, last.col + 1))


def _mark_initial(doc: YMap) -> bool:
    steps = doc.get("steps")
    if not isinstance(steps, YMap) or not steps:
        return False
    name = next(iter(steps))
    spec = steps[name]
    if spec is None:
        spec = YMap()
        spec.loc, spec.key_locs, spec.val_locs = steps.key_locs[name], {}, {}
        steps[name] = spec
    if not isinstance(spec, YMap) or spec.get("initial") is True:
        return False
    spec["initial"] = True
    spec.key_locs["initial"] = spec.val_locs["initial"] = spec.loc
    return True


@dataclass
class Loaded:
    g: Grafcet | None
    diags: list[Diag]
    repaired: set[str]  # codes of rule errors found by the loader (the chart was patched)
    failure: SourceError | None = None


def load_grafcet_checked(path: str) -> Loaded:
    """Load a grafcet; a loader error that breaks one of seed 000's rules (G101, G105,
    G106) becomes a diagnostic, the offending part is left out, and loading goes on so
    that every such error is reported and the rest of the checks still run."""
    from runtime.language import GrafcetLoader, load_grafcet

    try:
        return Loaded(load_grafcet(path), [], set())
    except SourceError as exc:
        if _grafcet_code(exc) is None:
            return Loaded(None, [], set(), exc)
    doc = load_yaml(path)
    diags: list[Diag] = []
    codes: set[str] = set()
    for _ in range(500):
        try:
            return Loaded(GrafcetLoader(path, doc).load(), diags, codes)
        except SourceError as exc:
            code = _grafcet_code(exc)
            if code is None:
                return Loaded(None, diags, codes, exc)
            diags.append(diag(exc.loc, "error", code, exc.message))
            codes.add(code)
            ok = _mark_initial(doc) if code == "G101" else _remove_action(doc, exc.loc)
            if not ok:
                return Loaded(None, diags, codes)
    return Loaded(None, diags, codes)


# -- the checks of one chart --------------------------------------------------------------
class ChartChecker:
    def __init__(self, g: Grafcet, limit: int = LIMIT, repaired: Iterable[str] = ()) -> None:
        self.g = g
        self.limit = limit
        self.repaired = set(repaired)
        self.out: list[Diag] = []
        self.logic = Logic(g)
        self.where = Where(g.path)
        self.never: set[int] = set()
        self.reach: Reach | None = None

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
        return self.out

    # -- helpers ------------------------------------------------------------------------
    def tname(self, t: Transition) -> str:
        src = ", ".join(t.sources) or "(source)"
        dst = ", ".join(t.targets) or "(sink)"
        return f"{t.name + ' ' if t.name else ''}{src} → {dst}"

    def outgoing(self, step: str) -> list[int]:
        return [k for k, t in enumerate(self.g.transitions) if step in t.src_steps]

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
        r = self.reach = explore(g, self.never, self.limit)
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
        incoming = [(k, t) for k, t in enumerate(g.transitions)
                    if set(t.dst_steps) & targets or set(t.targets) & targets]
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
        g = self.g
        seen: set[tuple[int, int]] = set()
        for s in g.leaf_steps():
            outs = [k for k in self.outgoing(s.name) if k not in self.never]
            for i, a in enumerate(outs):
                for b in outs[i + 1:]:
                    if (a, b) in seen:
                        continue
                    seen.add((a, b))
                    ta, tb = g.transitions[a], g.transitions[b]
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
                return (f"the delay {format_time(d)} is not shorter than the step's max time "
                        f"{format_time(s.max_ns)}")
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
                            f"the delay {format_time(d)} has elapsed")
        return None

    # -- G203 ---------------------------------------------------------------------------
    def _forward(self, starts: Iterable[str], stop: str | None = None,
                 skip: int | None = None) -> set[str]:
        g = self.g
        seen: set[str] = set()
        todo = list(starts)
        while todo:
            n = todo.pop()
            if n in seen:
                continue
            seen.add(n)
            if n == stop:
                continue
            for k in self.outgoing(n):
                if k != skip:
                    todo.extend(g.transitions[k].dst_steps)
        return seen

    def unclosed(self) -> None:
        g = self.g
        incoming: dict[str, int] = {}
        for t in g.transitions:
            for d in set(t.dst_steps):
                incoming[d] = incoming.get(d, 0) + 1
        for s in g.leaf_steps():
            outs = [k for k in self.outgoing(s.name) if k not in self.never
                    and s.name not in g.transitions[k].dst_steps]
            if len(outs) < 2:
                continue
            reach = [self._forward(g.transitions[k].dst_steps, stop=s.name) for k in outs]
            common = set.intersection(*reach) if reach else set()
            if not any(incoming.get(c, 0) >= 2 for c in common):
                lines = ", ".join(str(g.transitions[k].loc.line) for k in outs)
                self.add(s.loc, "warning", "G203", f"OR divergence after step '{s.name}' "
                         f"(transitions at line {lines}) is not closed by an OR convergence: "
                         "its branches never meet again (seed 000 recommends closing every "
                         "OR divergence with an OR convergence)")
        for k, t in enumerate(g.transitions):
            if len(set(t.dst_steps)) < 2:
                continue
            branches = [self._forward([d], skip=k) for d in t.dst_steps]
            closed = any(
                len(set(u.src_steps)) >= 2 and j != k
                and all(set(u.src_steps) & b for b in branches)
                for j, u in enumerate(g.transitions))
            if not closed:
                self.add(t.loc, "warning", "G203", f"AND divergence {self.tname(t)} is not "
                         "closed by an AND convergence: its parallel branches never "
                         "synchronise again (seed 000 recommends closing every AND "
                         "divergence with an AND convergence)")

    # -- G204 ---------------------------------------------------------------------------
    def same_condition(self) -> None:
        g = self.g
        for a in g.transitions:
            key = unparse(a.cond)
            if has_edge(a.cond) or self.logic.const(a.cond) is not None or isinstance(
                    a.cond, A.Lit):
                continue
            for b in g.transitions:
                if b is a or not set(a.dst_steps) & set(b.src_steps):
                    continue
                if unparse(b.cond) == key:
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
                    loc = self.where.in_text(a.loc, 0, stmt.start)
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
            self._promotions([t.cond], t.text, 0, lambda off, t=t: self.where.in_condition(t, off))
        for a in g.actions():
            roots = [x for x in (a.cond, a.event) if x is not None] + list(a.body or [])
            self._promotions(roots, a.text, 0,
                             lambda off, a=a: self.where.in_text(a.loc, 0, off))
        for st in [*g.pre, *g.post]:
            base = st.node.start
            self._promotions([st.node], st.text, base,
                             lambda off, st=st, base=base: self.where.in_text(st.loc, base, off))

    def _promotions(self, roots: list[A.Node], text: str, base: int, locate: Any) -> None:
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


# -- plant files ----------------------------------------------------------------------------
def check_plant_model(p: PlantDef) -> list[Diag]:
    """Driver points of a loaded plant: do they exist on their driver (G303-G305)?"""
    from drivers.base import ConfigError, Direction, PointError, PointKind
    from drivers.registry import DriverImportError, driver_class

    out: list[Diag] = []
    drivers: dict[str, Any] = {}
    missing: dict[str, str] = {}
    for name, d in p.drivers.items():
        try:
            cls = driver_class(d.type)
        except DriverImportError as exc:
            missing[name] = str(exc)
            continue
        except KeyError:
            out.append(diag(d.loc, "error", "G304", f"unknown driver type '{d.type}'"))
            continue
        try:
            drivers[name] = cls(name, dict(d.config))
        except (ConfigError, ValueError, TypeError) as exc:
            out.append(diag(d.loc, "error", "G304", f"driver '{name}' ({d.type}): {exc}"))
    noted: set[str] = set()
    for inst in p.instances.values():
        for direction, section in ((Direction.IN, inst.inputs), (Direction.OUT, inst.outputs)):
            for b in section.values():
                if b.driver is None:
                    continue
                if b.point == "ok":
                    if direction is Direction.OUT:
                        out.append(diag(b.loc, "error", "G303", f"'{b.source}' is the "
                                        "driver's health, a read-only input: it cannot be "
                                        f"bound as output '{b.signal}'"))
                    continue
                if b.driver in missing:
                    if b.driver not in noted:
                        noted.add(b.driver)
                        out.append(diag(b.loc, "note", "G305", f"points of driver "
                                        f"'{b.driver}' not checked: {missing[b.driver]}"))
                    continue
                drv = drivers.get(b.driver)
                if drv is None:
                    continue
                try:
                    kind = drv.add_point(b.point or "", direction)
                except PointError as exc:
                    out.append(diag(b.loc, "error", "G303", f"{exc} (instance "
                                    f"'{inst.name}', {direction.value}put '{b.signal}')"))
                    continue
                var = inst.grafcet.variables.get(b.signal)
                if var is None or p.drivers[b.driver].type == "sim":
                    continue
                want_int = var.type is not T.BOOL
                if want_int != (kind is PointKind.INT):
                    out.append(diag(b.loc, "error", "G303", f"'{b.source}' carries "
                                    f"{'a register (int)' if kind is PointKind.INT else 'a bit'}"
                                    f" but '{inst.name}.{b.signal}' is {var.type}"))
    return out


def _plant_bindings_scan(path: str) -> list[Diag]:
    """Every unbound signal and physical output bound twice, from the YAML text (the
    loader stops at the first)."""
    from runtime.language import load_grafcet

    out: list[Diag] = []
    try:
        doc = load_yaml(path)
    except SourceError:
        return out
    if not isinstance(doc, YMap) or not isinstance(doc.get("instances"), YMap):
        return out
    drv = doc.get("drivers")
    drivers: dict[str, Any] = drv if isinstance(drv, YMap) else {}
    driven: dict[str, tuple[str, str, Loc]] = {}
    instances = doc["instances"]
    for name, spec in instances.items():
        if not isinstance(spec, YMap) or "grafcet" not in spec:
            continue
        gpath = str(spec["grafcet"])
        if not os.path.isabs(gpath):
            gpath = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(path)),
                                                  gpath))
        try:
            g = load_grafcet(gpath)
        except SourceError:
            continue
        for key, signals in (("inputs", g.inputs), ("outputs", g.outputs)):
            section = spec.get(key)
            bound = section if isinstance(section, YMap) else {}
            where = spec.key_locs.get(key, instances.key_locs[name])
            for var in signals:
                if var.name not in bound:
                    out.append(diag(where, "error", "G301", f"instance '{name}' leaves "
                                    f"{key[:-1]} '{var.name}' of grafcet {g.name} unbound: "
                                    f"expected a binding '{var.name}: driver.point' in "
                                    f"'{key}', found none"))
            if key != "outputs" or not isinstance(section, YMap):
                continue
            for sig, b in section.items():
                loc = section.val_locs[sig]
                if isinstance(b, YMap):
                    loc = b.val_locs.get("from", loc)
                    b = b.get("from")
                if not isinstance(b, str) or "." not in b:
                    continue
                if b.split(".", 1)[0] not in drivers:
                    continue
                if b in driven:
                    other_inst, other_sig, other_loc = driven[b]
                    out.append(diag(loc, "error", "G302", f"physical output '{b}' is bound "
                                    f"twice: expected one output per point, found "
                                    f"'{name}.{sig}' and '{other_inst}.{other_sig}' (line "
                                    f"{other_loc.line})"))
                else:
                    driven[str(b)] = (name, sig, loc)
    return out


# -- files ----------------------------------------------------------------------------------
SCRIPT_KEYS = frozenset({"duration", "cycles", "set", "description"})


def file_kind(path: str) -> str:
    """'grafcet', 'plant', 'script' (a simulation script) or 'other', from the top-level
    keys (SourceError if the file is not YAML)."""
    doc = load_yaml(path)
    if isinstance(doc, YMap):
        if "grafcet" in doc or "steps" in doc:
            return "grafcet"
        if "instances" in doc or "drivers" in doc or "plc" in doc:
            return "plant"
        if set(doc) <= SCRIPT_KEYS and set(doc) & {"duration", "cycles", "set"}:
            return "script"
    return "other"


@dataclass
class FileResult:
    path: str
    diags: list[Diag]
    failure: str | None = None  # the loading error line (exit status 2)
    ms: float = 0.0


class Session:
    """Checks files, each chart once (a plant's charts are checked with it).

    ``plant``: the plant that simulation scripts are checked against (``--plant``); without
    it, a script is checked against the one plant file of its directory (the layout of
    ``configs/``: ``plant_sim.yaml`` beside ``story.yaml``)."""

    def __init__(self, limit: int = LIMIT, plant: str | None = None,
                 paths: Iterable[str] = ()) -> None:
        self.limit = limit
        self.plant = plant
        self.paths = list(paths)  # every file of the command line (plants for scripts)
        self.charts_done: set[str] = set()
        self._kinds: dict[str, str] = {}

    def kind(self, path: str) -> str:
        real = os.path.realpath(path)
        if real not in self._kinds:
            self._kinds[real] = file_kind(path)
        return self._kinds[real]

    def check_path(self, path: str) -> list[FileResult]:
        t0 = time.perf_counter()
        try:
            kind = self.kind(path)
        except SourceError as exc:
            return [FileResult(path, [], str(exc))]
        if kind == "grafcet":
            if os.path.realpath(path) in self.charts_done:
                return []  # already checked with a plant of this command line
            res = [self._grafcet(path)]
        elif kind == "plant":
            res = self._plant(path)
        elif kind == "script":
            res = [self._script(path)]
        else:
            res = [FileResult(path, [], f"{path}:1:1: error: expected a grafcet file "
                                        "('grafcet:' and 'steps:'), a plant file "
                                        "('instances:') or a simulation script "
                                        "('duration:' or 'cycles:', 'set:')")]
        res[0].ms = (time.perf_counter() - t0) * 1000
        return res

    # -- simulation scripts -----------------------------------------------------------------
    def _plant_of_script(self, path: str) -> tuple[str | None, str]:
        """(plant file, how it was found) or (None, why none)."""
        if self.plant is not None:
            return self.plant, "--plant"
        folder = os.path.dirname(os.path.abspath(path))

        def plants(paths: Iterable[str]) -> list[str]:
            out = []
            for p in paths:
                try:
                    if self.kind(p) == "plant" and p not in out:
                        out.append(p)
                except (SourceError, OSError):
                    continue
            return out

        here = [p for p in self.paths if os.path.dirname(os.path.abspath(p)) == folder]
        found = plants(here)
        if not found:
            disk = sorted(os.path.join(folder, n) for n in os.listdir(folder)
                          if n.endswith((".yaml", ".yml")))
            found = plants(disk)
        if len(found) == 1:
            return found[0], "the plant file of its directory"
        if not found:
            return None, "no plant file in its directory"
        names = ", ".join(os.path.basename(p) for p in found)
        return None, f"several plant files in its directory ({names})"

    def _script(self, path: str) -> FileResult:
        """A simulation script is checked against its plant: every name it sets must be an
        input (or chart flag) of an instance, or an input point of a driver, with a value
        of the right type; the times must be times."""
        from runtime.plant import Plant
        from runtime.plantfile import load_plant
        from runtime.simulate import load_script

        plant, how = self._plant_of_script(path)
        if plant is None:
            return FileResult(path, [diag(Loc(path, 1, 1), "note", "G400", "simulation "
                                          f"script not checked: {how}; name its plant with "
                                          "--plant PLANT.yaml")])
        try:
            p = Plant(load_plant(plant), sim=True)
        except SourceError:
            return FileResult(path, [diag(Loc(path, 1, 1), "note", "G400", "simulation "
                                          f"script not checked: its plant "
                                          f"{_show_path(plant)} ({how}) does not load")])
        try:
            load_script(path, p)
        except SourceError as exc:
            return FileResult(path, [], f"{exc} (checked against {_show_path(plant)})")
        return FileResult(path, [])

    def _grafcet(self, path: str) -> FileResult:
        self.charts_done.add(os.path.realpath(path))
        loaded = load_grafcet_checked(path)
        diags = list(loaded.diags)
        if loaded.g is not None:
            diags += check_grafcet(loaded.g, self.limit, loaded.repaired)
        failure = str(loaded.failure) if loaded.failure is not None else None
        return FileResult(path, _sorted(diags), failure)

    def _plant(self, path: str) -> list[FileResult]:
        from runtime.plantfile import load_plant

        results: list[FileResult] = []
        diags: list[Diag] = []
        try:
            p = load_plant(path)
        except SourceError as exc:
            code = _plant_code(exc)
            chart = exc.loc.file
            if code is None and os.path.realpath(chart) != os.path.realpath(path) and (
                    _grafcet_code(exc) is not None):
                # a chart of the plant breaks one of seed 000's rules: report its findings
                # with their codes; the plant itself cannot be checked further
                res = [] if os.path.realpath(chart) in self.charts_done else [
                    self._grafcet(chart)]
                if not any(r.failure for r in res):
                    note = diag(Loc(path, 1, 1), "note", "G300", f"plant not checked further: "
                                f"its chart {_show_path(chart)} does not load")
                    return [FileResult(path, [note]), *res]
            if code is None:
                return [FileResult(path, [], str(exc))]
            found = _plant_bindings_scan(path)
            if not any(d.line == exc.loc.line and d.code == code for d in found):
                found.append(diag(exc.loc, "error", code, exc.message))
            diags += found
            charts = self._plant_charts(path)
        else:
            diags += check_plant_model(p)
            charts = []
            for inst in p.instances.values():
                if inst.grafcet.path not in charts:
                    charts.append(inst.grafcet.path)
        results.append(FileResult(path, _sorted(diags)))
        for c in charts:
            if os.path.realpath(c) not in self.charts_done:
                results.append(self._grafcet(c))
        return results

    def _plant_charts(self, path: str) -> list[str]:
        out: list[str] = []
        try:
            doc = load_yaml(path)
        except SourceError:
            return out
        inst = doc.get("instances") if isinstance(doc, YMap) else None
        if isinstance(inst, YMap):
            for spec in inst.values():
                if isinstance(spec, YMap) and isinstance(spec.get("grafcet"), str):
                    g = str(spec["grafcet"])
                    if not os.path.isabs(g):
                        g = os.path.normpath(os.path.join(os.path.dirname(
                            os.path.abspath(path)), g))
                    if os.path.exists(g) and g not in out:
                        out.append(g)
        return out


def _sorted(diags: list[Diag]) -> list[Diag]:
    unique = list(dict.fromkeys(diags))
    return sorted(unique, key=lambda d: (d.file, d.line, d.col, SEVERITY_ORDER[d.severity],
                                         d.code))


def check_files(paths: Iterable[str], limit: int = LIMIT,
                plant: str | None = None) -> list[FileResult]:
    paths = list(paths)
    session = Session(limit, plant, paths)
    out: list[FileResult] = []
    for p in paths:
        out += session.check_path(p)
    return out


def exit_status(results: Iterable[FileResult]) -> int:
    results = list(results)
    if any(r.failure for r in results):
        return 2
    if any(d.severity == "error" for r in results for d in r.diags):
        return 1
    return 0


# -- command line ---------------------------------------------------------------------------
def cmd_check(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    results = check_files(args.files, args.limit, args.plant)
    errors = warnings = 0
    for r in results:
        for d in r.diags:
            if args.errors_only and d.severity != "error":
                continue
            sys.stdout.write(f"{d}\n")
        if r.failure:
            sys.stdout.write(f"{r.failure}\n")
        errors += sum(d.severity == "error" for d in r.diags) + (1 if r.failure else 0)
        warnings += sum(d.severity == "warning" for d in r.diags)
    ms = (time.perf_counter() - t0) * 1000
    if not args.quiet:
        sys.stderr.write(f"check: {len(results)} file(s), {errors} error(s), {warnings} "
                         f"warning(s) in {ms:.0f} ms\n")
    sys.stdout.flush()
    return exit_status(results)


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    c = sub.add_parser("check", help="static checks of seed 000's rules (G1xx errors, G2xx "
                                     "warnings, G3xx plant bindings)",
                       description="Check grafcet files, plant files and simulation "
                                   "scripts: FILE:LINE:COL: error|warning|note GCODE: "
                                   "message. Exit 1 on errors, 2 if a file does not load.")
    c.add_argument("files", nargs="+", metavar="FILE")
    c.add_argument("--limit", type=int, default=LIMIT,
                   help=f"most reachable situations to explore (default {LIMIT})")
    c.add_argument("--plant", metavar="PLANT.yaml",
                   help="plant that simulation scripts among FILE are checked against "
                        "(default: the one plant file in each script's directory)")
    c.add_argument("--errors-only", action="store_true", help="print errors only")
    c.add_argument("-q", "--quiet", action="store_true", help="no summary line on stderr")
    c.set_defaults(func=cmd_check)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="softplc")
    sub = p.add_subparsers(dest="command", required=True)
    register(sub)
    args = p.parse_args(["check", *(argv if argv is not None else sys.argv[1:])])
    return int(args.func(args))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
