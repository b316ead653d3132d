"""Syntax tree of expressions and statements; each node knows its span in the source text."""

from __future__ import annotations

import enum
from collections.abc import Iterator
from dataclasses import dataclass, field


class Type(enum.Enum):
    """Implicit types of the language (seed 000: the context decides)."""

    BOOL = "bool"
    INT = "int"
    REAL = "real"
    TIME = "time"  # integer nanoseconds at run time
    STRING = "string"

    def __str__(self) -> str:
        return self.value


@dataclass(eq=False, slots=True)
class Node:
    start: int  # offset of the first character in the source string
    end: int  # offset past the last character
    type: Type | None = field(default=None, init=False)


@dataclass(eq=False, slots=True)
class Lit(Node):
    value: bool | int | float
    lit_type: Type  # BOOL, INT, REAL or TIME
    bool_like: bool = False  # 0 or 1: usable as a bool constant too


@dataclass(eq=False, slots=True)
class Name(Node):
    name: str


@dataclass(eq=False, slots=True)
class StepFlag(Node):
    step: str
    flag: str  # "X" or "T"


@dataclass(eq=False, slots=True)
class Member(Node):
    obj: str  # a function-block instance
    member: str


@dataclass(eq=False, slots=True)
class MethodCall(Node):
    obj: str
    method: str  # Ini End Reset Val Set
    args: list[Node]


@dataclass(eq=False, slots=True)
class Unary(Node):
    op: str  # NOT NEG RE FE
    operand: Node
    text: str = ""  # operator as written: ' NOT ! ↑ RE ...


@dataclass(eq=False, slots=True)
class Binary(Node):
    op: str  # OR XOR AND ADD SUB MUL DIV MOD EQ NE LT LE GT GE
    left: Node
    right: Node
    text: str = ""  # operator as written


@dataclass(eq=False, slots=True)
class Assign(Node):
    target: Name
    value: Node


@dataclass(eq=False, slots=True)
class CallStmt(Node):
    call: MethodCall


@dataclass(eq=False, slots=True)
class FbCall(Node):
    block: str
    args: list[tuple[str, Node]]


@dataclass(eq=False, slots=True)
class If(Node):
    branches: list[tuple[Node, list[Node]]]
    orelse: list[Node]


@dataclass(eq=False, slots=True)
class Case(Node):
    selector: Node
    arms: list[tuple[list[tuple[int, int]], list[Node]]]
    orelse: list[Node]


@dataclass(eq=False, slots=True)
class For(Node):
    var: Name
    first: Node
    last: Node
    step: Node | None
    body: list[Node]


def walk(node: Node) -> Iterator[Node]:
    """Yield ``node`` and every node below it, parents first."""
    yield node
    if isinstance(node, Unary):
        yield from walk(node.operand)
    elif isinstance(node, Binary):
        yield from walk(node.left)
        yield from walk(node.right)
    elif isinstance(node, MethodCall):
        for a in node.args:
            yield from walk(a)
    elif isinstance(node, Assign):
        yield from walk(node.target)
        yield from walk(node.value)
    elif isinstance(node, CallStmt):
        yield from walk(node.call)
    elif isinstance(node, FbCall):
        for _, a in node.args:
            yield from walk(a)
    elif isinstance(node, If):
        for c, body in node.branches:
            yield from walk(c)
            for s in body:
                yield from walk(s)
        for s in node.orelse:
            yield from walk(s)
    elif isinstance(node, Case):
        yield from walk(node.selector)
        for _, body in node.arms:
            for s in body:
                yield from walk(s)
        for s in node.orelse:
            yield from walk(s)
    elif isinstance(node, For):
        yield from walk(node.var)
        yield from walk(node.first)
        yield from walk(node.last)
        if node.step is not None:
            yield from walk(node.step)
        for s in node.body:
            yield from walk(s)
