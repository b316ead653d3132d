"""Deciding conditions for ``softplc check``: can these conditions all be true at once?

A condition is evaluated over *atoms*, with Kleene three-valued logic (unknown = None) so
that a depth-first search over the atoms can prune as soon as a condition is decided:

- a bool variable, a step flag ``gsX.X``, or anything opaque (``timeX.End()``,
  ``tonDoor.Q``, a comparison that is not "term OP constant") is a bool atom;
- a numeric term compared with constants (``sCierres >= 1000``, ``gsAbrir.T < 10s``) is a
  numeric atom whose values are the constants and one value on each side of them, so that
  ``x >= 10`` and ``x < 10`` are found exclusive;
- an edge ``↑e`` is ``e`` now and not ``e`` in the previous scan: every atom under an edge
  also exists in its previous-scan version (``↑x`` and ``x'`` are exclusive, ``↑x`` and
  ``↓x`` too);
- a temporary assigned once at the top level of ``pre`` stands for its definition (the
  seed's ``tParo := iCerrado·sParo + (sCierres >= 1000)``), so witnesses name real inputs.

The search is exact (every combination is covered, with pruning) when the product of the
atoms' domains is at most 2**16; beyond that it stops after a budget of evaluations and says
the question is undecided.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from drivers.durations import format_ns
from runtime.language import ast as A
from runtime.language.model import Grafcet, VarKind
from runtime.language.unparse import ARITH, COMPARE, unparse

T = A.Type
EXACT_LIMIT = 1 << 16
BUDGET = 200_000


def has_edge(n: A.Node) -> bool:
    return any(isinstance(x, A.Unary) and x.op in ("RE", "FE") for x in A.walk(n))


# -- three-valued helpers ---------------------------------------------------------------
def _not(a: bool | None) -> bool | None:
    return None if a is None else not a


def _and(a: bool | None, b: bool | None) -> bool | None:
    if a is False or b is False:
        return False
    if a is None or b is None:
        return None
    return True


def _or(a: bool | None, b: bool | None) -> bool | None:
    if a is True or b is True:
        return True
    if a is None or b is None:
        return None
    return False


def _cmp(op: str, a: Any, b: Any) -> bool:
    if op == "EQ":
        return bool(a == b)
    if op == "NE":
        return bool(a != b)
    if op == "LT":
        return bool(a < b)
    if op == "LE":
        return bool(a <= b)
    if op == "GT":
        return bool(a > b)
    return bool(a >= b)


_FLIP = {"LT": "GT", "LE": "GE", "GT": "LT", "GE": "LE", "EQ": "EQ", "NE": "NE"}


@dataclass
class Atom:
    key: str  # canonical text of the term
    age: int  # 0 = this scan, 1 = previous scan, ...
    numeric: bool = False
    typ: A.Type = T.BOOL
    consts: set[Any] = field(default_factory=set)
    nonneg: bool = False  # step times
    domain: list[Any] = field(default_factory=list)

    def make_domain(self) -> None:
        if not self.numeric:
            self.domain = [False, True]
            return
        vals: set[Any] = set()
        cs = sorted(self.consts)
        if not cs:
            cs = [0]
        if self.typ is T.REAL:
            vals.update(cs)
            vals.add(cs[0] - 1.0)
            vals.add(cs[-1] + 1.0)
            for a, b in itertools.pairwise(cs):
                vals.add((a + b) / 2)
        elif self.typ is T.TIME:  # a scan lasts milliseconds: neighbours 1 ms away
            gaps = [b - a for a, b in itertools.pairwise(cs) if b > a]
            d = max(1, min([1_000_000, *(g // 2 for g in gaps)]))
            for c in cs:
                vals.update((c - d, c, c + d))
        else:
            for c in cs:
                vals.update((c - 1, c, c + 1))
        if self.nonneg:
            vals = {v for v in vals if v >= 0} or {0}
        self.domain = sorted(vals)

    def show(self, value: Any) -> str:
        if not self.numeric:
            v = "1" if value else "0"
        elif self.typ is T.TIME:
            v = format_ns(int(value))
        elif self.typ is T.REAL:
            v = f"{value:g}"
        else:
            v = str(value)
        key = self.key if re.fullmatch(r"[\w.]+(\(\))?", self.key) else f"[{self.key}]"
        return f"{key}={v}"


class Logic:
    """Atoms and evaluation of the conditions of one grafcet."""

    def __init__(self, g: Grafcet) -> None:
        self.g = g
        self.defs: dict[str, A.Node] = temporary_definitions(g)

    # -- term classification --------------------------------------------------------
    def resolve(self, n: A.Node, seen: frozenset[str] = frozenset()) -> A.Node:
        """A temporary with a single definition stands for that definition."""
        while isinstance(n, A.Name) and n.name in self.defs and n.name not in seen:
            seen = seen | {n.name}
            n = self.defs[n.name]
        return n

    def const(self, n: A.Node) -> Any:
        """The value of a constant expression, or None."""
        if isinstance(n, A.Lit):
            if n.type is T.BOOL:
                return 1 if n.value else 0
            return n.value
        if isinstance(n, A.Unary) and n.op == "NEG":
            v = self.const(n.operand)
            return None if v is None else -v
        if isinstance(n, A.Binary) and n.op in ARITH:
            a, b = self.const(n.left), self.const(n.right)
            if a is None or b is None:
                return None
            try:
                if n.op == "ADD":
                    return a + b
                if n.op == "SUB":
                    return a - b
                if n.op == "MUL":
                    return a * b
                if n.op == "DIV":
                    return a // b if isinstance(a, int) and isinstance(b, int) else a / b
                return a % b
            except (ZeroDivisionError, TypeError):
                return None
        return None

    def term(self, n: A.Node) -> tuple[str, A.Type, bool] | None:
        """(key, type, nonneg) if ``n`` is a simple numeric term."""
        n = self.resolve(n)
        if isinstance(n, A.Name):
            v = self.g.variables.get(n.name)
            typ = v.type if v is not None else n.type
            if typ in (T.INT, T.REAL, T.TIME):
                return n.name, typ, False
        if isinstance(n, A.StepFlag) and n.flag == "T":
            return f"{n.step}.T", T.TIME, True
        if isinstance(n, A.Member) and n.type in (T.INT, T.REAL, T.TIME):
            return unparse(n), n.type, n.type is T.TIME
        if isinstance(n, A.MethodCall) and n.method == "Val":
            return unparse(n), T.TIME, True
        return None

    def is_bool(self, n: A.Node) -> bool:
        n = self.resolve(n)
        if n.type is T.BOOL:
            return True
        return isinstance(n, A.Lit) and n.bool_like

    # -- evaluation --------------------------------------------------------------------
    def ev(self, n: A.Node, age: int, env: Env) -> bool | None:
        n = self.resolve(n)
        if isinstance(n, A.Lit):
            return bool(n.value)
        if isinstance(n, A.Name):
            return env.truth(n.name, age)
        if isinstance(n, A.StepFlag):
            if n.flag == "X" and age == 0 and n.step in env.true_steps:
                return True
            return env.truth(f"{n.step}.X", age)
        if isinstance(n, A.Unary):
            if n.op == "NOT":
                return _not(self.ev(n.operand, age, env))
            if n.op == "RE":
                return _and(self.ev(n.operand, age, env), _not(self.ev(n.operand, age + 1, env)))
            if n.op == "FE":
                return _and(_not(self.ev(n.operand, age, env)), self.ev(n.operand, age + 1, env))
        if isinstance(n, A.Binary):
            if n.op == "AND":
                a = self.ev(n.left, age, env)
                return False if a is False else _and(a, self.ev(n.right, age, env))
            if n.op == "OR":
                a = self.ev(n.left, age, env)
                return True if a is True else _or(a, self.ev(n.right, age, env))
            if n.op == "XOR":
                a, b = self.ev(n.left, age, env), self.ev(n.right, age, env)
                return None if a is None or b is None else a != b
            if n.op in COMPARE:
                return self._compare(n, age, env)
        return env.truth(unparse(n), age)

    def _compare(self, n: A.Binary, age: int, env: Env) -> bool | None:
        simple = self._simple(n)
        if simple is not None:
            key, op, c = simple
            v = env.get(key, age)
            return None if v is None else _cmp(op, v, c)
        if self.is_bool(n.left) and self.is_bool(n.right):
            a, b = self.ev(n.left, age, env), self.ev(n.right, age, env)
            return None if a is None or b is None else _cmp(n.op, int(a), int(b))
        return env.truth(unparse(n), age)

    def _simple(self, n: A.Binary) -> tuple[str, str, Any] | None:
        """``term OP constant`` (either way round) as (key, op, constant)."""
        for term_side, const_side, op in ((n.left, n.right, n.op),
                                          (n.right, n.left, _FLIP[n.op])):
            t = self.term(term_side)
            c = self.const(self.resolve(const_side))
            if t is not None and c is not None:
                return t[0], op, c
        return None

    # -- atoms -------------------------------------------------------------------------
    def atoms(self, nodes: Iterable[A.Node], true_steps: Iterable[str] = ()) -> list[Atom]:
        """Every atom the nodes read, in order of first appearance."""
        out: dict[tuple[str, int], Atom] = {}
        steps = set(true_steps)

        def add(key: str, age: int, **kw: Any) -> Atom:
            a = out.get((key, age))
            if a is None:
                a = out[(key, age)] = Atom(key, age, **kw)
            return a

        def visit(n: A.Node, age: int, seen: frozenset[str]) -> None:
            if isinstance(n, A.Name) and n.name in self.defs and n.name not in seen:
                visit(self.defs[n.name], age, seen | {n.name})
                return
            if isinstance(n, A.Lit):
                return
            if isinstance(n, A.Name):
                add(n.name, age)
                return
            if isinstance(n, A.StepFlag):
                if not (n.flag == "X" and age == 0 and n.step in steps):
                    add(f"{n.step}.X", age)
                return
            if isinstance(n, A.Unary) and n.op in ("NOT", "RE", "FE"):
                visit(n.operand, age, seen)
                if n.op != "NOT":
                    visit(n.operand, age + 1, seen)
                return
            if isinstance(n, A.Binary) and n.op in ("AND", "OR", "XOR"):
                visit(n.left, age, seen)
                visit(n.right, age, seen)
                return
            if isinstance(n, A.Binary) and n.op in COMPARE:
                simple = self._simple(n)
                if simple is not None:
                    key, _, c = simple
                    t = self.term(n.left) or self.term(n.right)
                    assert t is not None
                    a = add(key, age, numeric=True, typ=t[1], nonneg=t[2])
                    a.consts.add(c)
                    return
                if self.is_bool(n.left) and self.is_bool(n.right):
                    visit(n.left, age, seen)
                    visit(n.right, age, seen)
                    return
            add(unparse(n), age)

        for n in nodes:
            visit(n, 0, frozenset())
        result = list(out.values())
        for a in result:
            a.make_domain()
        return result

    # -- the search -------------------------------------------------------------------
    def solve(self, conds: Sequence[tuple[A.Node, bool]], true_steps: Iterable[str] = (),
              budget: int = BUDGET) -> Result:
        """Find values of the atoms making every ``cond`` equal to its wanted value."""
        steps = frozenset(true_steps)
        atoms = self.atoms([c for c, _ in conds], steps)
        space = 1
        for a in atoms:
            space *= len(a.domain)
        exact = space <= EXACT_LIMIT
        env = Env(steps)
        count = 0

        def status() -> bool | None:
            result: bool | None = True
            for c, want in conds:
                v = self.ev(c, 0, env)
                if v is None:
                    result = None
                elif v != want:
                    return False
            return result

        def dfs(i: int) -> bool | None:
            nonlocal count
            count += 1
            if not exact and count > budget:
                return None
            s = status()
            if s is True:
                return True
            if s is False or i == len(atoms):
                return False
            a = atoms[i]
            undecided = False
            for v in a.domain:
                env.values[(a.key, a.age)] = v
                r = dfs(i + 1)
                if r is True:
                    return True
                if r is None:
                    undecided = True
                    break
            del env.values[(a.key, a.age)]
            return None if undecided else False

        r = dfs(0)
        if r is True:
            for a in atoms:  # leave out what the conditions do not need
                key = (a.key, a.age)
                if key in env.values:
                    v = env.values.pop(key)
                    if status() is not True:
                        env.values[key] = v
            witness = [(a, env.values[(a.key, a.age)]) for a in atoms
                       if (a.key, a.age) in env.values]
            return Result(True, witness, len(atoms), exact)
        return Result(False if r is False else None, [], len(atoms), exact)


@dataclass
class Env:
    true_steps: frozenset[str]
    values: dict[tuple[str, int], Any] = field(default_factory=dict)

    def get(self, key: str, age: int) -> Any:
        return self.values.get((key, age))

    def truth(self, key: str, age: int) -> bool | None:
        """A bool atom's value (None: not assigned yet)."""
        v = self.values.get((key, age))
        return None if v is None else bool(v)


