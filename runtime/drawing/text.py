"""The texts of a drawn chart: conditions as the file wrote them (or in the seed notation),
action and condition lines.

Conditions, action conditions and events, and the pre/post equations are drawn as the
chart file wrote them (``notation="written"``, the default): the page's "why" list shows a
transition's text as written, and the drawing above it says the same words. With
``notation="seed"`` (``softplc draw --notation seed``) they are redrawn in the seed's
notation (``↑iMarcha·iParo'`` for ``RE iMarcha AND NOT iParo``).

Also how wide a text is drawn (DejaVu Sans advance widths), which the layout needs to keep
texts apart, and the font family of every drawing (``softplc draw`` and ``softplc
chronogram``).
"""

from __future__ import annotations

import re

from drivers.durations import format_ns
from runtime.language import ast as A
from runtime.language.model import Action, Qualifier, Statement, Step
from runtime.language.unparse import atom_text, unparse

#: the font family of every drawing; the widths below are this font's
FONT = "DejaVu Sans, Helvetica, Arial, sans-serif"

# -- text widths (DejaVu Sans advance widths, in em; a wider font only adds white space) ----
_EM: dict[str, float] = {
    **dict.fromkeys("abdghnopqu0123456789", 0.636), **dict.fromkeys("ekvxy", 0.6),
    **dict.fromkeys("cszJ", 0.55), **dict.fromkeys("ijlI'|.,:;!·", 0.3),
    **dict.fromkeys("frt", 0.4), **dict.fromkeys("()[]{}", 0.4), **dict.fromkeys("/\\", 0.34),
    **dict.fromkeys("=+<>#↑↓≥≤≠~^", 0.84), **dict.fromkeys("-", 0.37),
    **dict.fromkeys("*_", 0.5), "m": 0.98, "w": 0.82, "M": 0.87, "W": 0.99, " ": 0.32,
    "…": 1.0, "\u00a0": 0.32,
}


def text_w(text: str, size: float = 12) -> float:
    """Width of ``text`` in px at font size ``size`` px."""
    return size * sum(_EM.get(c, 0.74 if c.isupper() else 0.65) for c in text)


#: how a drawing writes conditions: as the file wrote them, or in the seed's notation
NOTATIONS = ("written", "seed")


def expression_text(written: str, node: A.Node, notation: str = "written") -> str:
    """An expression of the chart as drawn: ``written`` (the file's text) on one line, or
    ``node`` in the seed's notation."""
    if notation == "seed":
        return seed_text(node)
    return " ".join(_COMMENT.sub(" ", written).split()) or seed_text(node)


# -- the seed notation -----------------------------------------------------------------------
_BINARY = {"AND": ("·", 2), "MUL": (" * ", 2), "DIV": (" / ", 2), "MOD": (" MOD ", 2),
           "OR": (" + ", 3), "ADD": (" + ", 3), "SUB": (" - ", 3), "XOR": (" XOR ", 6)}
_COMPARE = {"EQ": "=", "NE": "<>", "LT": "<", "LE": "<=", "GT": ">", "GE": ">="}
_ASSOCIATIVE = {"AND", "MUL", "OR", "ADD", "XOR"}


def seed_text(n: A.Node) -> str:
    """An expression in the seed's notation: ``·`` ``+`` ``'`` ``↑`` ``↓``, with the
    parentheses that language.md's precedence table needs (comparisons inside ``·``/``+``
    are parenthesised, as seed 000 writes ``iCerrado·sParo + (sCierres >= 1000)``)."""
    return _seed(n)[0]


def _seed(n: A.Node) -> tuple[str, int]:
    """(text, level): 0 atom, 1 unary, then the levels of language.md (2 ``·``, 3 ``+``,
    4 comparisons, 6 XOR)."""
    if isinstance(n, A.Lit):
        if n.lit_type is A.Type.TIME:
            return format_ns(int(n.value)), 0
        if n.lit_type is A.Type.BOOL or isinstance(n.value, bool):
            return ("1" if n.value else "0"), 0
        return f"{n.value!r}", (1 if n.value < 0 else 0)
    atom = atom_text(n, seed_text)
    if atom is not None:
        return atom, 0
    if isinstance(n, A.Unary):
        inner, level = _seed(n.operand)
        if n.op == "NOT":  # postfix ' binds tighter than ↑: (↑a)' needs its parentheses
            if level == 0 or (isinstance(n.operand, A.Unary) and n.operand.op == "NOT"):
                return inner + "'", 1
            return f"({inner})'", 1
        sym = {"RE": "↑", "FE": "↓", "NEG": "-"}.get(n.op)
        if sym is not None:
            return (sym + inner if level <= 1 else f"{sym}({inner})"), 1
    if isinstance(n, A.Binary):
        if n.op in _COMPARE:
            op = n.text if n.text in ("=", "==", "<>", "!=", "≠", "<", "<=", "≤", ">", ">=",
                                      "≥") else _COMPARE[n.op]
            sym, level = f" {op} ", 4
        elif n.op in _BINARY:
            sym, level = _BINARY[n.op]
        else:
            return f"({unparse(n)})", 0
        left, ll = _seed(n.left)
        right, rl = _seed(n.right)
        lop = n.left.op if isinstance(n.left, A.Binary) else None
        rop = n.right.op if isinstance(n.right, A.Binary) else None
        # same level: only the same operator (or -, / after their kin) goes without
        # parentheses, so that a bool OR never reads as an arithmetic sum, nor the reverse
        if ll > level or (ll == level and (level == 4 or not _kin(lop, n.op))):
            left = f"({left})"
        if rl > level or (rl == level and (level == 4 or n.op not in _ASSOCIATIVE
                                           or rop != n.op)):
            right = f"({right})"
        return left + sym + right, level
    return f"({unparse(n)})", 0


