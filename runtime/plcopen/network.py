"""A transition condition drawn in FBD or LD, as an expression: variables (``inVariable``),
contacts (normally open or closed, rising or falling edge), contacts in series (AND) and in
parallel (OR) from the left power rail, connectors and continuations, and the gates AND, OR,
XOR and NOT. Anything else in the network (a TON, an arithmetic block ...) is refused at its
place: softplc carries a condition only as an expression."""

from __future__ import annotations

import re

from runtime.errors import Loc, SourceError
from runtime.language.yamlsrc import YStr
from runtime.plcopen.schema import PLCOPEN_NS
from runtime.plcopen.sfcgraph import connections, local_id
from runtime.plcopen.texts import compose
from runtime.plcopen.xmltree import Element

#: the longest chain of FBD/LD elements a condition may be
MAX_CHAIN = 200
#: FBD gates carried, and how many inputs they take (0: any)
GATES = {"AND": 0, "OR": 0, "XOR": 0, "NOT": 1}
_TRUE = "TRUE"


class Network:
    """The FBD/LD elements of one body, by localId (for connections() they stand as a
    Level: ``elements`` is all it reads)."""

    def __init__(self, body: Element) -> None:
        self.elements: dict[int, Element] = {}
        for e in body.children:
            if e.ns == PLCOPEN_NS and e.get("localId") is not None:
                self.elements.setdefault(local_id(e), e)
        self.connectors: dict[str, Element] = {
            (e.get("name") or "").lower(): e for e in self.elements.values()
            if e.tag == "connector"}
        self.used: set[int] = set()  # the elements some condition was read from

    def point(self, point: Element, trail: tuple[int, ...] = ()) -> YStr:
        """The expression feeding a connection point (several connections: their OR)."""
        conns = connections(point, self.elements)
        if not conns:
            raise SourceError(point.loc, "a condition's connection point connects to nothing")
        parts = [self.element(ref, trail) for ref, _ in conns]
        if len(parts) == 1:
            return parts[0]
        return _join(parts, "OR", point.loc)

    def element(self, ref: int, trail: tuple[int, ...]) -> YStr:
        e = self.elements[ref]
        if ref in trail:
            cycle = " -> ".join(map(str, (*trail[trail.index(ref):], ref)))
            raise SourceError(e.loc, f"cycle in refLocalId: {cycle} (a condition's network "
                                     "must start at variables or at the left power rail)")
        trail = (*trail, ref)
        self.used.add(ref)
        if len(trail) > MAX_CHAIN:
            raise SourceError(e.loc, f"a transition's condition network more than {MAX_CHAIN} "
                                     "elements long: write the condition in ST")
        if e.tag == "leftPowerRail":
            return compose([_TRUE], e.loc)
        if e.tag in ("inVariable", "inOutVariable"):
            expr = e.find("expression", PLCOPEN_NS)
            if expr is None or not expr.text.strip():
                raise SourceError(e.loc, f"localId {ref}: {e.tag} without an expression")
            return _modified(e, expr.ystr())
        if e.tag == "contact":
            var = e.find("variable", PLCOPEN_NS)
            if var is None or not var.text.strip():
                raise SourceError(e.loc, f"localId {ref}: contact without a variable")
            me = _modified(e, var.ystr())
            cin = e.find("connectionPointIn", PLCOPEN_NS)
            if cin is None or not cin.findall("connection", PLCOPEN_NS):
                return me
            before = self.point(cin, trail)
            if str(before) == _TRUE:
                return me
            return _join([before, me], "AND", e.loc)
        if e.tag == "continuation":
            source = self.connectors.get((e.get("name") or "").lower())
            cin = source.find("connectionPointIn", PLCOPEN_NS) if source else None
            if source is None or cin is None:
                raise SourceError(e.loc, f"localId {ref}: continuation '{e.get('name')}' has "
                                         "no connector of that name")
            self.used.add(local_id(source))
            return self.point(cin, (*trail, local_id(source)))
        if e.tag == "block" and (e.get("typeName") or "").upper() in GATES:
            return self.gate(e, ref, trail)
        what = f"{e.tag} {e.get('typeName')}" if e.get("typeName") else e.tag
        raise SourceError(e.loc, f"localId {ref}: a {what} in a transition's condition: "
                          "softplc carries variables, contacts (in series and in parallel) "
                          "and the gates AND, OR, XOR, NOT; write the condition in ST")

    def gate(self, e: Element, ref: int, trail: tuple[int, ...]) -> YStr:
        op = (e.get("typeName") or "").upper()
        ins = e.find("inputVariables", PLCOPEN_NS)
        parts = []
        for v in ins.findall("variable", PLCOPEN_NS) if ins is not None else []:
            cin = v.find("connectionPointIn", PLCOPEN_NS)
            if cin is None:
                raise SourceError(v.loc, f"localId {ref}: input {v.get('formalParameter')} of "
                                         f"{op} is not connected")
            parts.append(_modified(v, self.point(cin, trail)))
        if not parts or (GATES[op] and len(parts) != GATES[op]):
            raise SourceError(e.loc, f"localId {ref}: {op} with {len(parts)} inputs")
        if op == "NOT":
            return compose(["NOT ", *_paren(parts[0], e.loc)], e.loc)
        out = _join(parts, op, e.loc)
        outs = e.find("outputVariables", PLCOPEN_NS)
        first = outs.find("variable", PLCOPEN_NS) if outs is not None else None
        if first is not None and first.get("negated") == "true":
            out = compose(["NOT ", *_paren(out, e.loc)], e.loc)
        return out


#: operands that need no parentheses: of NOT, RE and FE a name (or ``step.X``); of AND,
#: OR and XOR also a name negated or edged
_NAME = re.compile(r"^\w+(\.\w+)?$")
_OPERAND = re.compile(r"^((NOT|RE|FE) )?\w+(\.\w+)?$")


def _paren(text: YStr, at: Loc, atom: re.Pattern[str] = _NAME) -> list[str | YStr]:
    """``text`` as an operand: in parentheses unless ``atom`` matches it."""
    return [text] if atom.match(str(text)) else ["(", text, ")"]


def _join(parts: list[YStr], op: str, at: Loc) -> YStr:
    pieces: list[str | YStr] = []
    for i, p in enumerate(parts):
        if i:
            pieces.append(f" {op} ")
        pieces += _paren(p, at, _OPERAND)
    return compose(pieces, at)


def _modified(e: Element, text: YStr) -> YStr:
    """``text`` with the element's ``negated`` and ``edge`` attributes applied (an edge
    first, then the negation: a negated rising-edge contact is NOT RE x)."""
    edge = e.get("edge", "none")
    if e.get("storage", "none") not in ("none", None):
        raise SourceError(e.loc, f"a {e.tag} with storage '{e.get('storage')}' in a "
                                 "transition's condition: set and reset have no meaning there")
    out = text
    if edge in ("rising", "falling"):
        out = compose(["RE " if edge == "rising" else "FE ", *_paren(out, e.loc)], e.loc)
    if e.get("negated") == "true":
        out = compose(["NOT ", *_paren(out, e.loc)], e.loc)
    return out