@dataclass
class Result:
    sat: bool | None  # None: undecided within the budget
    witness: list[tuple[Atom, Any]]
    atoms: int
    exact: bool

    def show(self) -> str:
        """``iAbierto=1, gsAbrir.T=10s, iMarcha=1 (previous scan 0)``."""
        now: dict[str, tuple[Atom, Any]] = {}
        before: dict[str, list[tuple[int, Atom, Any]]] = {}
        for a, v in self.witness:
            if a.age == 0:
                now[a.key] = (a, v)
            else:
                before.setdefault(a.key, []).append((a.age, a, v))
        parts = []
        keys = list(dict.fromkeys([a.key for a, _ in self.witness]))
        for k in keys:
            if k in now:
                a, v = now[k]
                text = a.show(v)
            else:
                text = f"{k} unchanged"
            if k in before:
                prev = ", ".join(
                    (f"previous scan {a.show(v).rsplit('=', 1)[1]}" if age == 1 else
                     f"{age} scans ago {a.show(v).rsplit('=', 1)[1]}")
                    for age, a, v in sorted(before[k], key=lambda x: x[0]))
                if k in now:
                    text += f" ({prev})"
                else:
                    text = f"{k}: {prev}"
            parts.append(text)
        return ", ".join(parts) if parts else "any values"


