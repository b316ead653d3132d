"""Syntax trees and transitions back to text: the one home of ``unparse``."""

from __future__ import annotations

from collections.abc import Callable

from drivers.durations import format_ns
from runtime.language import ast as A
from runtime.language.model import Transition

T = A.Type
#: binary operators (the syntax tree's names) -> their ST spelling
COMPARE = {"EQ": "=", "NE": "<>", "LT": "<", "LE": "<=", "GT": ">", "GE": ">="}
ARITH = {"ADD": "+", "SUB": "-", "MUL": "*", "DIV": "/", "MOD": " MOD "}
LOGIC = {"OR": " OR ", "XOR": " XOR ", "AND": " AND "}
_PREFIX = {"NOT": "NOT ", "NEG": "-", "RE": "↑", "FE": "↓"}


def atom_text(n: A.Node, argument: Callable[[A.Node], str]) -> str | None:
    """The text of a name, a step flag (``gsA.X``), a block member (``ton.Q``) or a method
    call (``timeX.Ini(...)``, its arguments written by ``argument``); None for any other
    node. Every notation writes them alike."""
    if isinstance(n, A.Name):
        return n.name
    if isinstance(n, A.StepFlag):
        return f"{n.step}.{n.flag}"
    if isinstance(n, A.Member):
        return f"{n.obj}.{n.member}"
    if isinstance(n, A.MethodCall):
        return f"{n.obj}.{n.method}({', '.join(argument(a) for a in n.args)})"
    return None


def unparse(n: A.Node) -> str:
    """A canonical ST-like text of an expression: equal texts mean equal expressions."""
    if isinstance(n, A.Lit):
        if n.lit_type is T.TIME:
            return format_ns(int(n.value))
        if n.type is T.BOOL or n.lit_type is T.BOOL:
            return "1" if n.value else "0"
        return repr(n.value)
    atom = atom_text(n, unparse)
    if atom is not None:
        return atom
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


# -- Structured Text -------------------------------------------------------------------------
#: binary operators -> (ST spelling, precedence level of language.md: 2 tightest .. 7)
_ST_BINARY = {"MUL": ("*", 2), "DIV": ("/", 2), "MOD": ("MOD", 2), "ADD": ("+", 3),
              "SUB": ("-", 3), **{op: (sym, 4) for op, sym in COMPARE.items()},
              "AND": ("AND", 5), "XOR": ("XOR", 6), "OR": ("OR", 7)}
_ST_PREFIX = {"NOT": "NOT ", "NEG": "-", "RE": "RE ", "FE": "FE "}
#: one level of indentation of ST statements
ST_INDENT = "    "


def st_text(n: A.Node) -> str:
    """An expression in Structured Text with the fewest parentheses the precedence table
    needs: ``AND OR XOR NOT``, ``T#10s``, ``TRUE``/``FALSE`` for bools (after type
    checking, so the seed's ``+`` and ``·`` between bools are ``OR`` and ``AND``). Edges
    are written ``RE x``/``FE x``, the language's own ASCII form (IEC 61131-3 has none in
    expressions). Parsed again in the same chart, the text gives the same typed tree."""
    return _st(n)[0]


def st_real(value: float) -> str:
    """A real in IEC 61131-3's form: digits, a point, digits (``1.0E-05``, not ``1e-05``)."""
    text = repr(value)
    if "e" in text:
        mantissa, exp = text.split("e")
        text = f"{mantissa if '.' in mantissa else mantissa + '.0'}E{exp}"
    return text


def _st_lit(n: A.Lit) -> str:
    if n.lit_type is T.TIME:
        return "T#" + format_ns(int(n.value))
    if n.type is T.BOOL or (n.type is None and n.lit_type is T.BOOL):
        return "TRUE" if n.value else "FALSE"
    if isinstance(n.value, float):
        return st_real(n.value)
    return str(int(n.value))


def _st(n: A.Node) -> tuple[str, int]:
    """(text, level): 0 an atom, 1 a prefix operator, then the binary levels."""
    if isinstance(n, A.Lit):
        text = _st_lit(n)
        return (f"({text})", 0) if text.startswith("-") else (text, 0)
    atom = atom_text(n, st_text)
    if atom is not None:
        return atom, 0
    if isinstance(n, A.Unary):
        inner, level = _st(n.operand)
        if level > 1 or (n.op == "NEG" and inner.startswith("-")):
            inner = f"({inner})"
        return _ST_PREFIX[n.op] + inner, 1
    if isinstance(n, A.Binary):
        sym, level = _ST_BINARY[n.op]
        left, llv = _st(n.left)
        right, rlv = _st(n.right)
        if llv > level or (llv == level == 4):
            left = f"({left})"
        if rlv >= level:
            right = f"({right})"
        return f"{left} {sym} {right}", level
    raise TypeError(f"no Structured Text for {type(n).__name__}")


def st_statements(body: list[A.Node], indent: str = "") -> str:
    """Statements in Structured Text, one per line, each ended by ``;``."""
    return "\n".join(_st_stmt(s, indent) for s in body)


def _st_block(body: list[A.Node], indent: str) -> list[str]:
    return [_st_stmt(s, indent) for s in body]


def _st_else(body: list[A.Node], indent: str) -> list[str]:
    return [f"{indent}ELSE", *_st_block(body, indent + ST_INDENT)] if body else []


def _st_stmt(s: A.Node, indent: str) -> str:
    inner = indent + ST_INDENT
    if isinstance(s, A.Assign):
        return f"{indent}{s.target.name} := {st_text(s.value)};"
    if isinstance(s, A.CallStmt):
        return f"{indent}{st_text(s.call)};"
    if isinstance(s, A.FbCall):
        args = ", ".join(f"{k} := {st_text(v)}" for k, v in s.args)
        return f"{indent}{s.block}({args});"
    if isinstance(s, A.If):
        lines: list[str] = []
        for i, (cond, body) in enumerate(s.branches):
            lines.append(f"{indent}{'IF' if i == 0 else 'ELSIF'} {st_text(cond)} THEN")
            lines += _st_block(body, inner)
        return "\n".join(lines + _st_else(s.orelse, indent) + [f"{indent}END_IF;"])
    if isinstance(s, A.Case):
        lines = [f"{indent}CASE {st_text(s.selector)} OF"]
        for labels, body in s.arms:
            text = ", ".join(str(lo) if lo == hi else f"{lo}..{hi}" for lo, hi in labels)
            lines.append(f"{inner}{text}:")
            lines += _st_block(body, inner + ST_INDENT)
        return "\n".join(lines + _st_else(s.orelse, indent) + [f"{indent}END_CASE;"])
    if isinstance(s, A.For):
        step = f" BY {st_text(s.step)}" if s.step is not None else ""
        lines = [f"{indent}FOR {s.var.name} := {st_text(s.first)} TO {st_text(s.last)}"
                 f"{step} DO"]
        lines += _st_block(s.body, inner)
        lines.append(f"{indent}END_FOR;")
        return "\n".join(lines)
    raise TypeError(f"no Structured Text for {type(s).__name__}")