def _kin(child: str | None, parent: str) -> bool:
    """Can ``child`` stand without parentheses as the left operand of ``parent``?"""
    families = ({"AND"}, {"OR"}, {"XOR"}, {"ADD", "SUB"}, {"MUL", "DIV", "MOD"})
    return any(child in f and parent in f for f in families)


# -- action boxes ---------------------------------------------------------------------------
_COMMENT = re.compile(r"\(\*.*?\*\)|//[^\n]*", re.DOTALL)
LINE_CHARS = 44  # characters per line of an action body or a condition
BODY_LINES = 6
EQUATION_CHARS = 72  # characters per line of a pre/post equation (beside the chart)


def action_parts(a: Action, notation: str = "written") -> tuple[str, list[str]]:
    """(qualifier cell, body lines) of an action box: ``("D 500ms", ["oX"])``,
    ``("↑iPieza", ["sN := sN + 1"])`` for ``on ↑iPieza do sN := sN + 1``; comments are
    left out, a body keeps its line structure (IF ... END_IF) and long lines are wrapped.
    A condition and an event as transitions' are (``notation``)."""
    text = _COMMENT.sub("", a.text).strip()
    if a.cond is not None and a.target is not None:  # `N x if C`: C as transitions are
        m = re.search(r"\bif\s+(.*)$", text, re.IGNORECASE | re.DOTALL)
        cond = expression_text(m.group(1) if m else "", a.cond,
                               notation if m else "seed")
        return "N", body_lines(f"{a.target} if {cond}")
    if a.qualifier is Qualifier.EVENT:
        m = re.match(r"on\s+(.*?)\s+do\s+(.*)$", text, re.IGNORECASE | re.DOTALL)
        if m:
            event = (expression_text(m.group(1), a.event, notation) if a.event is not None
                     else " ".join(m.group(1).split()))
            return event, body_lines(m.group(2))
        return "on", body_lines(text)
    q = a.qualifier.value
    words = text.split(None, 1)
    body = text
    if len(words) > 1 and words[0].upper() == q:
        body = words[1]
        if a.time_ns is not None:
            parts = body.split(None, 1)
            body = parts[1] if len(parts) > 1 else ""
    if a.time_ns is not None:
        q = f"{q} {format_ns(a.time_ns)}"
    return q, body_lines(body)


def step_times(st: Step) -> str:
    """A step's ``min``/``max`` as written in its box (``min 2s · max 10s``), or ""."""
    parts = [f"{k} {format_ns(v)}" for k, v in (("min", st.min_ns), ("max", st.max_ns))
             if v is not None]
    return " · ".join(parts)


def equation_lines(st: Statement, notation: str = "written") -> list[str]:
    """A pre/post statement as drawn: assignments, calls and block calls on one line (split
    when long), as written or with their expressions in the seed notation (``notation``);
    other statements (IF, CASE, FOR) as written, comments left out, line by line."""
    n = st.node
    if notation != "seed" and isinstance(n, (A.Assign, A.CallStmt, A.FbCall)):
        return condition_lines(" ".join(_COMMENT.sub(" ", st.text).split()), EQUATION_CHARS)
    if isinstance(n, A.Assign):
        return condition_lines(f"{n.target.name} := {seed_text(n.value)}", EQUATION_CHARS)
    if isinstance(n, A.CallStmt):
        return condition_lines(seed_text(n.call), EQUATION_CHARS)
    if isinstance(n, A.FbCall):
        args = ", ".join(f"{k} := {seed_text(v)}" for k, v in n.args)
        return condition_lines(f"{n.block}({args})", EQUATION_CHARS)
    return body_lines(_COMMENT.sub("", st.text), most=8)


def body_lines(body: str, width: int = LINE_CHARS, most: int = BODY_LINES) -> list[str]:
    """The lines of a body as drawn: blank lines dropped, indentation kept (as no-break
    spaces), lines longer than ``width`` wrapped, at most ``most`` lines."""
    out: list[str] = []
    for raw in body.splitlines():
        if not raw.strip():
            continue
        lead = min(len(raw) - len(raw.lstrip()), 8)
        out += wrap(raw.split(), width, lead)
    if not out:
        out = [""]
    if len(out) > most:
        out = out[:most - 1] + ["…"]
    return [ln.replace(" ", "\u00a0", len(ln) - len(ln.lstrip(" "))) for ln in out]


def wrap(words: list[str], width: int, lead: int = 0) -> list[str]:
    lines: list[str] = []
    cur = " " * lead
    for w in words:
        if cur.strip() and len(cur) + 1 + len(w) > width:
            lines.append(cur)
            cur = " " * (lead + 2) + w
        else:
            cur += (" " if cur.strip() else "") + w
    lines.append(cur)
    return [ln if len(ln) <= width else ln[:width - 1] + "…" for ln in lines]


def condition_lines(text: str, width: int = LINE_CHARS) -> list[str]:
    """A condition on one line, or split after its ``·``/``+`` (``AND``/``OR``) when too
    long (3 lines at most)."""
    if len(text) <= width:
        return [text]
    pieces = re.split(r"(?<=·)|(?<= \+ )|(?<= AND )|(?<= OR )", text)
    lines = [""]
    for p in pieces:
        if lines[-1] and len(lines[-1]) + len(p) > width:
            lines.append(p.lstrip())
        else:
            lines[-1] += p
    if len(lines) > 3:
        lines = lines[:2] + ["".join(lines[2:])]
    return [ln if len(ln) <= width + 12 else ln[:width + 11] + "…" for ln in lines]
