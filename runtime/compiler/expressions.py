"""Expressions as Python code: the chart's names as locals of the scan function or as
entries of the state list, the operators with IEC semantics, and the edges sampled once
a scan."""

from __future__ import annotations

from collections.abc import Callable

from runtime.compiler.emit import Emitter, ident
from runtime.compiler.layout import StateLayout
from runtime.compiler.program import step_time_code
from runtime.language import ast as A
from runtime.language.typecheck import CLOCK_PERIOD_NS

T = A.Type


def idiv(a: int, b: int) -> int:
    """IEC integer division: truncates toward zero."""
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b >= 0) else -q


def imod(a: int, b: int) -> int:
    """IEC MOD: the sign follows the dividend."""
    return a - b * idiv(a, b)


#: the helpers that generated expressions call, by the names they call them
HELPERS: dict[str, Callable[[int, int], int]] = {"_idiv": idiv, "_imod": imod}


class ExprEmitter:
    """Generates the code of expressions against one chart's state layout."""

    def __init__(self, state: StateLayout) -> None:
        self.state = state

    def ref_local(self, kind: str, name: str) -> str:
        """References to the scan function's locals (the usual code)."""
        if kind == "var":
            return ident("v", name)
        if kind == "X":
            return ident("x", name)
        if kind == "T":
            return step_time_code(ident("x", name), "ct", ident("t0", name),
                                  ident("tk", name))
        if kind == "block":
            return ident("b", name)
        if kind == "edge":
            return f"e{name}"
        if kind == "first":
            return "first"
        raise AssertionError(kind)

    def ref_state(self, kind: str, name: str) -> str:
        """References into the state list, for explain's probes (evaluated between scans)."""
        ix = self.state.index
        if kind == "var":
            return f"m[{ix[name]}]"
        if kind == "X":
            return f"m[{ix[name + '.X']}]"
        if kind == "T":
            return step_time_code(f"m[{ix[name + '.X']}]", f"m[{ix['#ct']}]",
                                  f"m[{ix[name + '.T0']}]", f"m[{ix[name + '.TK']}]")
        if kind == "block":
            return f"m[{ix[name]}]"
        if kind == "edge":
            return f"m[{ix[f'#edge{name}']}]"
        if kind == "first":
            return f"m[{ix['#first']}]"
        raise AssertionError(kind)

    def ex(self, n: A.Node, ref: Callable[[str, str], str] | None = None) -> str:
        r = ref or self.ref_local
        e = self.ex
        if isinstance(n, A.Lit):
            if n.type is T.BOOL:
                return "True" if n.value else "False"
            return repr(n.value)
        if isinstance(n, A.Name):
            if n.name == "FirstScan":
                return r("first", "")
            if n.name in CLOCK_PERIOD_NS:
                p = CLOCK_PERIOD_NS[n.name]
                return f"(up % {p} < {p // 2})"
            return r("var", n.name)
        if isinstance(n, A.StepFlag):
            return r(n.flag, n.step)
        if isinstance(n, A.Member):
            return f"{r('block', n.obj)}.{n.member}"
        if isinstance(n, A.MethodCall):
            return f"{r('block', n.obj)}.{n.method.lower()}(now)"
        if isinstance(n, A.Unary):
            if n.op == "NOT":
                return f"(not {e(n.operand, ref)})"
            if n.op == "NEG":
                return f"(-{e(n.operand, ref)})"
            return r("edge", str(self.state.edges[id(n)]))
        if isinstance(n, A.Binary):
            lhs, rhs = e(n.left, ref), e(n.right, ref)
            op = n.op
            if op == "OR":
                return f"({lhs} or {rhs})"
            if op == "AND":
                return f"({lhs} and {rhs})"
            if op == "XOR":
                return f"({lhs} != {rhs})"
            if op == "DIV":
                if n.type is T.REAL:
                    return f"({lhs} / {rhs})"
                if T.REAL in (n.left.type, n.right.type):
                    return f"int({lhs} / {rhs})"
                return f"_idiv({lhs}, {rhs})"
            if op == "MOD":
                return f"_imod({lhs}, {rhs})"
            if op == "MUL" and n.type is T.TIME and T.REAL in (n.left.type, n.right.type):
                return f"int({lhs} * {rhs})"
            sym = {"ADD": "+", "SUB": "-", "MUL": "*", "EQ": "==", "NE": "!=", "LT": "<",
                   "LE": "<=", "GT": ">", "GE": ">="}[op]
            return f"({lhs} {sym} {rhs})"
        raise AssertionError(type(n))

    def sample_edges(self, out: Emitter, roots: list[A.Node]) -> None:
        """Sample every edge below ``roots`` (inner edges first), once per scan."""
        found: list[A.Unary] = []
        for root in roots:
            for n in A.walk(root):
                if isinstance(n, A.Unary) and n.op in ("RE", "FE") and n not in found:
                    found.append(n)
        for n in reversed(found):
            k = self.state.edges[id(n)]
            cur = self.ex(n.operand)
            out(f"_c = {cur}")
            now = f"_c and not ep{k}" if n.op == "RE" else f"ep{k} and not _c"
            out(f"{self.state.let(f'e{k}', value=now)}; {self.state.let(f'ep{k}', value='_c')}")
