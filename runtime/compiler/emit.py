"""The lines of a generated scan function as they are written, the local that holds each
chart name in it, the one way a text reaches a comment, a line's code without its strings
and comment, and a block of generated lines with some of its names replaced."""

from __future__ import annotations

import io
import keyword
import re
import tokenize
from collections.abc import Callable


def ident(prefix: str, name: str) -> str:
    """The local of a chart name: ``v_`` variable, ``x_`` ``t0_`` ``tk_`` a step's X and
    times, ``a_`` ``l_`` entered / left this scan, ``b_`` a block, ``s_`` a set target."""
    return f"{prefix}_{name}"


def one_line(text: str) -> str:
    """``text`` as one line of printable characters: every character that is not printable
    (CR, LF, VT, FF, NUL, the file separators, NEL, U+2028, U+2029, a tab ...) written as
    its Python escape (``\\r``), a backslash doubled. What a comment may carry of a user's
    text: nothing in it can end the comment for the compiler, ``tokenize`` or a line
    split."""
    if text.isprintable() and "\\" not in text:
        return text
    return "".join(c if c.isprintable() and c != "\\" else ascii(c)[1:-1] for c in text)


def comment(text: str) -> str:
    """A comment line's text (``# ...``) carrying ``text`` made :func:`one_line`: the only
    way an emitter writes a comment holding anything but its own words."""
    return "# " + one_line(text)


#: a name in a line of generated code
_NAME = re.compile(r"[A-Za-z_]\w*")
#: a string literal of generated code, as ``repr`` writes one (its prefix: group 1), or a
#: comment
_INERT = re.compile(r"""(?<!\w)([rRbBuUfF]{0,2})(?:'(?:[^'\\\n]|\\.)*'|"(?:[^"\\\n]|\\.)*")|#.*""")


def _inert(s: re.Match[str]) -> str:
    if s.group(1) is None:  # a comment
        return ""
    return s.group() if "f" in s.group(1).lower() else "''"  # an f-string's fields are code


def code_only(line: str) -> str:
    """``line`` of generated code with its strings emptied (``''``) and its comment cut:
    what names its words are. A chart's texts reach the code as strings and comments
    only, so no word of theirs may count as a name the code uses (a ``nonlocal`` to
    declare, a mark to clear, a default argument to bind)."""
    if "'" not in line and '"' not in line and "#" not in line:
        return line
    return _INERT.sub(_inert, line)


def code_names(line: str) -> list[str]:
    """The words of ``line`` of generated code that are names: outside its strings and
    its comment (:func:`code_only`), in order, repeats kept."""
    return _NAME.findall(code_only(line))


class Emitter:
    """Collects the lines of the scan function's body, indented four spaces a level."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.level = 1

    def __call__(self, line: str) -> None:
        self.lines.append("    " * self.level + line)

    def indent(self) -> None:
        self.level += 1

    def dedent(self) -> None:
        self.level -= 1


def renamed(lines: list[str], rename: Callable[[str], str | None]) -> list[str]:
    """``lines`` (a block of Python at column 0) with every name token that ``rename``
    maps (not None) replaced: an attribute after ``.`` and a keyword argument are not
    names, strings and comments are left as they are."""
    out = list(lines)
    edits: dict[int, list[tuple[int, int, str]]] = {}
    # the tokens one by one, with the one before and the one after: never a list of them
    # all (a large chart's fast path has 150 000; freeing such a list at once is one long
    # stretch holding the GIL, tens of ms)
    tokens = tokenize.generate_tokens(io.StringIO("\n".join(lines) + "\n").readline)
    prev: tokenize.TokenInfo | None = None
    tok = next(tokens, None)
    depth = 0
    while tok is not None:
        nxt = next(tokens, None)
        if tok.type == tokenize.OP:
            depth += tok.string in "([{"
            depth -= tok.string in ")]}"
        elif tok.type == tokenize.NAME and not keyword.iskeyword(tok.string) and not (
                prev is not None and prev.type == tokenize.OP and prev.string == "."
        ) and not (  # an attribute, a keyword argument: not names
                depth and nxt is not None and nxt.type == tokenize.OP and nxt.string == "="):
            new = rename(tok.string)
            if new is not None and new != tok.string:
                (row, col), (_, end) = tok.start, tok.end
                edits.setdefault(row - 1, []).append((col, end, new))
        prev, tok = tok, nxt
    for row, spans in edits.items():
        line = out[row]
        for col, end, new in sorted(spans, reverse=True):
            line = line[:col] + new + line[end:]
        out[row] = line
    return out
