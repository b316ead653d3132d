"""Texts read from a PLCopen file that keep the file place of every character (``YStr``), so
that the language's own parser reports a fault in an ST body at its line and column in the
XML file; and how IEC 61131-3's case-insensitive names become the chart's spelling."""

from __future__ import annotations

import re

from runtime.errors import Loc, SourceError
from runtime.language.lexer import Lexer
from runtime.language.yamlsrc import YStr, placed_str, synthetic_str
from runtime.plcopen.schema import XHTML_NS
from runtime.plcopen.xmltree import Element


def compose(parts: list[str | YStr], at: Loc) -> YStr:
    """The texts of ``parts`` one after the other; the characters of a YStr keep their
    places, those of a plain str (an operator the importer adds) are placed at ``at``."""
    places: list[tuple[int, int]] = []
    first: Loc | None = None
    for p in parts:
        if isinstance(p, YStr):
            own = p.places()
            places += own[:len(p)]
            places += [(at.line, at.col)] * (len(p) - len(own))
            if first is None and len(p):
                first = p.loc
        else:
            places += [(at.line, at.col)] * len(p)
    return placed_str("".join(parts), places, first or at)


def sub(s: YStr, start: int, end: int | None = None) -> YStr:
    """``s[start:end]`` keeping the places of its characters, white space stripped."""
    end = len(s) if end is None else end
    while start < end and s[start].isspace():
        start += 1
    while end > start and s[end - 1].isspace():
        end -= 1
    return placed_str(str(s)[start:end], s.places()[start:end],
                      s.pos(start) if start < len(s) else s.loc)


def plain(text: str, at: Loc) -> YStr:
    """A text that is not written as such in the file (an attribute's value), placed at the
    element that holds it."""
    return synthetic_str(text, at)


def formatted(e: Element) -> YStr:
    """The text of a ``formattedText`` (an ST body, a documentation): the text of its XHTML
    element (``xhtml:p`` as Beremiz writes it, ``xhtml`` as CODESYS does), or its own text
    in files that put it there directly."""
    for c in e.children:
        if c.ns == XHTML_NS:
            return _deep(c)
    return _deep(e)


def _deep(e: Element) -> YStr:
    """The text of ``e`` and of the elements inside it (an ``xhtml:br`` a line break)."""
    if not e.children:
        return e.ystr()
    parts: list[str | YStr] = [e.ystr(strip=False)]
    for c in e.children:
        parts.append("\n" if c.tag == "br" else "")
        parts.append(_deep(c))
    joined = compose(parts, e.loc)
    return sub(joined, 0)


def spell_as_declared(text: YStr, names: dict[str, str]) -> YStr:
    """``text`` with every name written in another case than declared spelled as declared
    (IEC 61131-3 names are case-insensitive, the language's are not); ``names`` maps each
    declared name in lower case to its spelling (names that collide in lower case are left
    out). A text the lexer cannot read is returned as it is (the parser reports it)."""
    try:
        toks = Lexer(str(text), text.pos).tokens()
    except SourceError:
        return text
    chars = list(str(text))
    changed = False
    for t in toks:
        if t.kind != "NAME":
            continue
        want = names.get(t.text.lower())
        if want is not None and want != t.text and len(want) == len(t.text):
            chars[t.start:t.end] = want
            changed = True
    if not changed:
        return text
    return placed_str("".join(chars), text.places(), text.loc)


def native_text(qualifier: str, duration: str | None, body: str) -> str:
    """The action text the importer reads from a native action: ``L T#2s oX``; a softplc
    event action (``on ... do``) stands alone."""
    if qualifier == "N" and duration is None and re.match(r"on\s", body.lstrip(), re.I):
        return body
    return " ".join(p for p in (qualifier, duration, body) if p)


#: the mark of a step action that came from a POU action: ``N (* action Blink *) ...``
_MARK = re.compile(r"\s*(?:(?:N|S|R|L|D|P|P1|P0|DS|SD|SL)\s+(?:(?:T#|TIME#)?\d[\w.#]*\s+)?)?"
                   r"\(\*\s*action\s+([A-Za-z_][A-Za-z0-9_]*)\s*\*\)", re.I)


def pou_action_mark(name: str) -> str:
    """The comment that marks a step action as the POU action ``name`` (docs/plcopen.md,
    "POU actions"): written after the qualifier and time, before the statements."""
    return f"(* action {name} *)"


def pou_action_of(text: str) -> str | None:
    """The POU action a step action's text is marked with (``[Q [TIME]] (* action NAME *)
    statements``), else None."""
    m = _MARK.match(text)
    return m.group(1) if m else None


def pou_action_as(name: str, body: str) -> str:
    """What softplc's data records an export wrote for a reference to POU action ``name``
    of ST ``body``: an edit of the body in an editor changes it."""
    return f"{name}: {body}"


def fingerprint(text: str) -> str:
    """A text with its white space made single spaces: what an edit of layout changes."""
    return " ".join(text.split())
