"""An FBD or LD network read as Structured Text: a transition's condition as an expression,
an action's body as statements.

Carried: variables (``inVariable``, ``inOutVariable``), contacts (normally open or closed,
rising or falling edge), contacts in series (AND) and in parallel (OR) from the left power
rail, connectors and continuations, coils (plain, negated, set, reset, edges), the gates AND,
OR, XOR, NOT, the comparisons and arithmetic blocks (GT GE EQ NE LE LT, ADD SUB MUL DIV MOD,
MOVE), and the instances of the function blocks the language has (TON TOF TP CTU CTD CTUD
R_TRIG F_TRIG SR RS) declared in the POU. Every block instance is called once, where the
network first needs one of its outputs, after the blocks that feed it (Beremiz's generator
does the same): a block that feeds itself back through another reads its previous output.
The calls are ``program``, in that order; where they run is the importer's choice
(docs/plcopen.md). Anything else is refused at its place.

Every text read from the file goes through the language's lexer before it is placed: a
name where a name is expected, an expression (no statement, no comment) where an expression
is; so a network becomes ST text the language's own parser reads, never anything else.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from functools import cmp_to_key

from runtime.errors import Loc, SourceError
from runtime.language.lexer import KEYWORDS, Lexer, is_name
from runtime.language.signatures import FB_MEMBERS
from runtime.language.yamlsrc import YStr
from runtime.plcopen.schema import PLCOPEN_NS
from runtime.plcopen.sfcgraph import connections, local_id, position
from runtime.plcopen.texts import compose, plain
from runtime.plcopen.xmltree import Element

#: the longest chain of FBD/LD elements a condition may be
MAX_CHAIN = 200
#: FBD gates carried, and how many inputs they take (0: any)
GATES = {"AND": 0, "OR": 0, "XOR": 0, "NOT": 1}
#: functions carried as operators: name -> (operator, number of inputs, 0: two or more)
FUNCTIONS = {"GT": (">", 2), "GE": (">=", 2), "EQ": ("=", 2), "NE": ("<>", 2),
             "LE": ("<=", 2), "LT": ("<", 2), "ADD": ("+", 0), "MUL": ("*", 0),
             "SUB": ("-", 2), "DIV": ("/", 2), "MOD": (" MOD ", 2), "MOVE": ("", 1)}
_TRUE = "TRUE"


class NotCarried(SourceError):
    """An element the language has no form for (a jump, a block of another type): in a
    condition an error; an action holding it is left out with a warning."""


#: a block the importer resolves itself (a program's instance of an imported chart): given
#: the block, its localId, the output asked for and the trail, its output's text
Resolver = Callable[["Network", Element, int, str | None, tuple[int, ...]], YStr]


class Network:
    """The FBD/LD elements of one body, by localId (for connections() they stand as a
    Level: ``elements`` is all it reads); ``blocks``: the POU's function block instances,
    by their name in lower case, as (name as declared, type)."""

    def __init__(self, body: Element, blocks: Mapping[str, tuple[str, str]] | None = None,
                 resolve: Mapping[str, Resolver] | None = None,
                 other: Resolver | None = None) -> None:
        self.body = body
        self.elements: dict[int, Element] = {}
        for e in body.children:
            if e.ns == PLCOPEN_NS and e.get("localId") is not None:
                self.elements.setdefault(local_id(e), e)
        self.connectors: dict[str, Element] = {
            (e.get("name") or "").lower(): e for e in self.elements.values()
            if e.tag == "connector"}
        self.blocks = blocks or {}
        self.resolve = resolve or {}  # block type (upper case) -> its reader
        self.other = other  # the reader of any other block but gates and functions
        self.used: set[int] = set()  # the elements some expression was read from
        self.called: set[int] = set()  # the blocks whose call is in ``program``
        self.program: list[YStr] = []  # block calls, in the order the network needs them
        self.assignments: list[tuple[YStr, YStr]] = []  # (variable, value) of statements()

    # -- expressions -----------------------------------------------------------------------
    def point(self, point: Element, trail: tuple[int, ...] = ()) -> YStr:
        """The expression feeding a connection point (several connections: their OR)."""
        conns = connections(point, self.elements)
        if not conns:
            raise SourceError(point.loc, "a connection point connects to nothing")
        parts = [self.element(ref, trail, conn.get("formalParameter")) for ref, conn in conns]
        if len(parts) == 1:
            return parts[0]
        return _join(parts, "OR", point.loc)

    def element(self, ref: int, trail: tuple[int, ...], out: str | None = None) -> YStr:
        e = self.elements[ref]
        kind = (e.get("typeName") or "").upper() if e.tag == "block" else ""
        if ref in self.called:  # a block already called (a feedback reads its last output)
            reader = self._reader(kind)
            return reader(self, e, ref, out, trail) if reader else self.block_output(e, ref, out)
        if ref in trail:
            cycle = " -> ".join(map(str, (*trail[trail.index(ref):], ref)))
            raise SourceError(e.loc, f"cycle in refLocalId: {cycle} (a network must start at "
                                     "variables or at the left power rail)")
        trail = (*trail, ref)
        self.used.add(ref)
        if len(trail) > MAX_CHAIN:
            raise SourceError(e.loc, f"a network more than {MAX_CHAIN} elements long: write "
                                     "it in ST")
        if e.tag == "leftPowerRail":
            return compose([_TRUE], e.loc)
        if e.tag in ("inVariable", "inOutVariable"):
            expr = e.find("expression", PLCOPEN_NS)
            if expr is None or not expr.text.strip():
                raise SourceError(e.loc, f"localId {ref}: {e.tag} without an expression")
            return _modified(e, expression(expr.ystr(), f"localId {ref}: the {e.tag}"))
        if e.tag == "contact":
            var = e.find("variable", PLCOPEN_NS)
            if var is None or not var.text.strip():
                raise SourceError(e.loc, f"localId {ref}: contact without a variable")
            me = _modified(e, reference(var.ystr(), f"localId {ref}: the contact"))
            cin = e.find("connectionPointIn", PLCOPEN_NS)
            if cin is None or not cin.findall("connection", PLCOPEN_NS):
                return me
            before = self.point(cin, trail)
            if str(before) == _TRUE:
                return me
            return _join([before, me], "AND", e.loc)
        if e.tag == "coil":  # coils in series pass their input on
            cin = e.find("connectionPointIn", PLCOPEN_NS)
            if cin is None:
                raise SourceError(e.loc, f"localId {ref}: coil without an input")
            return self.point(cin, trail)
        if e.tag == "continuation":
            source = self.connectors.get((e.get("name") or "").lower())
            cin = source.find("connectionPointIn", PLCOPEN_NS) if source else None
            if source is None or cin is None:
                raise SourceError(e.loc, f"localId {ref}: continuation '{e.get('name')}' has "
                                         "no connector of that name")
            self.used.add(local_id(source))
            return self.point(cin, (*trail, local_id(source)))
        if e.tag == "block" and kind in GATES:
            return self.gate(e, ref, trail)
        if e.tag == "block" and kind in FUNCTIONS:
            return self.function(e, ref, trail)
        reader = self._reader(kind) if e.tag == "block" else None
        if reader is not None:
            return reader(self, e, ref, out, trail)
        if e.tag == "block" and kind in FB_MEMBERS:
            return self.call(e, ref, trail, out)
        what = f"{e.tag} {e.get('typeName')}" if e.get("typeName") else e.tag
        raise NotCarried(e.loc, f"localId {ref}: a {what}: softplc carries variables, "
                                "contacts, coils, the gates AND OR XOR NOT, comparisons and "
                                "arithmetic, and the blocks TON TOF TP CTU CTD CTUD R_TRIG "
                                "F_TRIG SR RS; write it in ST")

    def _reader(self, kind: str) -> Resolver | None:
        """The importer's own reader of a block type, if it has one."""
        return self.resolve.get(kind, self.other)

    def inputs(self, e: Element, ref: int, trail: tuple[int, ...]
               ) -> list[tuple[Element, YStr | None]]:
        """Each input variable of block ``e`` with the expression feeding it (None: not
        connected), its ``negated``/``edge`` applied."""
        ins = e.find("inputVariables", PLCOPEN_NS)
        out: list[tuple[Element, YStr | None]] = []
        for v in ins.findall("variable", PLCOPEN_NS) if ins is not None else []:
            cin = v.find("connectionPointIn", PLCOPEN_NS)
            if cin is None or not cin.findall("connection", PLCOPEN_NS):
                out.append((v, None))
                continue
            out.append((v, _modified(v, self.point(cin, trail))))
        return out

    def gate(self, e: Element, ref: int, trail: tuple[int, ...]) -> YStr:
        op = (e.get("typeName") or "").upper()
        parts = []
        for v, text in self.inputs(e, ref, trail):
            if text is None:
                raise SourceError(v.loc, f"localId {ref}: input {v.get('formalParameter')} of "
                                         f"{op} is not connected")
            parts.append(text)
        if not parts or (GATES[op] and len(parts) != GATES[op]):
            raise SourceError(e.loc, f"localId {ref}: {op} with {len(parts)} inputs")
        if op == "NOT":
            out = compose(["NOT ", *_paren(parts[0], e.loc)], e.loc)
        else:
            out = _join(parts, op, e.loc)
        return self._negated_output(e, out)

    def function(self, e: Element, ref: int, trail: tuple[int, ...]) -> YStr:
        name = (e.get("typeName") or "").upper()
        op, arity = FUNCTIONS[name]
        parts = []
        for v, text in self.inputs(e, ref, trail):
            if text is None:
                raise SourceError(v.loc, f"localId {ref}: input {v.get('formalParameter')} of "
                                         f"{name} is not connected")
            parts.append(text)
        if (arity and len(parts) != arity) or (not arity and len(parts) < 2):
            raise SourceError(e.loc, f"localId {ref}: {name} with {len(parts)} inputs")
        if name == "MOVE":
            return self._negated_output(e, parts[0])
        pieces: list[str | YStr] = ["("]
        for i, p in enumerate(parts):
            if i:
                pieces.append(f" {op.strip()} ")
            pieces += _paren(p, e.loc, _NAME)
        pieces.append(")")
        return self._negated_output(e, compose(pieces, e.loc))

    def _negated_output(self, e: Element, out: YStr) -> YStr:
        outs = e.find("outputVariables", PLCOPEN_NS)
        first = outs.find("variable", PLCOPEN_NS) if outs is not None else None
        if first is not None and first.get("negated") == "true":
            return compose(["NOT ", *_paren(out, e.loc)], e.loc)
        return out

    # -- function blocks ---------------------------------------------------------------------
    def instance(self, e: Element, ref: int) -> tuple[str, str]:
        """(name as declared, type) of block ``e``'s instance; an error if the POU declares
        no instance of that name and type."""
        kind = (e.get("typeName") or "").upper()
        raw = (e.get("instanceName") or "").strip()
        decl = self.blocks.get(raw.lower())
        if decl is None or decl[1] != kind:
            found = f" (it is a {decl[1]})" if decl else ""
            raise SourceError(e.loc, f"localId {ref}: block {kind} instance '{raw}': expected "
                                     f"a {kind} declared by that name in the POU's variables"
                                     f"{found}")
        return decl

    def call(self, e: Element, ref: int, trail: tuple[int, ...], out: str | None) -> YStr:
        """Block ``e`` called (once) and the text of output ``out`` of it."""
        name, kind = self.instance(e, ref)
        self.called.add(ref)  # before its inputs: a feedback reads its last output
        members = FB_MEMBERS[kind]
        args: list[str | YStr] = [name, "("]
        for v, text in self.inputs(e, ref, trail):
            param = (v.get("formalParameter") or "").upper()
            if param not in members or not members[param][1]:
                raise SourceError(v.loc, f"localId {ref}: {kind} has no input '"
                                         f"{v.get('formalParameter')}': expected "
                                         f"{', '.join(m for m, (_, i) in members.items() if i)}")
            if text is None:
                continue
            if args[-1] != "(":
                args.append(", ")
            args += [f"{param} := ", text]
        args.append(")")
        self.program.append(compose(args, e.loc))
        return self.block_output(e, ref, out)

    def block_output(self, e: Element, ref: int, out: str | None) -> YStr:
        """The text of output ``out`` of a called block (its only output when the
        connection does not name one), ``negated`` applied."""
        name, kind = self.instance(e, ref)
        members = FB_MEMBERS[kind]
        outs = e.find("outputVariables", PLCOPEN_NS)
        declared = outs.findall("variable", PLCOPEN_NS) if outs is not None else []
        if out is None and len(declared) == 1:
            out = declared[0].get("formalParameter")
        param = (out or "").upper()
        if param not in members or members[param][1]:
            raise SourceError(e.loc, f"localId {ref}: a connection from {kind} '{name}' names "
                                     f"no output ('{out or ''}'): expected "
                                     f"{', '.join(m for m, (_, i) in members.items() if not i)}")
        text = plain(f"{name}.{param}", e.loc)
        for v in declared:
            if (v.get("formalParameter") or "").upper() == param and v.get("negated") == "true":
                return compose(["NOT ", text], e.loc)
        return text

    # -- statements ---------------------------------------------------------------------------
    def statements(self) -> list[YStr]:
        """The body as statements, in Beremiz's order: the elements with an
        ``executionOrderId``, in that order; then the output variables and coils, top to
        bottom and left to right; then the blocks no output needed. Each statement comes
        after the calls of the blocks it reads."""
        ordered, outputs, blocks = [], [], []
        for ref, e in self.elements.items():
            if e.tag in ("jump", "label", "return", "vendorElement"):
                raise NotCarried(e.loc, f"localId {ref}: a {e.tag}: softplc's statements "
                                        "have no jumps, labels or returns; write it in ST")
            if e.tag not in ("outVariable", "inOutVariable", "coil", "block"):
                continue
            n = _order(e)
            if n > 0 and e.tag != "coil":
                ordered.append((n, ref))
            elif e.tag == "block":
                blocks.append(ref)
            else:
                outputs.append(ref)
        ordered.sort()
        spot = cmp_to_key(self._beremiz)
        todo = [r for _, r in ordered] + sorted(outputs, key=spot) + sorted(blocks, key=spot)
        out: list[YStr] = []
        for ref in todo:
            e = self.elements[ref]
            before = len(self.program)
            stmt = None
            if e.tag == "block":
                if ref not in self.called:
                    self.element(ref, ())
            else:
                stmt = self.assignment(e, ref)
            out += self.program[before:]
            if stmt is not None:
                out.append(stmt)
        return out

    def _beremiz(self, a: int, b: int) -> int:
        """Beremiz's order of outputs and blocks: top to bottom, left to right when less
        than 10 px apart vertically."""
        (ax, ay), (bx, by) = position(self.elements[a]), position(self.elements[b])
        if abs(int(ay) - int(by)) < 10:
            return (int(ax) > int(bx)) - (int(ax) < int(bx))
        return (int(ay) > int(by)) - (int(ay) < int(by))

    def assignment(self, e: Element, ref: int) -> YStr | None:
        """The statement of an output variable or a coil (None: not connected)."""
        cin = e.find("connectionPointIn", PLCOPEN_NS)
        if cin is None or not cin.findall("connection", PLCOPEN_NS):
            return None
        if e.tag == "coil":
            var = e.find("variable", PLCOPEN_NS)
            what = f"localId {ref}: the coil"
        else:
            var = e.find("expression", PLCOPEN_NS)
            what = f"localId {ref}: the {e.tag}"
        if var is None or not var.text.strip():
            raise SourceError(e.loc, f"{what} names no variable")
        target = target_name(var.ystr(), what)
        value = self.point(cin, (ref,))
        self.assignments.append((target, value))
        at = e.loc
        storage = e.get("storage", "none") if e.tag == "coil" else "none"
        if e.get("negated") == "true":
            value = compose(["NOT ", *_paren(value, at)], at)
        elif storage in ("set", "reset"):
            word = "TRUE" if storage == "set" else "FALSE"
            return compose(["IF ", value, " THEN ", target, f" := {word}; END_IF"], at)
        elif e.get("edge", "none") in ("rising", "falling"):
            edge = "RE " if e.get("edge") == "rising" else "FE "
            value = compose([edge, *_paren(value, at)], at)
        return compose([target, " := ", value], at)