def temporary_definitions(g: Grafcet) -> dict[str, A.Node]:
    """Temporaries assigned exactly once in the whole program, at the top level of pre."""
    counts: dict[str, int] = {}
    defs: dict[str, A.Node] = {}

    def count_assign(nodes: Iterable[A.Node]) -> None:
        for top in nodes:
            for n in A.walk(top):
                if isinstance(n, A.Assign):
                    counts[n.target.name] = counts.get(n.target.name, 0) + 1
                elif isinstance(n, A.For):
                    counts[n.var.name] = counts.get(n.var.name, 0) + 2
                elif isinstance(n, A.MethodCall) and n.method == "Set":
                    counts[n.obj] = counts.get(n.obj, 0) + 2

    count_assign(s.node for s in g.pre)
    count_assign(s.node for s in g.post)
    for act in g.actions():
        count_assign(act.body or [])
    temps = {v.name for v in g.variables.values() if v.kind is VarKind.TEMP}
    for s in g.pre:
        n = s.node
        if isinstance(n, A.Assign) and n.target.name in temps and (
                counts.get(n.target.name) == 1):
            reads = {x.name for x in A.walk(n.value) if isinstance(x, A.Name)} & temps
            # a temporary read before its own assignment holds last scan's value: keep it opaque
            if reads <= set(defs):
                defs[n.target.name] = n.value
    return defs
