"""Syntax trees and transitions back to text: the one home of ``unparse``."""

from __future__ import annotations

from drivers.durations import format_ns
from runtime.language import ast as A
from runtime.language.model import Transition

T = A.Type
#: binary operators (the syntax tree's names) -> their ST spelling
COMPARE = {"EQ": "=", "NE": "<>", "LT": "<", "LE": "<=", "GT": ">", "GE": ">="}
ARITH = {"ADD": "+", "SUB": "-", "MUL": "*", "DIV": "/", "MOD": " MOD "}
LOGIC = {"OR": " OR ", "XOR": " XOR ", "AND": " AND "}
_PREFIX = {"NOT": "NOT ", "NEG": "-", "RE": "↑", "FE": "↓"}


def unparse(n: A.Node) -> str:
    """A canonical ST-like text of an expression: equal texts mean equal expressions."""
    if isinstance(n, A.Lit):
        if n.lit_type is T.TIME:
            return format_ns(int(n.value))
        if n.type is T.BOOL or n.lit_type is T.BOOL:
            return "1" if n.value else "0"
        return repr(n.value)
    if isinstance(n, A.Name):
        return n.name
    if isinstance(n, A.StepFlag):
        return f"{n.step}.{n.flag}"
    if isinstance(n, A.Member):
        return f"{n.obj}.{n.member}"
    if isinstance(n, A.MethodCall):
        return f"{n.obj}.{n.method}({', '.join(unparse(a) for a in n.args)})"
    if isinstance(n, A.Unary):
        inner = unparse(n.operand)
        op = _PREFIX[n.op]
        return f"{op}({inner})" if isinstance(n.operand, (A.Binary, A.Unary)) else op + inner
    if isinstance(n, A.Binary):
        op = COMPARE.get(n.op) or ARITH.get(n.op) or LOGIC.get(n.op) or n.op
        if n.op in COMPARE:
            op = f" {op} "
        return f"({unparse(n.left)}{op}{unparse(n.right)})"
    return f"<{type(n).__name__}@{n.start}>"


def transition_text(t: Transition) -> str:
    """``src -> dst when condition``, as the condition is written (explain, unstable)."""
    src = ",".join(t.sources) or "(source)"
    dst = ",".join(t.targets) or "(sink)"
    return f"{src} -> {dst} when {t.text}"