def _order(e: Element) -> int:
    raw = (e.get("executionOrderId") or "0").strip()
    return int(raw) if raw.isdigit() else 0


# -- texts from the file ----------------------------------------------------------------------
def _tokens(text: YStr, what: str) -> list[tuple[str, str, int, int]]:
    """(kind, text, start, end) of the tokens of a text of the file; an error if it holds a
    comment (it would hide what follows it once placed in a longer text)."""
    try:
        toks = [(t.kind, t.text, t.start, t.end)
                for t in Lexer(str(text), text.pos).tokens() if t.kind not in ("NL", "EOF")]
    except SourceError as exc:
        raise SourceError(exc.loc, f"{what}: {exc.message}") from None
    covered: set[int] = set()
    for _, _, a, b in toks:
        covered.update(range(a, b))
    for i, c in enumerate(str(text)):
        if i not in covered and not c.isspace():
            raise SourceError(text.pos(i), f"{what}: expected an expression, found a comment "
                                           f"'{str(text)[i:i + 20]}'")
    return toks


def expression(text: YStr, what: str) -> YStr:
    """``text`` if it is one expression for the language's parser to read: no statement
    (``:=``, ``;``), no comment."""
    for kind, word, a, _ in _tokens(text, what):
        if kind == "OP" and word in (":=", ";"):
            raise SourceError(text.pos(a), f"{what}: expected an expression, found '{word}'")
    return text


