"""Parser of expressions, statements and action strings (both notations).

A hand-written Pratt parser: it gives the exact column of every fault and says what it
expected and what it found, and has no dependency. Precedence (language.md, tightest first):
1 ``.X .T`` calls, postfix ``'``, prefix ``↑ ↓ RE FE NOT ! -``; 2 ``· * / MOD``;
3 ``+ -``; 4 comparisons; 5 ``AND &``; 6 ``XOR``; 7 ``OR``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import islice

from runtime.errors import Loc, SourceError
from runtime.language import ast as A
from runtime.language.lexer import Lexer, Tok, spaced_time

QUALIFIERS = ("N", "S", "R", "L", "D", "P", "P1", "P0", "DS", "SD", "SL")
TIMED_QUALIFIERS = ("L", "D", "DS", "SD", "SL")

_BINARY = {
    "OR": (7, "OR"), "XOR": (6, "XOR"), "AND": (5, "AND"), "&": (5, "AND"),
    "=": (4, "EQ"), "==": (4, "EQ"), "<>": (4, "NE"), "!=": (4, "NE"), "≠": (4, "NE"),
    "<": (4, "LT"), "<=": (4, "LE"), "≤": (4, "LE"), ">": (4, "GT"), ">=": (4, "GE"),
    "≥": (4, "GE"), "+": (3, "ADD"), "-": (3, "SUB"), "*": (2, "MUL"), "·": (2, "MUL"),
    "∙": (2, "MUL"), "⋅": (2, "MUL"), "/": (2, "DIV"), "MOD": (2, "MOD"),
}
_PREFIX = {"↑": "RE", "RE": "RE", "↓": "FE", "FE": "FE", "NOT": "NOT", "!": "NOT", "-": "NEG"}
METHODS = ("Ini", "End", "Reset", "Val", "Set")
#: limits that keep the checker, the compiler and Python's own parser within their bounds
MAX_NESTING = 50  # parentheses and prefix operators inside one another
MAX_DEPTH = 100  # operators in a chain (a + b + c ...: depth = number of operators)
MAX_BLOCKS = 16  # IF / CASE / FOR inside one another
#: tokens read from the text at a time, beyond the one asked for
_READ_AHEAD = 16


def _describe(t: Tok) -> str:
    if t.kind == "EOF":
        return "end of text"
    if t.kind == "NL":
        return "end of line"
    return f"'{t.text}'"


class Parser:
    """Parses one source string (an expression, statements, or an action)."""

    def __init__(self, text: str, locate: Callable[[int], Loc]) -> None:
        self.lexer = Lexer(text, locate)
        self._more = self.lexer.tokens()
        #: the tokens read so far (read as the parser gets to them: ``_tok``); EOF last
        self.toks: list[Tok] = []
        self.i = 0
        self.depth = 0  # parenthesis depth: newlines inside parentheses are spaces
        self.nesting = 0  # parentheses and prefix operators being parsed
        self.blocks = 0  # IF / CASE / FOR statements being parsed
        self.text = text

    # -- token helpers -----------------------------------------------------------------
    def tok(self, k: int) -> Tok:
        """Token number ``k`` (EOF past the end), read from the text if not yet."""
        toks = self.toks
        if k >= len(toks):
            if toks and toks[-1].kind == "EOF":
                return toks[-1]
            toks.extend(islice(self._more, k + _READ_AHEAD - len(toks)))
            return toks[min(k, len(toks) - 1)]
        return toks[k]

    def peek(self, skip_nl: bool = False) -> Tok:
        i = self.i
        t = self.tok(i)
        if skip_nl or self.depth:
            while t.kind == "NL":
                i += 1
                t = self.tok(i)
        return t

    def next(self, skip_nl: bool = False) -> Tok:
        if skip_nl or self.depth:
            self.skip_nl()
        t = self.tok(self.i)
        if t.kind != "EOF":  # EOF is never passed
            self.i += 1
        return t

    def skip_nl(self) -> None:
        while self.tok(self.i).kind == "NL":
            self.i += 1

    def at(self, kind: str, text: str | None = None, skip_nl: bool = False) -> bool:
        t = self.peek(skip_nl)
        return t.kind == kind and (text is None or t.text == text)

    def error(self, tok: Tok, expected: str) -> SourceError:
        spaced = self.spaced_time(tok)
        if spaced is not None:
            return spaced
        if tok.kind == "KW" and tok.text in ("WHILE", "REPEAT"):
            return SourceError(self.lexer.locate(tok.start),
                               f"expected {expected}, found {tok.text}: WHILE and REPEAT loops "
                               "are not allowed (a scan must always end): use a bounded FOR "
                               "loop")
        return SourceError(self.lexer.locate(tok.start),
                           f"expected {expected}, found {_describe(tok)}")

    def spaced_time(self, tok: Tok) -> SourceError | None:
        """The error for ``5 s`` when ``tok`` is the unit after a number and a space (the
        newcomer's time literal), else None."""
        k = next((i for i, t in enumerate(self.toks) if t is tok), 0)
        if k == 0:
            return None
        number = self.toks[k - 1]
        if number.kind not in ("INT", "REAL"):
            return None
        return spaced_time(self.text, number.start, tok, self.lexer.locate)

    def expect(self, kind: str, text: str | None, what: str, skip_nl: bool = False) -> Tok:
        t = self.peek(skip_nl)
        if t.kind != kind or (text is not None and t.text != text):
            raise self.error(t, what)
        return self.next(skip_nl)

    # -- expressions -------------------------------------------------------------------
    def expression(self, max_level: int = 7) -> A.Node:
        """An expression with binary operators up to ``max_level`` (7: all of them)."""
        return self._binary(max_level)

    def keyword_delimited(self) -> A.Node:
        """An expression ended by a keyword (IF ... THEN, FOR ... TO ... DO, CASE ... OF):
        new lines inside it are spaces, as in IEC 61131-3 ST."""
        self.depth += 1
        try:
            return self.expression()
        finally:
            self.depth -= 1

    def _binary(self, max_level: int) -> A.Node:
        """Operators of level <= max_level (1 tightest), left-associative (Pratt loop).

        A chain longer than MAX_DEPTH is refused at its first operator past the limit, as
        soon as it is read (``check_depth`` sees the whole tree, once parsed)."""
        left = self._unary()
        chain = 0
        while True:
            t = self.peek()
            key = t.text if t.kind in ("OP", "KW") else None
            if key is None or key not in _BINARY or _BINARY[key][0] > max_level:
                return left
            chain += 1
            if chain > MAX_DEPTH:
                raise _too_deep(self.lexer.locate(t.start))
            level, op = _BINARY[key]
            self.next()
            self.skip_nl()  # an operator at the end of a line continues the expression
            right = self._binary(level - 1)  # only tighter operators on the right
            left = A.Binary(left.start, right.end, op, left, right, t.text)

    def nest(self, tok: Tok) -> None:
        """Enter a parenthesis, an argument list or a prefix operator (bounded depth)."""
        self.nesting += 1
        if self.nesting > MAX_NESTING:
            raise SourceError(self.lexer.locate(tok.start),
                              f"expected at most {MAX_NESTING} nested parentheses or prefix "
                              f"operators, found more: split the expression with temporaries")

    def _unary(self) -> A.Node:
        t = self.peek()
        key = t.text if t.kind in ("OP", "KW") else None
        if key in _PREFIX:
            self.next()
            self.skip_nl()  # an operator at the end of a line continues the expression
            self.nest(t)
            operand = self._unary()
            self.nesting -= 1
            return A.Unary(t.start, operand.end, _PREFIX[key], operand, t.text)
        node = self._postfix(self._primary())
        return node

    def _postfix(self, node: A.Node) -> A.Node:
        while self.at("OP", "'"):
            t = self.next()
            node = A.Unary(node.start, t.end, "NOT", node, "'")
        return node

    def _primary(self) -> A.Node:
        t = self.next()
        if t.kind == "OP" and t.text == "(":
            self.depth += 1
            self.nest(t)
            inner = self.expression()
            self.nesting -= 1
            self.depth -= 1
            close = self.peek()
            if not (close.kind == "OP" and close.text == ")"):
                opened = self.lexer.locate(t.start)
                raise SourceError(self.lexer.locate(close.start),
                                  f"unbalanced parentheses: expected ')' to close the '(' "
                                  f"opened at line {opened.line}, column {opened.col}, found "
                                  f"{_describe(close)}")
            self.next()
            inner.start, inner.end = t.start, close.end  # keep parentheses in the span
            return inner
        if t.kind == "INT":
            v = int(t.value)  # type: ignore[call-overload]
            return A.Lit(t.start, t.end, v, A.Type.INT, v in (0, 1))
        if t.kind == "REAL":
            return A.Lit(t.start, t.end, t.value, A.Type.REAL)  # type: ignore[arg-type]
        if t.kind == "TIME":
            return A.Lit(t.start, t.end, t.value, A.Type.TIME)  # type: ignore[arg-type]
        if t.kind == "KW" and t.text in ("TRUE", "FALSE"):
            return A.Lit(t.start, t.end, t.text == "TRUE", A.Type.BOOL)
        if t.kind == "NAME":
            if self.at("OP", "."):
                self.next()
                m = self.expect("NAME", None, "a member name after '.' (X, T, Q, ET, End...)")
                if self.at("OP", "("):
                    args = self._call_args(positional=True)
                    end = self.toks[self.i - 1].end
                    return A.MethodCall(t.start, end, t.text, m.text, args)
                if m.text in ("X", "T", "x", "t"):
                    return A.StepFlag(t.start, m.end, t.text, m.text.upper())
                return A.Member(t.start, m.end, t.text, m.text)
            return A.Name(t.start, t.end, t.text)
        if t.kind == "OP" and t.text == ")":
            raise SourceError(self.lexer.locate(t.start),
                              "unbalanced parentheses: expected an operand, found ')' without "
                              "a matching '('")
        raise self.error(t, "an operand (a name, a number, a time, '(' or an operator like "
                            "NOT ↑)")

    def _call_args(self, positional: bool) -> list:  # type: ignore[type-arg]
        self.nest(self.expect("OP", "(", "'('"))
        self.depth += 1
        args: list = []  # type: ignore[type-arg]
        if not self.at("OP", ")"):
            while True:
                if positional:
                    args.append(self.expression())
                else:
                    name = self.expect("NAME", None, "an argument name (e.g. IN := x)")
                    self.expect("OP", ":=", f"':=' after argument '{name.text}'")
                    args.append((name.text, self.expression(), name.start))
                if self.at("OP", ","):
                    self.next()
                    continue
                break
        t = self.peek()
        if not (t.kind == "OP" and t.text == ")"):
            self.depth -= 1
            raise SourceError(self.lexer.locate(t.start),
                              f"unbalanced parentheses: expected ',' or ')' in the argument "
                              f"list, found {_describe(t)}")
        self.next()
        self.depth -= 1
        self.nesting -= 1
        return args

    # -- statements --------------------------------------------------------------------
    def statements(self, until: tuple[str, ...] = ()) -> list[A.Node]:
        """Statements separated by ';' or new lines, up to EOF or a keyword in ``until``."""
        out: list[A.Node] = []
        while True:
            while self.at("NL") or self.at("OP", ";"):
                self.next()
            t = self.peek()
            if t.kind == "EOF" or (t.kind == "KW" and t.text in until):
                return out
            out.append(self.statement())
            t = self.peek()
            if t.kind == "NL" or (t.kind == "OP" and t.text == ";"):
                continue
            if t.kind == "EOF" or (t.kind == "KW" and t.text in until):
                return out
            raise self.error(t, "';' or a new line between statements")

    def statement(self) -> A.Node:
        t = self.peek()
        if t.kind == "KW" and t.text in ("IF", "CASE", "FOR"):
            self.blocks += 1
            if self.blocks > MAX_BLOCKS:
                raise SourceError(self.lexer.locate(t.start),
                                  f"expected at most {MAX_BLOCKS} IF, CASE or FOR statements "
                                  f"inside one another, found more: simplify the logic")
            node = {"IF": self._if, "CASE": self._case, "FOR": self._for}[t.text]()
            self.blocks -= 1
            return node
        if t.kind == "KW":
            raise self.error(t, "a statement (x := expr, a call, IF, CASE or FOR)")
        if t.kind != "NAME":
            raise self.error(t, "a statement (x := expr, a call, IF, CASE or FOR)")
        self.next()
        if self.at("OP", ":="):
            self.next()
            self.skip_nl()
            value = self.expression()
            return A.Assign(t.start, value.end, A.Name(t.start, t.end, t.text), value)
        if self.at("OP", "."):
            self.next()
            m = self.expect("NAME", None, "a method name after '.' (Ini, Reset, Set ...)")
            if not self.at("OP", "("):
                raise self.error(self.peek(), f"'(' to call {t.text}.{m.text}")
            args = self._call_args(positional=True)
            end = self.toks[self.i - 1].end
            call = A.MethodCall(t.start, end, t.text, m.text, args)
            return A.CallStmt(t.start, end, call)
        if self.at("OP", "("):
            raw = self._call_args(positional=False)
            end = self.toks[self.i - 1].end
            return A.FbCall(t.start, end, t.text, [(n, e) for n, e, _ in raw])
        raise self.error(self.peek(), f"':=' or a call after '{t.text}'")

    def _if(self) -> A.Node:
        start = self.next().start
        branches = []
        cond = self.keyword_delimited()
        self.expect("KW", "THEN", "THEN", skip_nl=True)
        body = self.statements(("ELSIF", "ELSE", "END_IF"))
        branches.append((cond, body))
        orelse: list[A.Node] = []
        while True:
            t = self.next(skip_nl=True)
            if t.kind == "KW" and t.text == "ELSIF":
                cond = self.keyword_delimited()
                self.expect("KW", "THEN", "THEN", skip_nl=True)
                branches.append((cond, self.statements(("ELSIF", "ELSE", "END_IF"))))
            elif t.kind == "KW" and t.text == "ELSE":
                orelse = self.statements(("END_IF",))
            elif t.kind == "KW" and t.text == "END_IF":
                return A.If(start, t.end, branches, orelse)
            else:
                raise self.error(t, "ELSIF, ELSE or END_IF")

    def _case_label(self) -> int:
        neg = False
        if self.at("OP", "-"):
            self.next()
            neg = True
        t = self.expect("INT", None, "an integer CASE label")
        assert isinstance(t.value, int)
        return -t.value if neg else t.value

    def _case(self) -> A.Node:
        start = self.next().start
        sel = self.keyword_delimited()
        self.expect("KW", "OF", "OF", skip_nl=True)
        arms: list[tuple[list[tuple[int, int]], list[A.Node]]] = []
        orelse: list[A.Node] = []
        while True:
            self.skip_nl()
            t = self.peek()
            if t.kind == "KW" and t.text == "END_CASE":
                self.next()
                return A.Case(start, t.end, sel, arms, orelse)
            if t.kind == "KW" and t.text == "ELSE":
                self.next()
                orelse = self.statements(("END_CASE",))
                continue
            labels: list[tuple[int, int]] = []
            while True:
                first = self.peek()
                lo = self._case_label()
                hi = lo
                if self.at("OP", ".."):
                    self.next()
                    hi = self._case_label()
                    if hi < lo:
                        raise SourceError(self.lexer.locate(first.start),
                                          f"expected a CASE range low..high, found {lo}..{hi}")
                written = self.text[first.start:self.toks[self.i - 1].end]
                for seen_lo, seen_hi in [x for arm in arms for x in arm[0]] + labels:
                    if lo <= seen_hi and seen_lo <= hi:
                        before = (str(seen_lo) if seen_lo == seen_hi
                                  else f"{seen_lo}..{seen_hi}")
                        raise SourceError(self.lexer.locate(first.start),
                                          f"expected each CASE value in one label only, found "
                                          f"{written} overlapping the earlier label {before}")
                labels.append((lo, hi))
                if self.at("OP", ","):
                    self.next()
                    self.skip_nl()
                    continue
                break
            self.expect("OP", ":", "':' after the CASE labels")
            body = self._case_body()
            arms.append((labels, body))

    def _case_body(self) -> list[A.Node]:
        """Statements of one CASE arm: up to the next label, ELSE or END_CASE."""
        out: list[A.Node] = []
        while True:
            while self.at("NL") or self.at("OP", ";"):
                self.next()
            t = self.peek()
            if t.kind == "KW" and t.text in ("ELSE", "END_CASE"):
                return out
            if t.kind == "EOF":
                raise self.error(t, "END_CASE")
            if t.kind == "INT" or (t.kind == "OP" and t.text == "-"):
                return out  # no statement starts with a number: the next arm's labels
            out.append(self.statement())

    def _for(self) -> A.Node:
        start = self.next().start
        v = self.expect("NAME", None, "the FOR loop variable")
        self.expect("OP", ":=", "':=' after the FOR variable")
        first = self.keyword_delimited()
        self.expect("KW", "TO", "TO", skip_nl=True)
        last = self.keyword_delimited()
        step = None
        if self.at("KW", "BY", skip_nl=True):
            self.next(skip_nl=True)
            step = self.keyword_delimited()
        self.expect("KW", "DO", "DO", skip_nl=True)
        body = self.statements(("END_FOR",))
        t = self.expect("KW", "END_FOR", "END_FOR", skip_nl=True)
        return A.For(start, t.end, A.Name(v.start, v.end, v.text), first, last, step, body)

    def finish(self, what: str) -> None:
        while self.at("NL"):
            self.next()
        t = self.peek()
        if t.kind != "EOF":
            if t.kind == "OP" and t.text == ")":
                raise SourceError(self.lexer.locate(t.start),
                                  f"unbalanced parentheses: expected {what}, found ')' without "
                                  "a matching '('")
            raise self.error(t, what)


def _children(n: A.Node) -> list[A.Node]:
    if isinstance(n, A.Unary):
        return [n.operand]
    if isinstance(n, A.Binary):
        return [n.left, n.right]
    if isinstance(n, A.MethodCall):
        return list(n.args)
    if isinstance(n, A.Assign):
        return [n.value]
    if isinstance(n, A.CallStmt):
        return [n.call]
    if isinstance(n, A.FbCall):
        return [a for _, a in n.args]
    if isinstance(n, A.If):
        return [x for c, body in n.branches for x in (c, *body)] + list(n.orelse)
    if isinstance(n, A.Case):
        return [n.selector, *(x for _, body in n.arms for x in body), *n.orelse]
    if isinstance(n, A.For):
        return [x for x in (n.first, n.last, n.step, *n.body) if x is not None]
    return []


def _too_deep(loc: Loc) -> SourceError:
    return SourceError(loc, f"expected at most {MAX_DEPTH} operators in a chain, found more: "
                            "split the expression with temporaries")


def check_depth(roots: list[A.Node], locate: Callable[[int], Loc]) -> None:
    """Refuse expressions nested deeper than MAX_DEPTH operators (without recursion: the
    checker and the compiler recurse on the tree, and Python limits nested parentheses)."""
    stack = [(r, 0) for r in roots]
    while stack:
        n, d = stack.pop()
        if isinstance(n, (A.Unary, A.Binary, A.MethodCall)):
            d += 1
            if d > MAX_DEPTH:
                raise _too_deep(locate(n.start))
        else:
            d = 0  # a statement: its expressions start afresh
        stack.extend((c, d) for c in _children(n))


def parse_expression(text: str, locate: Callable[[int], Loc]) -> A.Node:
    """Parse one expression (a transition condition, an action condition)."""
    p = Parser(text, locate)
    p.skip_nl()
    if p.at("EOF"):
        raise p.error(p.peek(), "an expression")
    e = p.expression()
    p.finish("an operator or the end of the expression")
    check_depth([e], locate)
    return e


def parse_statements(text: str, locate: Callable[[int], Loc]) -> list[A.Node]:
    """Parse statements separated by ';' or new lines."""
    p = Parser(text, locate)
    body = p.statements()
    p.finish("';' or a new line between statements")
    check_depth(body, locate)
    return body


@dataclass(slots=True)
class ParsedAction:
    """An action string split into its parts; ``target`` xor ``body`` is set."""

    qualifier: str
    time_ns: int | None
    target: A.Name | None
    cond: A.Node | None  # `N x if C`
    event: A.Node | None  # `on E do ...`
    body: list[A.Node] | None
    qualifier_start: int


def _starts_event(p: Parser) -> bool:
    """Is the word ``on`` at the parser's position the start of ``on EVENT do ...``?

    ``on`` is not reserved (an output may be named ``On``/``oN``): it starts an event action
    only when an event expression follows it. A bare variable (``oN``, ``oN if C``), an
    assignment (``oN := 1``) or a method call (``oN.Set(...)``) cannot be an event; ``oN(...)``
    is a block call unless a ``do`` follows the parentheses."""
    nxt = p.tok(p.i + 1)
    if nxt.kind in ("EOF", "NL") or (nxt.kind == "KW" and nxt.text == "IF") or (
            nxt.kind == "OP" and nxt.text in (":=", ";", ".", "=")):
        return False
    if nxt.kind == "OP" and nxt.text == "(":
        depth, k = 0, p.i + 1
        while p.tok(k).kind != "EOF":
            t = p.tok(k)
            if t.kind == "OP" and t.text == "(":
                depth += 1
            elif t.kind == "OP" and t.text == ")":
                depth -= 1
            elif depth == 0 and t.kind == "KW" and t.text == "DO":
                return True
            elif depth == 0 and (t.kind == "NL" or (t.kind == "OP" and t.text in (":=", ";"))):
                return False
            k += 1
        return False
    return True


def parse_action(text: str, locate: Callable[[int], Loc]) -> ParsedAction:
    """``[QUALIFIER [TIME]] BODY [if CONDITION]`` or ``on EVENT do STATEMENTS``."""
    p = Parser(text, locate)
    p.skip_nl()
    t0 = p.peek()
    if t0.kind == "EOF":
        raise p.error(t0, "an action (a variable, or a qualifier and a body)")
    if t0.kind == "NAME" and t0.text.lower() == "on" and _starts_event(p):
        p.next()
        ev = p.expression()
        t = p.peek()
        if not (t.kind == "KW" and t.text == "DO"):
            raise p.error(t, "'do' after the event of an 'on EVENT do' action")
        p.next()
        p.skip_nl()
        t, after = p.peek(), p.tok(p.i + 1)
        if t.kind == "NAME" and after.kind in ("EOF", "NL"):
            raise SourceError(locate(t.start), f"expected statements after 'do' (e.g. "
                              f"'{t.text} := 1'), found the bare variable '{t.text}': a "
                              "continuous action cannot be tied to an event (seed-000 rule I.6)",
                              "G105")
        body = p.statements()
        p.finish("';' or a new line between statements")
        if not body:
            raise p.error(p.peek(), "statements after 'do'")
        check_depth([ev, *body], locate)
        return ParsedAction("EVENT", None, None, None, ev, body, t0.start)
    if t0.kind == "NAME" and t0.text.upper() == "ACTION" and p.tok(p.i + 1).text == "(" and (
            p.tok(p.i + 2).text.upper() in QUALIFIERS and p.tok(p.i + 3).text == ")"):
        raise SourceError(locate(t0.start), "expected an action as 'QUALIFIER statements' "
                          "(e.g. 'N x := x + 1' or 'P1 x := x + 1'), found an ACTION(...): "
                          "... END_ACTION block: write the qualifier first, without ACTION and "
                          "END_ACTION")
    qual, qstart, time_ns = "N", t0.start, None
    known = t0.kind == "NAME" and t0.text.upper() in QUALIFIERS
    k = p.i + 1
    while known and p.tok(k).kind == "NL":  # a qualifier may end its line (block scalars)
        k += 1
    t1 = p.tok(k)
    if t0.kind == "NAME" and (t1.kind in ("NAME", "TIME") or (
            known and t1.kind in ("INT", "REAL")) or (
            t1.kind == "KW" and t1.text in ("IF", "CASE", "FOR", "WHILE", "REPEAT") and (
                known or t1.text != "IF"))):
        # `QUALIFIER [TIME] BODY`; but `oX if C` is a bare variable with a condition
        if not known:
            raise SourceError(locate(t0.start),
                              f"unknown qualifier '{t0.text}': expected one of "
                              f"{' '.join(QUALIFIERS)} (or 'on EVENT do')")
        qual = t0.text.upper()
        p.next()
        p.skip_nl()
        if p.at("TIME"):
            tt = p.next()
            if qual not in TIMED_QUALIFIERS:
                raise SourceError(locate(tt.start),
                                  f"expected a variable or statements after {qual} (only "
                                  f"{' '.join(TIMED_QUALIFIERS)} take a time), found the time "
                                  f"'{tt.text}'")
            time_ns = int(tt.value)  # type: ignore[call-overload]
            p.skip_nl()
        elif qual in TIMED_QUALIFIERS:
            if p.peek().kind in ("INT", "REAL"):
                spaced = p.spaced_time(p.tok(p.i + 1))
                if spaced is not None:
                    raise spaced
            raise SourceError(locate(p.peek().start),
                              f"expected a time after qualifier {qual} (e.g. '{qual} 2s oX'), "
                              f"found {_describe(p.peek())}")
    # a bare variable, maybe with `if COND`?
    t = p.peek()
    after = p.tok(p.i + 1)
    if t.kind == "NAME" and (after.kind in ("EOF", "NL") or (
            after.kind == "KW" and after.text == "IF")):
        p.next()
        target = A.Name(t.start, t.end, t.text)
        cond = None
        if p.at("KW", "IF"):
            p.next()
            cond = p.expression()
        p.finish("the end of the action or 'if CONDITION'")
        check_depth([cond] if cond is not None else [], locate)
        return ParsedAction(qual, time_ns, target, cond, None, None, qstart)
    body = p.statements()
    p.finish("';' or a new line between statements")
    if not body:
        raise p.error(p.peek(), "an action body (a variable or statements)")
    check_depth(body, locate)
    return ParsedAction(qual, time_ns, None, None, None, body, qstart)
