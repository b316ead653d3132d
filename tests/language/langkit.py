"""Language-test kit: load chart text, canonical trees, an unparser, error helpers."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

import pytest

from drivers.durations import format_ns as format_time
from runtime.compiler.codegen import compile_grafcet
from runtime.engine.instance import Instance
from runtime.errors import Loc, SourceError
from runtime.language import ast as A
from runtime.language.grafcetfile import GrafcetLoader, load_grafcet
from runtime.language.model import Grafcet
from runtime.language.parser import (
    ParsedAction,
    parse_action,
    parse_expression,
    parse_statements,
)
from runtime.language.yamlsrc import load_yaml

S = 1_000_000_000
MS = 1_000_000


def _loc(offset: int) -> Loc:
    return Loc("<expr>", 1, offset + 1)


# -- parsing snippets ----------------------------------------------------------------
def expr(text: str) -> A.Node:
    """Parse one expression (columns are offset + 1 on line 1 of '<expr>')."""
    return parse_expression(text, _loc)


def stmts(text: str) -> list[A.Node]:
    return parse_statements(text, _loc)


def action(text: str) -> ParsedAction:
    return parse_action(text, _loc)


def tree(n: Any) -> Any:
    """A canonical, comparable form of a syntax tree (spans and written forms left out)."""
    if isinstance(n, list):
        return [tree(x) for x in n]
    if isinstance(n, A.Lit):
        return ("lit", n.value, n.lit_type.value)
    if isinstance(n, A.Name):
        return n.name
    if isinstance(n, A.StepFlag):
        return ("flag", n.step, n.flag)
    if isinstance(n, A.Member):
        return ("member", n.obj, n.member)
    if isinstance(n, A.MethodCall):
        return ("call", n.obj, n.method, tree(n.args))
    if isinstance(n, A.Unary):
        return (n.op, tree(n.operand))
    if isinstance(n, A.Binary):
        return (n.op, tree(n.left), tree(n.right))
    if isinstance(n, A.Assign):
        return (":=", n.target.name, tree(n.value))
    if isinstance(n, A.CallStmt):
        return ("stmt", tree(n.call))
    if isinstance(n, A.FbCall):
        return ("fb", n.block, [(k, tree(v)) for k, v in n.args])
    if isinstance(n, A.If):
        return ("IF", [(tree(c), tree(b)) for c, b in n.branches], tree(n.orelse))
    if isinstance(n, A.Case):
        return ("CASE", tree(n.selector), [(list(lb), tree(b)) for lb, b in n.arms],
                tree(n.orelse))
    if isinstance(n, A.For):
        return ("FOR", n.var.name, tree(n.first), tree(n.last),
                None if n.step is None else tree(n.step), tree(n.body))
    raise TypeError(type(n))


# -- the unparser: syntax tree -> fully parenthesised ST text -------------------------
_BIN_TEXT = {"OR": "OR", "XOR": "XOR", "AND": "AND", "ADD": "+", "SUB": "-", "MUL": "*",
             "DIV": "/", "MOD": "MOD", "EQ": "=", "NE": "<>", "LT": "<", "LE": "<=",
             "GT": ">", "GE": ">="}
_UN_TEXT = {"NOT": "NOT ", "RE": "RE ", "FE": "FE ", "NEG": "-"}


def unparse(n: Any, sep: str = "; ") -> str:
    """Fully parenthesised text of an expression, a statement or a list of statements."""
    if isinstance(n, list):
        return "".join(unparse(s, sep) + sep for s in n)
    if isinstance(n, A.Lit):
        if n.lit_type is A.Type.BOOL:
            return "TRUE" if n.value else "FALSE"
        if n.lit_type is A.Type.TIME:
            return format_time(int(n.value))
        if n.lit_type is A.Type.REAL:
            return repr(float(n.value))
        return str(int(n.value))
    if isinstance(n, A.Name):
        return n.name
    if isinstance(n, A.StepFlag):
        return f"{n.step}.{n.flag}"
    if isinstance(n, A.Member):
        return f"{n.obj}.{n.member}"
    if isinstance(n, A.MethodCall):
        return f"{n.obj}.{n.method}({', '.join(unparse(a) for a in n.args)})"
    if isinstance(n, A.Unary):
        return f"({_UN_TEXT[n.op]}{unparse(n.operand)})"
    if isinstance(n, A.Binary):
        return f"({unparse(n.left)} {_BIN_TEXT[n.op]} {unparse(n.right)})"
    if isinstance(n, A.Assign):
        return f"{n.target.name} := {unparse(n.value)}"
    if isinstance(n, A.CallStmt):
        return unparse(n.call)
    if isinstance(n, A.FbCall):
        return f"{n.block}({', '.join(f'{k} := {unparse(v)}' for k, v in n.args)})"
    if isinstance(n, A.If):
        out = ""
        for i, (c, body) in enumerate(n.branches):
            out += f"{'IF' if i == 0 else 'ELSIF'} {unparse(c)} THEN {unparse(body, sep)}"
        if n.orelse:
            out += f"ELSE {unparse(n.orelse, sep)}"
        return out + "END_IF"
    if isinstance(n, A.Case):
        out = f"CASE {unparse(n.selector)} OF "
        for labels, body in n.arms:
            lab = ", ".join(str(lo) if lo == hi else f"{lo}..{hi}" for lo, hi in labels)
            out += f"{lab}: {unparse(body, sep)}"
        if n.orelse:
            out += f"ELSE {unparse(n.orelse, sep)}"
        return out + "END_CASE"
    if isinstance(n, A.For):
        by = "" if n.step is None else f" BY {unparse(n.step)}"
        return (f"FOR {n.var.name} := {unparse(n.first)} TO {unparse(n.last)}{by} DO "
                f"{unparse(n.body, sep)}END_FOR")
    raise TypeError(type(n))


def assert_round_trip_expr(text: str) -> A.Node:
    """Parse, unparse, reparse: the same tree; unparsing again gives the same text."""
    first = expr(text)
    printed = unparse(first)
    again = expr(printed)
    assert tree(again) == tree(first), (text, printed)
    assert unparse(again) == printed
    return first


def assert_round_trip_stmts(text: str) -> list[A.Node]:
    first = stmts(text)
    for sep in ("; ", "\n"):
        printed = unparse(first, sep)
        again = stmts(printed)
        assert tree(again) == tree(first), (text, printed)
        assert unparse(again, sep) == printed
    return first


# -- whole charts ------------------------------------------------------------------------
def load_text(text: str, path: str = "chart.yaml") -> Grafcet:
    """Load a grafcet from text (dedented), without touching the disk."""
    doc = load_yaml(path, textwrap.dedent(text))
    return GrafcetLoader(path, doc).load()


def write(tmp_path: Path, name: str, text: str) -> str:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text), encoding="utf-8")
    return str(p)


def run(text: str, scans: list[dict[str, Any]], keys: list[str],
        cycle_ns: int = 10 * MS) -> list[list[Any]]:
    """Compile a chart, scan it once per dict of inputs, return ``keys`` after each scan."""
    inst = Instance("t", compile_grafcet(load_text(text)))
    out = []
    for k, values in enumerate(scans):
        for name, v in values.items():
            inst.set(name, v)
        inst.scan(1_000 * S + k * cycle_ns, k * cycle_ns)
        out.append([inst.get(key) for key in keys])
    return out


# -- errors ------------------------------------------------------------------------------
def where(text: str, needle: str, nth: int = 0, plus: int = 0) -> tuple[int, int]:
    """(line, col), 1-based, of the ``nth`` occurrence of ``needle`` in dedented ``text``,
    ``plus`` characters further on the same line."""
    text = textwrap.dedent(text)
    pos = -1
    for _ in range(nth + 1):
        pos = text.index(needle, pos + 1)
    line = text.count("\n", 0, pos) + 1
    col = pos - (text.rfind("\n", 0, pos) + 1) + 1
    return line, col + plus


def load_error(text: str, path: str = "chart.yaml") -> SourceError:
    """The SourceError that loading ``text`` raises."""
    with pytest.raises(SourceError) as info:
        load_text(text, path)
    return info.value


def file_error(path: str) -> SourceError:
    """The SourceError that loading the grafcet or plant file ``path`` raises."""
    from runtime.language.plantfile import load_plant

    with pytest.raises(SourceError) as info:
        doc = load_yaml(path)
        if {"instances", "drivers", "plc"} & set(doc):
            load_plant(path)
        else:
            load_grafcet(path)
    return info.value


def assert_error(err: SourceError, file: str, at: tuple[int, int], *words: str) -> None:
    """The error is at ``file:line:col`` and its message holds every one of ``words``."""
    assert (err.loc.file, err.loc.line, err.loc.col) == (file, *at), str(err)
    for w in words:
        assert w in err.message, f"{w!r} not in {err.message!r}"
    assert str(err).startswith(f"{file}:{at[0]}:{at[1]}: error: ")