def reference(text: YStr, what: str) -> YStr:
    """``text`` if it names a variable (``x``, ``fb.Q``, ``step.X``)."""
    toks = _tokens(text, what)
    words = [w for k, w, _, _ in toks]
    ok = bool(words) and len(words) % 2 == 1 and all(
        (k == "NAME") if i % 2 == 0 else (w == ".") for i, (k, w, _, _) in enumerate(toks))
    if not ok:
        raise SourceError(text.loc, f"{what}: expected a variable name, found "
                                    f"'{str(text).strip()}'")
    return text


def target_name(text: YStr, what: str) -> YStr:
    """``text`` if it is one name a statement may assign."""
    word = str(text).strip()
    if not is_name(word) or word.upper() in KEYWORDS:
        raise SourceError(text.loc, f"{what}: expected the name of a variable to assign, "
                                    f"found '{word}'")
    return reference(text, what)


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
        raise SourceError(e.loc, f"a {e.tag} with storage '{e.get('storage')}' read as a "
                                 "value: set and reset have no meaning there")
    out = text
    if edge in ("rising", "falling"):
        out = compose(["RE " if edge == "rising" else "FE ", *_paren(out, e.loc)], e.loc)
    if e.get("negated") == "true":
        out = compose(["NOT ", *_paren(out, e.loc)], e.loc)
    return out
