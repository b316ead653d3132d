"""The evolution of the situation as Python code: transitions evaluated, their source steps
left and target steps entered (macro-steps too), the initial situation, and per scan model
when it happens (immediate: once; stable: rounds up to a stable situation; CODESYS: decided
for the next scan)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable

from runtime.compiler.emit import Emitter, comment, ident
from runtime.compiler.expressions import ExprEmitter
from runtime.compiler.layout import StateLayout, macro_initial
from runtime.errors import SoftplcError
from runtime.language import ast as A
from runtime.language.model import Grafcet, ScanModel, Step, Transition
from runtime.language.unparse import transition_text

#: rounds of the stable-situation search before "unstable chart"
STABLE_MAX_ROUNDS = 100


class UnstableChart(SoftplcError, RuntimeError):
    """``scan: stable`` found no stable situation within STABLE_MAX_ROUNDS rounds."""

    def __init__(self, chart: str, cycle: list[str], steps: list[str] | None = None) -> None:
        steps = steps or []
        super().__init__(f"unstable chart {chart}: the search for a stable situation did not "
                         f"end after {STABLE_MAX_ROUNDS} rounds; cycle of steps "
                         f"{', '.join(steps)}; transitions still firing: {'; '.join(cycle)}")
        self.cycle = cycle  # the transitions fired in the last round, "src -> dst when c"
        self.steps = steps  # their source and target steps, file order


def unstable_chart(chart: str, names: list[str], steps: list[list[str]], order: list[str],
                   fired: tuple[bool, ...]) -> UnstableChart:
    """Builds UnstableChart from the transitions fired in the last round (cold path)."""
    involved = {s for ss, f in zip(steps, fired, strict=True) if f for s in ss}
    return UnstableChart(chart, [n for n, f in zip(names, fired, strict=True) if f],
                         [s for s in order if s in involved])


def min_timed(g: Grafcet, t: Transition) -> list[Step]:
    """The steps with a ``min`` time that ``t`` leaves: each source as written, and for a
    macro-step its exit step, down to a plain step (a macro-step's min counts too)."""
    out = []
    for name in t.sources:
        st = g.steps[name]
        while True:
            if st.min_ns:
                out.append(st)
            if st.macro is None:
                break
            st = g.steps[st.macro.exit]
    return out


class Evolution:
    """Generates the evolution of one chart's situation."""

    def __init__(self, g: Grafcet, state: StateLayout, exprs: ExprEmitter) -> None:
        self.g = g
        self.state = state
        self.exprs = exprs
        self.leaf = g.leaf_steps()
        self.macros = [s for s in g.steps.values() if s.macro is not None]
        self.stable = g.scan is ScanModel.STABLE
        self.codesys = g.scan is ScanModel.CODESYS

    def fired_name(self, t: Transition) -> str:
        return f"pf{t.index}" if self.codesys else f"f{t.index}"

    def evaluate_transitions(self, out: Emitter) -> None:
        """Each transition's fired flag, by priority: its source steps active (and their
        min times reached), no earlier transition fired on one of its source steps, its
        condition. The earlier ones are summed up per step in a temporary (``h_STEP``:
        some transition leaving STEP fired so far), so a divergence of n branches costs n
        terms, not n²/2 (an earlier transition's ``not f`` each)."""
        g = self.g
        left = Counter(s for t in g.transitions for s in dict.fromkeys(t.src_steps))
        seen: set[str] = set()
        for t in g.transitions:
            f = self.fired_name(t)
            srcs = list(dict.fromkeys(t.src_steps))
            terms = [ident("x", s) for s in t.src_steps]
            for st in min_timed(g, t):
                terms.append(f"(ct - {ident('t0', st.name)}) >= {st.min_ns}")
            terms += [f"not {ident('h', s)}" for s in srcs if s in seen]
            terms.append(self.exprs.ex(t.cond))
            out(comment(transition_text(t)))
            out(self.state.let(f, value=" and ".join(terms)))
            for s in srcs:
                left[s] -= 1
                if left[s]:  # a later transition leaves it too
                    h = ident("h", s)
                    out(f"{h} = {h} or {f}" if s in seen else f"{h} = {f}")
                seen.add(s)

    def _leave(self, step: str) -> str:
        """Statements deactivating ``step``: its .T is kept, it is marked left."""
        x, t0, tk, lft = (ident(p, step) for p in ("x", "t0", "tk", "l"))
        return (f"{self.state.let(x, value='False')}; {self.state.let(tk, value=f'ct - {t0}')}; "
                f"{self.state.let(lft, value='True')}")

    def _enter(self, step: str) -> str:
        """Statements activating ``step``: its .T restarts, it is marked entered (and
        counted, with coverage)."""
        x, a = ident("x", step), ident("a", step)
        return (f"{self.state.let(x, value='True')}; "
                f"{self.state.let(*self._starts(step), value='ct')}; "
                f"{self.state.let(a, value='True')}{self.counted(step)}")

    def counted(self, step: str) -> str:
        """``; <count an activation of step>``, or "" without coverage."""
        count = self.state.count("step", step)
        return f"; {count}" if count else ""

    def _starts(self, step: str) -> list[str]:
        """The clocks an activation of ``step`` restarts: its ``.T``'s, and the one its L, D
        and DS delays count from (``ta_``), which a rule-5 re-entry leaves alone."""
        return [ident("t0", step)] + ([ident("ta", step)] if step in self.state.timed else [])

    def apply_fired(self, out: Emitter) -> None:
        """Deactivate sources, then activate targets, of the transitions that fired."""
        g = self.g
        for t in g.transitions:  # with coverage: each transition's firings counted
            count = self.state.count("transition", t.index, self.fired_name(t))
            if count:
                out(count)
        # the fired flags leaving / entering each step and macro-step, in file order (one
        # pass over the transitions, not one per step)
        leaves: dict[str, list[str]] = {}
        enters: dict[str, list[str]] = {}
        leaves_macro: dict[str, list[str]] = {}
        enters_macro: dict[str, list[str]] = {}
        for t in g.transitions:
            f = self.fired_name(t)
            for n in dict.fromkeys(t.src_steps):
                leaves.setdefault(n, []).append(f)
            for n in dict.fromkeys(t.dst_steps):
                enters.setdefault(n, []).append(f)
            for n in self._left_macros(t):
                leaves_macro.setdefault(n, []).append(f)
            for n in self._entered_macros(t):
                enters_macro.setdefault(n, []).append(f)
        for st in self.leaf:
            leaving = leaves.get(st.name, [])
            entering = enters.get(st.name, [])
            x, t0 = ident("x", st.name), ident("t0", st.name)
            if leaving and entering:
                out(f"if {' or '.join(leaving)}:")
                out.indent()
                out(f"if {' or '.join(entering)}: {self.state.let(t0, value='ct')}"
                    f"{self.counted(st.name)}  # rule 5: stays active, .T restarts")
                out(f"else: {self._leave(st.name)}")
                out.dedent()
                out(f"elif ({' or '.join(entering)}) and not {x}: {self._enter(st.name)}")
            elif leaving:
                out(f"if {' or '.join(leaving)}: {self._leave(st.name)}")
            elif entering:
                out(f"if ({' or '.join(entering)}) and not {x}: {self._enter(st.name)}")
        for m in self.macros:
            assert m.macro is not None
            x, t0, tk = (ident(p, m.name) for p in ("x", "t0", "tk"))
            a, lft = ident("a", m.name), ident("l", m.name)
            inner = [ident("x", s) for s in m.macro.steps if g.steps[s].macro is None]
            entering = enters_macro.get(m.name, [])
            leaving = leaves_macro.get(m.name, [])
            out(f"_nx = {' or '.join(inner)}")
            if entering:
                # entered: its .T restarts if it was inactive, or left and re-entered now
                again = f" or {' or '.join(leaving)}" if leaving else ""
                out(f"if ({' or '.join(entering)}) and (not {x}{again}):")
                out.indent()
                out(self.state.let(t0, value="ct"))
                entered = self.state.let(a, value="True") + self.counted(m.name)
                if m.name in self.state.timed:  # entered while inactive: its delays start
                    entered = f"{self.state.let(ident('ta', m.name), value='ct')}; {entered}"
                out(f"if not {x}: {entered}")
                out.dedent()
            out(f"if {x} and not _nx: {self.state.let(tk, value=f'ct - {t0}')}; "
                f"{self.state.let(lft, value='True')}")
            out(self.state.let(x, value="_nx"))

    def _left_macros(self, t: Transition) -> set[str]:
        """The macro-steps that ``t`` leaves: its sources' exit chains."""
        out: set[str] = set()
        for name in t.sources:
            st = self.g.steps[name]
            while st.macro is not None:
                out.add(st.name)
                st = self.g.steps[st.macro.exit]
        return out

    def _entered_macros(self, t: Transition) -> set[str]:
        out: set[str] = set()
        for name in t.targets:
            st = self.g.steps[name]
            while st.macro is not None:
                out.add(st.name)
                st = self.g.steps[st.macro.entry]
        return out

    def to_initial(self, out: Emitter, mark_entered: bool) -> None:
        """Situation = initial steps, every .T = 0."""
        for st in self.g.steps.values():
            x, t0, tk = (ident(p, st.name) for p in ("x", "t0", "tk"))
            init = st.initial or macro_initial(self.g, st)
            line = (f"{self.state.let(x, value=str(init))}; "
                    f"{self.state.let(*self._starts(st.name), value='ct')}; "
                    f"{self.state.let(tk, value='0')}")
            if mark_entered and init:
                line += (f"; {self.state.let(ident('a', st.name), value='True')}"
                         f"{self.counted(st.name)}")
            out(line)
        if self.codesys:
            out("; ".join(self.state.let(f"pf{t.index}", value="False") for t in self.g.transitions)
                or "pass")

    def section(self, out: Emitter, folded: bool = False) -> None:
        """The evolution of one scan, per scan model (CODESYS: decided for the next scan).
        ``folded``: the fast path's body, where no chart flag was set when the scan
        began (nothing frozen or paused, no tip pulse) and none by a pre equation: only a
        CODESYS chart tests tip mode, which its actions, run before its evolution, may
        have set in this scan (``if True:`` compiles to nothing)."""
        g = self.g
        guard = ("if not frozen and (not v_SFCTipMode or tip):" if not folded
                 else "if not v_SFCTipMode:" if self.codesys else "if True:")
        if self.codesys:
            out("# 5b. CODESYS: the transitions decide the next scan's situation")
        else:
            out("# 3. evolution")
        self.exprs.sample_edges(out, [t.cond for t in g.transitions])
        if not g.transitions:
            return
        if self.codesys:
            out(guard)
            out.indent()
            self.evaluate_transitions(out)
            out.dedent()
            out("else:  # tip mode: nothing decided" if folded
                else "elif not paused:  # a pending evolution waits for the end of a pause")
            out.indent()
            out(self.state.let(*(f"pf{t.index}" for t in g.transitions), value="False"))
            out.dedent()
            return
        fired = " or ".join(f"f{t.index}" for t in g.transitions)
        out(guard)
        out.indent()
        if self.stable:
            out("rounds = 0")
            out("while True:")
            out.indent()
            self.evaluate_transitions(out)
            out(f"if not ({fired}): break")
            self.apply_fired(out)
            out("rounds += 1")
            trans_edges = sorted({self.state.edges[id(n)] for t in g.transitions
                                  for n in A.walk(t.cond)
                                  if isinstance(n, A.Unary) and n.op in ("RE", "FE")})
            if trans_edges:
                out("if rounds == 1:  # edges are true in the first round only")
                out.indent()
                out(self.state.let(*(f"e{k}" for k in trans_edges), value="False"))
                out.dedent()
            out(f"if rounds > {STABLE_MAX_ROUNDS}:")
            out.indent()
            names = [transition_text(t) for t in g.transitions]
            steps = [[*t.src_steps, *t.dst_steps] for t in g.transitions]
            flags = ", ".join(f"f{t.index}" for t in g.transitions)
            out(f"raise _Unstable({g.name!r}, {names!r}, {steps!r}, "
                f"{[s.name for s in self.leaf]!r}, ({flags},))")
            out.dedent()
            out.dedent()
        else:
            can = self.may_fire()
            if can is not None:
                out(f"if {can}:  # some transition fires: each one's, by priority")
                out.indent()
            self.evaluate_transitions(out)
            out(f"if {fired}:")
            out.indent()
            self.apply_fired(out)
            out.dedent()
            if can is not None:
                out.dedent()
        out.dedent()

    def fired_or_not(self, out: Emitter, clear_marks: Callable[[], None],
                     actions: Callable[[bool], None]) -> None:
        """The folded evolution with the actions after it (immediate), or before it
        (CODESYS: after the situation it decided in the last scan becomes current), in
        two branches: where a step changes, ``clear_marks()`` (the entered and left marks
        set to false, before the steps change), the evolution, then ``actions(True)``;
        where none does, ``actions(False)``: the actions written with every mark false
        (none can be set), so a usual scan neither clears the marks nor tests them."""
        g = self.g
        if self.codesys:
            if g.transitions:
                out("# 3. CODESYS: the situation decided by the last scan becomes current")
                out(f"if {' or '.join(f'pf{t.index}' for t in g.transitions)}:")
                out.indent()
                clear_marks()
                self.apply_fired(out)
                actions(True)
                out.dedent()
                out("else:  # nothing decided: no step entered or left")
                out.indent()
                actions(False)
                out.dedent()
            else:
                actions(False)
            self.section(out, folded=True)
            return
        out("# 3. evolution")
        self.exprs.sample_edges(out, [t.cond for t in g.transitions])
        if not g.transitions:
            actions(False)
            return
        fired = " or ".join(f"f{t.index}" for t in g.transitions)
        can = self.may_fire()
        if can is not None:
            out(f"if {can}:  # some transition fires: each one's, by priority")
            out.indent()
            clear_marks()
            self.evaluate_transitions(out)
            out(f"if {fired}:")
            out.indent()
            self.apply_fired(out)
            out.dedent()
        else:
            self.evaluate_transitions(out)
            out(f"if {fired}:")
            out.indent()
            clear_marks()
            self.apply_fired(out)
        actions(True)
        out.dedent()
        out("else:  # nothing fires: no step entered or left")
        out.indent()
        actions(False)
        out.dedent()

    def may_fire(self) -> str | None:
        """An expression true exactly when some transition fires, cheaper than evaluating
        them all: per set of source steps, its activity and min times, then the conditions
        of its transitions in file order (a transition that loses to an earlier one on a
        shared step means that one fires). None where a condition calls a block method
        (not to be called twice when a transition fires) or divides (it could then raise
        where the evaluation by priority never evaluates it: a lower-priority transition
        on a shared step whose condition divides by zero)."""
        g = self.g
        groups: dict[tuple[str, ...], list[str]] = {}
        for t in g.transitions:
            if any(isinstance(n, A.MethodCall)
                   or (isinstance(n, A.Binary) and n.op in ("DIV", "MOD"))
                   for n in A.walk(t.cond)):
                return None
            guard = [ident("x", s) for s in t.src_steps]
            guard += [f"(ct - {ident('t0', st.name)}) >= {st.min_ns}" for st in min_timed(g, t)]
            groups.setdefault(tuple(guard), []).append(self.exprs.ex(t.cond))
        out = []
        for terms, conds in groups.items():
            cond = conds[0] if len(conds) == 1 else f"({' or '.join(conds)})"
            out.append(f"({' and '.join([*terms, cond])})")
        return " or ".join(out)
