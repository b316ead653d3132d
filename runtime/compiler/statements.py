"""Statements as Python code: assignments (with the value converted to the variable's
type), block calls and methods, IF, CASE, and FOR bounded by its limit and step."""

from __future__ import annotations

from runtime.compiler.emit import Emitter, ident
from runtime.compiler.expressions import ExprEmitter
from runtime.compiler.layout import StateLayout
from runtime.language import ast as A
from runtime.language.model import Grafcet

T = A.Type


class StmtEmitter:
    """Generates the code of statements; CASE and FOR number their temporaries."""

    def __init__(self, g: Grafcet, state: StateLayout, exprs: ExprEmitter) -> None:
        self.g = g
        self.state = state
        self.exprs = exprs
        self.tmp = 0  # temporaries used so far: _sel1, _last2 ...

    def converted(self, vt: A.Type | None, value: A.Node) -> str:
        """``value`` as stored into a variable of type ``vt`` (bool -> 0/1, int -> real)."""
        code, et = self.exprs.ex(value), value.type
        if vt is T.INT and et is T.BOOL:
            return f"int({code})"
        if vt is T.REAL and et in (T.INT, T.BOOL):
            return f"float({code})"
        return code

    def stmt(self, out: Emitter, s: A.Node) -> None:
        if isinstance(s, A.Assign):
            value = self.converted(s.target.type, s.value)
            out(self.state.let(ident("v", s.target.name), value=value))
        elif isinstance(s, A.CallStmt):
            c = s.call
            if c.method == "Set":
                var = self.g.variables.get(c.obj)
                value = self.converted(var.type if var else None, c.args[0])
                out(f"if {self.exprs.ex(c.args[1])}: "
                    f"{self.state.let(ident('v', c.obj), value=value)}")
            elif c.method == "Ini":
                out(f"{ident('b', c.obj)}.ini(now, {self.exprs.ex(c.args[0])})")
            else:
                out(f"{ident('b', c.obj)}.reset()")
        elif isinstance(s, A.FbCall):
            b = ident("b", s.block)
            for arg, val in s.args:
                out(f"{b}.{arg} = {self.exprs.ex(val)}")
            out(f"{b}.update(now)")
        elif isinstance(s, A.If):
            for i, (cond, body) in enumerate(s.branches):
                out(f"{'if' if i == 0 else 'elif'} {self.exprs.ex(cond)}:")
                self.block(out, body)
            if s.orelse:
                out("else:")
                self.block(out, s.orelse)
        elif isinstance(s, A.Case):
            self.tmp += 1
            sel = f"_sel{self.tmp}"
            out(f"{sel} = {self.exprs.ex(s.selector)}")
            for i, (labels, body) in enumerate(s.arms):
                tests = " or ".join(f"{sel} == {lo}" if lo == hi else f"{lo} <= {sel} <= {hi}"
                                    for lo, hi in labels)
                out(f"{'if' if i == 0 else 'elif'} {tests}:")
                self.block(out, body)
            if s.orelse:
                out("else:" if s.arms else "if True:")
                self.block(out, s.orelse)
        elif isinstance(s, A.For):
            self.tmp += 1
            k = self.tmp
            v = ident("v", s.var.name)
            last, by = self.exprs.ex(s.last), self.exprs.ex(s.step) if s.step else 1
            out(f"_last{k} = {last}; _by{k} = {by}")
            out(f"if _by{k} == 0: raise ZeroDivisionError('FOR loop with BY 0')")
            out(self.state.let(v, value=self.exprs.ex(s.first)))
            out(f"while ({v} <= _last{k}) if _by{k} > 0 else ({v} >= _last{k}):")
            self.block(out, s.body, extra=self.state.add(v, f"_by{k}"))
        else:  # pragma: no cover
            raise AssertionError(type(s))

    def block(self, out: Emitter, body: list[A.Node], extra: str | None = None) -> None:
        out.indent()
        if not body and extra is None:
            out("pass")
        for s in body:
            self.stmt(out, s)
        if extra:
            out(extra)
        out.dedent()
