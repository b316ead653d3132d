"""Lexer of expressions, statements and action strings: the text as tokens (names,
keywords, numbers, time literals, operators, new lines), each with its offsets."""

from __future__ import annotations

import unicodedata
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from drivers.durations import LITERAL_UNITS, format_ns, parse_literal
from runtime.errors import Loc, SourceError
from runtime.language.yamlsrc import INT_MAX, TIME_MAX_NS

#: tokens in one text (an expression, an action, a block of statements): about 40 kB of
#: text, a hundred times the longest of the examples; beyond, a text is refused where the
#: limit is crossed, before the rest of it is read (language.md, "Limits")
MAX_TOKENS = 10_000

KEYWORDS = {
    "AND", "OR", "XOR", "NOT", "MOD", "RE", "FE", "TRUE", "FALSE", "IF", "THEN", "ELSIF",
    "ELSE", "END_IF", "CASE", "OF", "END_CASE", "FOR", "TO", "BY", "DO", "END_FOR",
    "WHILE", "REPEAT", "END_WHILE", "UNTIL", "END_REPEAT",
}

_OPS = [":=", "..", "<=", ">=", "<>", "!=", "==", "≤", "≥", "≠", "(", ")", ",", ";", ":",
        ".", "+", "-", "*", "/", "·", "∙", "⋅", "&", "!", "'", "↑", "↓", "=", "<", ">"]


@dataclass(slots=True)
class Tok:
    kind: str  # NAME KW INT REAL TIME OP NL EOF
    text: str
    start: int
    end: int
    value: object = None


def time_space_message(written: str) -> str | None:
    """The advice for a time literal written with spaces (``5 s``, ``1m 30s``), or None if
    the text is no time literal once its spaces are taken out."""
    fixed = "".join(written.split())
    if fixed == written.strip() or parse_literal(fixed) is None:
        return None
    return (f"expected a time literal without a space between the number and its unit "
            f"({fixed}, or T#{fixed}), found '{written.strip()}'")


def spaced_time(text: str, number_start: int, unit: Tok, locate: Callable[[int], Loc]
                ) -> SourceError | None:
    """The error for a number followed on the same line by a time unit (``5 s``), placed at
    the number, or None if ``unit`` is no unit written after it."""
    between = text[number_start:unit.start]
    if unit.kind != "NAME" or unit.text not in LITERAL_UNITS or "\n" in between:
        return None
    message = time_space_message(text[number_start:unit.end])
    return None if message is None else SourceError(locate(number_start), message)


def is_name(word: str) -> bool:
    """A name of the language: letters (any alphabet: gsAvería), digits and '_', not starting
    with a digit, and written in its canonical form (no '²', no ligatures: they would
    collide with other names once compiled)."""
    return word.isidentifier() and unicodedata.normalize("NFKC", word) == word


