"""The state of a compiled chart laid out: a slot for each variable, each step's X and
times, each block, and the scan's own memory (edges, stored actions, the flags' history);
each slot is a local of the scan closure (a cell), numbered for the outside (``Slot.index``)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from runtime.compiler.emit import ident
from runtime.compiler.program import COVERAGE, Slot, SlotKind
from runtime.language import ast as A
from runtime.language.model import Action, Grafcet, Qualifier, ScanModel, Step, VarKind
from runtime.language.unparse import unparse

T = A.Type

#: the chart flags that, once set, make the scans take the slow path (program.State)
SLOW_FLAGS = ("SFCInit", "SFCReset", "SFCQuitError", "SFCPause", "SFCTip", "SFCTipMode")
#: the scan's own memory of those flags (set: the slow path too)
SLOW_MEMORY = ("initpend", "resetprev", "quitprev", "tipprev")


def macro_initial(g: Grafcet, s: Step) -> bool:
    """Is ``s`` a macro-step whose entry step is initial (so it is active at start)?"""
    return s.macro is not None and g.steps[s.macro.entry].initial


def bool_targets(g: Grafcet) -> dict[str, list[Action]]:
    """The actions that drive each bool target, by target, in file order."""
    out: dict[str, list[Action]] = {}
    for a in g.actions():
        if a.target is not None:
            out.setdefault(a.target, []).append(a)
    return out


def written(g: Grafcet) -> tuple[frozenset[str], frozenset[str]]:
    """The variables the scan of ``g`` writes: (those it writes at every scan, whatever the
    situation: the bool targets of actions, whose action control computes them, and the
    targets of assignments at the top level of ``pre`` and ``post``; those some action,
    equation or statement writes at all). An online change gives a variable the first
    chart wrote at every scan and the second does not its value of a cold start (its
    initial value), as it does an output the second chart never writes
    (runtime/change/diff.py)."""
    every = set(bool_targets(g))
    every |= {s.node.target.name for s in (*g.pre, *g.post) if isinstance(s.node, A.Assign)}
    anywhere = set(every)
    roots = [s.node for s in (*g.pre, *g.post)]
    roots += [n for a in g.actions() for n in a.body or []]
    for r in roots:
        for n in A.walk(r):
            if isinstance(n, A.Assign):
                anywhere.add(n.target.name)
            elif isinstance(n, A.CallStmt) and n.call.method == "Set":
                anywhere.add(n.call.obj)
            elif isinstance(n, A.For):
                anywhere.add(n.var.name)
    return frozenset(every), frozenset(anywhere)


#: the qualifiers timed from the step's activation, as IEC's ACTION_CONTROL times them: a
#: TON on the qualifier's input, the step's X, which a rule-5 re-entry leaves TRUE
ACTIVATION_TIMED = (Qualifier.L, Qualifier.D, Qualifier.DS)


def activation_timed(g: Grafcet) -> set[str]:
    """The steps with an L, D or DS action: they keep the chart clock at their activation,
    which rule 5 does not restart (``ta_``), beside the one ``.T`` counts from (``t0_``)."""
    return {a.step for a in g.actions() if a.qualifier in ACTIVATION_TIMED}


def coverage_key(kind: str, ref: str | int) -> str:
    """The slot key of the counter of a step's activations (``kind`` "step", ``ref`` its
    name), a transition's firings ("transition", its index) or an action's runs ("action",
    its position in ``Grafcet.actions()``)."""
    return f"{COVERAGE}{kind}:{ref}"


class StateLayout:
    """The slots of one chart's state list, and the locals stored into them."""

    def __init__(self, g: Grafcet, coverage: bool = False) -> None:
        self.g = g
        #: count what the chart does (``coverage_key``): a scenario's coverage
        self.coverage = coverage
        self.slots: list[Slot] = []
        self.index: dict[str, int] = {}  # slot key -> index
        self.edges: dict[int, int] = {}  # id(node) -> edge number
        self.edge_nodes: list[A.Unary] = []
        #: the locals of SLOW_FLAGS
        self.slow_locals = {ident("v", f) for f in SLOW_FLAGS}
        #: stores of a chart flag written so far (each also sets ``slow``)
        self.flag_stores = 0
        #: the steps that keep their activation's clock for L, D and DS (``ta_``)
        self.timed = activation_timed(g)

    def slot(self, key: str, local: str, init: Any, block: str | None = None,
             kind: SlotKind = SlotKind.INTERNAL, name: str = "",
             type_: A.Type | None = None) -> None:
        i = len(self.slots)
        self.index[key] = i
        self.slots.append(Slot(key, local, init, block, kind, name, type_, i))

    def let(self, *targets: str, value: str) -> str:
        """``a = b = value``. A state local is a cell of the instance's scan closure, so
        the store is the state itself: nothing to write back, and a scan that raises
        leaves every store it made so far (as a write-through list did)."""
        line = " = ".join([*targets, value])
        for t in targets:  # a chart flag set by the chart: the next test must see it
            if t in self.slow_locals:
                line += f"; slow = slow or {t}"
                self.flag_stores += 1
        return line

    def count(self, kind: str, ref: str | int, delta: str = "1") -> str:
        """The statement adding ``delta`` to a coverage counter, or "" when the chart is
        compiled without coverage."""
        if not self.coverage:
            return ""
        return f"{self.slots[self.index[coverage_key(kind, ref)]].local} += {delta}"

    def add(self, target: str, delta: str) -> str:
        """``target += delta``, stored like ``let``."""
        return self.let(target, value=f"{target} + ({delta})")

    def build(self) -> None:
        """Adds the slots of the variables, the steps, the blocks, the scan memory, the edges."""
        g = self.g
        for v in g.variables.values():
            if v.kind is VarKind.SYSTEM:
                continue
            self.slot(v.name, ident("v", v.name), v.init, None, SlotKind.VARIABLE, v.name,
                      v.type)
        for s in g.steps.values():
            self.slot(f"{s.name}.X", ident("x", s.name), s.initial or macro_initial(g, s),
                      None, SlotKind.STEP_X, s.name, T.BOOL)
            self.slot(f"{s.name}.T0", ident("t0", s.name), 0, None, SlotKind.STEP_START,
                      s.name, T.TIME)
            self.slot(f"{s.name}.TK", ident("tk", s.name), 0, None, SlotKind.STEP_LAST,
                      s.name, T.TIME)
            if s.name in self.timed:
                self.slot(f"{s.name}.TA", ident("ta", s.name), 0, None, SlotKind.STEP_START,
                          s.name, T.TIME)
        for name in g.timers:
            self.slot(name, ident("b", name), None, "SeedTimer", SlotKind.BLOCK, name)
        for b in g.blocks.values():
            self.slot(b.name, ident("b", b.name), None, b.kind, SlotKind.BLOCK, b.name)
        self.slot("#ct", "ct", 0, None, SlotKind.CLOCK, "", T.TIME)
        for key, local, init in (("#clockbase", "cb", 0),
                                 ("#first", "first", True), ("#initpend", "initpend", True),
                                 ("#paused", "wp", False), ("#resetprev", "resetprev", False),
                                 ("#quitprev", "quitprev", False), ("#tipprev", "tipprev", True)):
            self.slot(key, local, init)
        if g.scan is ScanModel.CODESYS:
            for t in g.transitions:
                self.slot(self._stable(f"#pending:{t.name or ','.join(t.sources) + '->'}"
                                       f"{'' if t.name else ','.join(t.targets)}"),
                          f"pf{t.index}", False)
            for a in g.actions():  # Q of the last scan, for the final scan of L/D actions
                if a.body is not None and a.qualifier in (Qualifier.L, Qualifier.D):
                    self.slot(self._stable(f"#cq:{a.step}:{a.qualifier.value}") + ".F",
                              f"cq{a.index}", False)
        for target, assocs in bool_targets(g).items():
            quals = {a.qualifier for a in assocs}
            if Qualifier.S in quals:
                self.slot(f"#S.{target}", ident("s", target), False)
            for k, a in enumerate(assocs):
                if a.qualifier in (Qualifier.SD, Qualifier.SL, Qualifier.DS):
                    tag = f"{a.qualifier.value.lower()}{k}_{target}"
                    key = self._stable(f"#{a.qualifier.value}:{a.step}:{target}")
                    self.slot(f"{key}.F", f"f{tag}", False)
                    self.slot(f"{key}.T", f"t{tag}", 0)
        # edges: every RE/FE node of the chart
        for where, n in self._all_nodes():
            if isinstance(n, A.Unary) and n.op in ("RE", "FE"):
                k = len(self.edge_nodes)
                self.edges[id(n)] = k
                self.edge_nodes.append(n)
                key = self._stable(f"#edge:{where}:[{unparse(n)}]")
                self.slot(f"{key}.prev", f"ep{k}", n.op == "RE")
                self.slot(key, f"e{k}", False)
                self.index[f"#edge{k}"] = self.index[key]
        if self.coverage:  # the counters last: the other slots keep their places
            for st in g.steps.values():
                self.slot(coverage_key("step", st.name), ident("k", st.name), 0)
            for t in g.transitions:
                self.slot(coverage_key("transition", t.index), f"kt{t.index}", 0)
            for i in range(len(g.actions())):
                self.slot(coverage_key("action", i), f"ka{i}", 0)

    def _stable(self, key: str) -> str:
        """``key``, numbered if it is taken: the keys of the scan's own memory are made of
        what they belong to (a transition's steps, an action's step, an edge's text), not
        of sequence numbers, so that an edited chart keeps them (online change)."""
        n, out = 1, key
        while out in self.index or f"{out}.F" in self.index or f"{out}.prev" in self.index:
            n += 1
            out = f"{key}#{n}"
        return out

    def _all_nodes(self) -> Iterator[tuple[str, A.Node]]:
        """Every node of the chart's expressions, with where it is: "pre", "post", the
        transition's steps or the action's step."""
        g = self.g
        roots: list[tuple[str, A.Node]] = [("pre", st.node) for st in g.pre]
        roots += [(t.name or f"{','.join(t.sources)}->{','.join(t.targets)}", t.cond)
                  for t in g.transitions]
        for a in g.actions():
            roots += [(a.step, x) for x in (a.cond, a.event) if x is not None]
            roots += [(a.step, x) for x in a.body or []]
        roots += [("post", st.node) for st in g.post]
        for where, r in roots:
            for n in A.walk(r):
                yield where, n
