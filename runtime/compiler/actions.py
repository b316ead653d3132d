"""Actions as Python code: each bool target's control from its qualifiers (N S R L D P SD
SL DS), statement actions (N L D P P0 P1, ``on EVENT do``), CODESYS's order and final
scan, and the supervision of steps' max times."""

from __future__ import annotations

from runtime.compiler.emit import Emitter, comment, ident
from runtime.compiler.expressions import ExprEmitter
from runtime.compiler.layout import StateLayout, bool_targets
from runtime.compiler.statements import StmtEmitter
from runtime.language import ast as A
from runtime.language.model import Action, Grafcet, Qualifier, ScanModel


class ActionEmitter:
    """Generates the actions of one chart."""

    def __init__(self, g: Grafcet, state: StateLayout, exprs: ExprEmitter,
                 stmts: StmtEmitter) -> None:
        self.g = g
        self.state = state
        self.exprs = exprs
        self.stmts = stmts
        self.stable = g.scan is ScanModel.STABLE
        self.codesys = g.scan is ScanModel.CODESYS
        #: each action's position in ``g.actions()`` (its coverage counter's number)
        self.number = {id(a): n for n, a in enumerate(g.actions())}

    def reset_stored(self, out: Emitter) -> None:
        """Reset every stored action's memory (S targets, SD SL DS flags, CODESYS's Q)."""
        for s in self.state.slots:
            if s.key.startswith("#S.") or (s.key.startswith("#") and s.key.endswith(".F")):
                out(self.state.let(s.local, value="False"))

    def active(self, step: str) -> str:
        """``step`` active for the actions (stable model: also if entered in this scan)."""
        x = ident("x", step)
        return f"({x} or {ident('a', step)})" if self.stable else x

    def bool_action(self, out: Emitter, target: str, assocs: list[Action]) -> None:
        """The value of ``target`` from every action that drives it (a reset wins)."""
        out(comment(f"action control of {target}: " + "; ".join(
            f"{a.qualifier.value} in {a.step}" for a in assocs)))
        terms: list[str] = []
        resets = [self.active(a.step) for a in assocs if a.qualifier is Qualifier.R]
        r = None
        if resets:
            r = "_r"
            out(f"_r = {' or '.join(resets)}")
        sets = [self.active(a.step) for a in assocs if a.qualifier is Qualifier.S]
        if sets:
            s = ident("s", target)
            out(self.state.let(s, value=f"({s} or {' or '.join(sets)})"
                               + (" and not _r" if r else "")))
            terms.append(s)
        for a in assocs:  # with coverage: a set or a reset runs while its step is active
            if a.qualifier in (Qualifier.S, Qualifier.R):
                self.count(out, a, self.active(a.step))
        for k, a in enumerate(assocs):
            q, st = a.qualifier, a.step
            x, ta = ident("x", st), ident("ta", st)  # ta: since X rose (layout.py)
            if q is Qualifier.N:
                terms.append(self.counted(out, a, f"({x} and {self.exprs.ex(a.cond)})"
                                          if a.cond is not None else x))
            elif q is Qualifier.L:
                terms.append(self.counted(out, a, f"({x} and ct - {ta} < {a.time_ns})"))
            elif q is Qualifier.D:
                terms.append(self.counted(out, a, f"({x} and ct - {ta} >= {a.time_ns})"))
            elif q is Qualifier.P:
                terms.append(self.counted(out, a, ident("a", st)))
            elif q in (Qualifier.SD, Qualifier.SL, Qualifier.DS):
                tag = f"{q.value.lower()}{k}_{target}"
                ff, tt = f"f{tag}", f"t{tag}"
                if q is Qualifier.DS:
                    out(f"if {x} and ct - {ta} >= {a.time_ns}: {self.state.let(ff, value='True')}")
                    terms.append(self.counted(out, a, ff))
                else:
                    out(f"if {self.active(st)} and not {ff}: {self.state.let(ff, value='True')}; "
                        f"{self.state.let(tt, value='ct')}")
                    cmp = ">=" if q is Qualifier.SD else "<"
                    terms.append(self.counted(out, a, f"({ff} and ct - {tt} {cmp} {a.time_ns})"))
                if r:
                    out(f"if _r: {self.state.let(ff, value='False')}")
        value = " or ".join(terms) or "False"
        if r:
            value = f"not _r and ({value})"
        out(self.state.let(ident("v", target), value=value))

    def count(self, out: Emitter, a: Action, term: str) -> None:
        """With coverage: count a run of ``a`` in a scan where ``term`` holds."""
        count = self.state.count("action", self.number[id(a)], term)
        if count:
            out(count)

    def counted(self, out: Emitter, a: Action, term: str) -> str:
        """``term``, the part of ``a`` in its target's value; with coverage, computed once
        into a temporary (``cvN``) whose truth counts a run of ``a``."""
        if not self.state.coverage:
            return term
        n = self.number[id(a)]
        out(f"cv{n} = {term}")
        self.count(out, a, f"cv{n}")
        return f"cv{n}"

    def statement_action(self, out: Emitter, a: Action, final_scan: bool = False) -> None:
        """``if <the action's Q>: body``; with ``final_scan``, CODESYS's extra run of an IEC
        action whose step was left in the previous scan (Q = false)."""
        q, st = a.qualifier, a.step
        x, ta = ident("x", st), ident("ta", st)
        ent, left = ident("a", st), ident("l", st)
        label = f"{q.value if q is not Qualifier.EVENT else 'on'} in {st}: {a.text[:60]}"
        held = f"cq{a.index}" if self.codesys and q in (Qualifier.L, Qualifier.D) else None
        if final_scan:
            out(comment(f"final scan of {label}"))
            # an L/D action runs once more only if it was running in the previous scan
            out(f"if {left} and {held}:" if held else f"if {left}:")
            self.run_counted(out, a)
            self.stmts.block(out, a.body or [])
            return
        if q is Qualifier.N:
            cond = x
        elif q is Qualifier.L:
            cond = f"{x} and ct - {ta} < {a.time_ns}"
        elif q is Qualifier.D:
            cond = f"{x} and ct - {ta} >= {a.time_ns}"
        elif q in (Qualifier.P, Qualifier.P1):
            cond = ent
        elif q is Qualifier.P0:
            cond = left
        else:  # EVENT
            cond = f"{self.active(st)} and {self.exprs.ex(a.event)}"  # type: ignore[arg-type]
        out(comment(label))
        if held:
            out(self.state.let(held, value=cond))
            cond = held
        out(f"if {cond}:")
        self.run_counted(out, a)
        self.stmts.block(out, a.body or [])

    def run_counted(self, out: Emitter, a: Action) -> None:
        """With coverage, the first line of a statement action's body: a run counted."""
        count = self.state.count("action", self.number[id(a)])
        if count:
            out.indent()
            out(count)
            out.dedent()

    def ordered_actions(self, out: Emitter) -> None:
        """Every action in the scan model's order, then the supervision of max times."""
        g = self.g
        stmt_actions = [a for a in g.actions() if a.body is not None]
        targets = bool_targets(self.g)
        if self.codesys:
            for q in (Qualifier.P0, Qualifier.P1):
                for a in stmt_actions:
                    if a.qualifier is q:
                        self.statement_action(out, a)
            for target, assocs in targets.items():
                self.bool_action(out, target, assocs)
            for a in stmt_actions:
                if a.qualifier in (Qualifier.N, Qualifier.L, Qualifier.D, Qualifier.P):
                    self.statement_action(out, a, final_scan=True)
            for a in stmt_actions:
                if a.qualifier not in (Qualifier.P0, Qualifier.P1):
                    self.statement_action(out, a)
        else:
            for target, assocs in targets.items():
                self.bool_action(out, target, assocs)
            for a in stmt_actions:
                self.statement_action(out, a)
        supervised = [s for s in g.steps.values() if s.max_ns is not None]  # macro-steps too
        if supervised:
            out("if v_SFCEnableLimit and not v_SFCError:")
            out.indent()
            for i, s in enumerate(supervised):
                x, t0 = ident("x", s.name), ident("t0", s.name)
                out(f"{'if' if i == 0 else 'elif'} {x} and ct - {t0} > {s.max_ns}: "
                    f"{self.state.let('v_SFCError', value='True')}; "
                    f"{self.state.let('v_SFCErrorStep', value=repr(s.name))}")
            out.dedent()

    def section(self, out: Emitter, folded: bool = False) -> None:
        """The actions of one scan, on the situation as it is now. ``folded``: the fast
        path's body (no chart flag set: the actions run, no ``SFCInit`` branch)."""
        g = self.g
        out("# 4-5. actions on the new situation, then supervision")
        roots: list[A.Node] = []
        for a in g.actions():
            roots += [x for x in (a.cond, a.event) if x is not None]
            roots += a.body or []
        self.exprs.sample_edges(out, roots)
        out("if True:" if folded else "if run and not paused:")
        out.indent()
        before = len(out.lines)
        self.ordered_actions(out)
        if len(out.lines) == before:
            out("pass")
        out.dedent()
        targets = list(bool_targets(self.g))
        if targets and not folded:
            out("elif not paused:  # SFCInit: no action executes, bool targets are off")
            out.indent()
            out(self.state.let(*(ident("v", t) for t in targets), value="False"))
            out.dedent()