class Lexer:
    """Turns a source string into tokens; ``locate(offset)`` maps an offset to a file place."""

    def __init__(self, text: str, locate: Callable[[int], Loc]) -> None:
        self.text = text
        self.locate = locate

    def error(self, offset: int, msg: str) -> SourceError:
        return SourceError(self.locate(offset), msg)

    def tokens(self) -> Iterator[Tok]:
        """The tokens, made as they are asked for (the parser stops at its first error, so
        a long text costs only what was read before it), the last one EOF; SourceError at
        the first that cannot be one, or at the one past MAX_TOKENS."""
        for k, tok in enumerate(self._tokens()):
            if k == MAX_TOKENS and tok.kind != "EOF":
                raise self.error(tok.start, f"expected at most {MAX_TOKENS} tokens (names, "
                                 "numbers, operators) in one expression, action or block of "
                                 "statements, found more: split it (temporaries, more "
                                 "actions, several pre: or post: items)")
            yield tok

    def _tokens(self) -> Iterator[Tok]:
        text, i = self.text, 0
        n = len(text)
        while i < n:
            c = text[i]
            if c == "\n":
                yield Tok("NL", "\n", i, i + 1)
                i += 1
                continue
            if c.isspace():
                i += 1
                continue
            if text.startswith("(*", i):  # ST comment
                j = text.find("*)", i + 2)
                if j < 0:
                    raise self.error(i, "unterminated comment: expected '*)'")
                i = j + 2
                continue
            if text.startswith("//", i):
                j = text.find("\n", i)
                i = n if j < 0 else j
                continue
            if c.isdigit():
                tok = self._number(i)
                yield tok
                i = tok.end
                continue
            if c.isalpha() or c == "_":
                j = i + 1
                while j < n and (text[j].isalnum() or text[j] == "_"):
                    j += 1
                word = text[i:j]
                if j < n and text[j] == "#" and word.upper() in ("T", "TIME"):
                    k = j + 1
                    while k < n and (text[k].isalnum() or text[k] in "._"):
                        k += 1
                    lit = text[j + 1:k]
                    ns = parse_literal(lit)
                    if ns is None:
                        raise self.error(i, f"bad time literal '{text[i:k]}': expected units "
                                            "in order d h m s ms (e.g. T#1h30m)")
                    yield Tok("TIME", text[i:k], i, k, ns)
                    i = k
                    continue
                if j < n and text[j] == "#" and word.isdigit():  # pragma: no cover
                    pass
                kind = "KW" if word.upper() in KEYWORDS else "NAME"
                if kind == "NAME" and not is_name(word):
                    raise self.error(i, f"expected a name of letters, digits and '_', found "
                                        f"'{word}'")
                yield Tok(kind, word.upper() if kind == "KW" else word, i, j)
                i = j
                continue
            for op in _OPS:
                if text.startswith(op, i):
                    yield Tok("OP", op, i, i + len(op))
                    i += len(op)
                    break
            else:
                if unicodedata.category(c).startswith("M"):
                    raise self.error(i, f"expected a letter, found the combining mark "
                                        f"U+{ord(c):04X}: write accented letters precomposed "
                                        "(save the file in Unicode NFC form)")
                raise self.error(i, f"expected an operand or an operator, found the "
                                    f"unexpected character '{c}'")
        yield Tok("EOF", "", n, n)

    def _number(self, i: int) -> Tok:
        text, n = self.text, len(self.text)
        j = i
        while j < n and (text[j].isdigit() or text[j] == "_"):
            j += 1
        if j < n and text[j] == "#":  # based integer 16#FF, 2#1010
            base = int(text[i:j].replace("_", ""))
            k = j + 1
            while k < n and (text[k].isalnum() or text[k] == "_"):
                k += 1
            try:
                digits = text[j + 1:k].replace("_", "")
                value = int(digits, base) if len(digits.lstrip("0")) <= 64 else INT_MAX + 1
            except ValueError:
                raise self.error(i, f"bad based integer '{text[i:k]}'") from None
            return Tok("INT", text[i:k], i, k, self._bounded(i, text[i:k], value))
        is_real = False
        if j + 1 < n and text[j] == "." and text[j + 1].isdigit():
            is_real = True
            j += 1
            while j < n and text[j].isdigit():
                j += 1
        if j < n and text[j] in "eE" and (j + 1 < n and (text[j + 1].isdigit() or
                                                      text[j + 1] in "+-")):
            k = j + 1 + (text[j + 1] in "+-")
            if k < n and text[k].isdigit():
                is_real = True
                j = k
                while j < n and text[j].isdigit():
                    j += 1
        if j < n and (text[j].isalpha() or text[j] == "_"):
            k = j
            while k < n and (text[k].isalnum() or text[k] in "._"):
                k += 1
            lit = text[i:k]
            ns = parse_literal(lit)  # exact, however long
            if ns is not None and ns > TIME_MAX_NS:
                raise self.error(i, f"time out of range: expected at most "
                                    f"{format_ns(TIME_MAX_NS)} (64-bit nanoseconds), found "
                                    f"'{_short(lit)}'")
            if ns is None:
                raise self.error(i, f"bad time literal '{lit}': expected a number followed by "
                                    "units in order d h m s ms (e.g. 1m30s, 250ms)")
            return Tok("TIME", lit, i, k, ns)
        raw = text[i:j].replace("_", "")
        if is_real:
            return Tok("REAL", text[i:j], i, j, float(raw))
        value = int(raw) if len(raw.lstrip("0")) <= 20 else INT_MAX + 1
        return Tok("INT", text[i:j], i, j, self._bounded(i, text[i:j], value))

    def _bounded(self, i: int, lit: str, value: int) -> int:
        """An integer literal of at most 64 bits (ULINT's greatest; a minus sign is an
        operator), so a 5000-digit number is an error, not a crash of Python's int limit."""
        if value > INT_MAX:
            raise self.error(i, f"integer out of range: expected at most {INT_MAX} (64 "
                                f"bits), found '{_short(lit)}'")
        return value


def _short(lit: str) -> str:
    return lit if len(lit) <= 24 else f"{lit[:10]}...{lit[-6:]} ({len(lit)} characters)"
