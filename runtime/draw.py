"""``softplc draw FILE -o OUT.svg``: a chart drawn in IEC 60848 style, as SVG.

What is drawn (seed 000's symbols): steps as boxes, initial steps as double boxes;
transitions as short thick bars with their condition in the seed notation on the right
(``↑iMarcha·iParo'``, whatever notation the file uses) and their name, if any, on the left;
actions as boxes beside their step (qualifier | body; comments left out, long bodies on
several lines); AND divergences and convergences as double horizontal lines, OR divergences
and convergences as single lines; links that go back up run in lanes on the left with an
upward arrow; links that skip rows (into an OR convergence) run down a channel on the right
of what they pass. Macro-step expansions are framed and captioned with the macro-step's name.

Layout: steps and transitions in alternating rows, a step below every transition that leads
to it (links that go back up excepted). In a row, an element goes right under its main
predecessor (the first branch of a divergence continues straight down, the next ones go to
its right; transitions that lead back up come first, so that their lanes do not cross the
others), and the row is spread with the least displacement that keeps elements, conditions
and action blocks apart. The left-to-right order in each row comes from that rule
(``--layout python``) or from Graphviz's ``dot`` (``--layout dot``, the default when ``dot``
is installed; fewer crossings on large charts); the rest is common, so both look alike.

With ``--trace TRACE.jsonl --cycle K`` the steps active in scan K of the trace (keys
``INSTANCE.STEP.X``) are filled and carry the GRAFCET token (a dot).
"""

from __future__ import annotations

import argparse
import html
import itertools
import json
import re
import shutil
import subprocess
import sys
from collections import deque
from dataclasses import dataclass, field

from runtime import ast as A
from runtime.check_logic import unparse
from runtime.errors import Loc, SourceError
from runtime.model import Action, Grafcet, Qualifier
from runtime.parser import format_time

ACTIVE_FILL = "#ffd54f"
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
            return format_time(int(n.value)), 0
        if n.lit_type is A.Type.BOOL or isinstance(n.value, bool):
            return ("1" if n.value else "0"), 0
        return f"{n.value!r}", (1 if n.value < 0 else 0)
    if isinstance(n, A.Name):
        return n.name, 0
    if isinstance(n, A.StepFlag):
        return f"{n.step}.{n.flag}", 0
    if isinstance(n, A.Member):
        return f"{n.obj}.{n.member}", 0
    if isinstance(n, A.MethodCall):
        return f"{n.obj}.{n.method}({', '.join(seed_text(a) for a in n.args)})", 0
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


def action_parts(a: Action) -> tuple[str, list[str]]:
    """(qualifier cell, body lines) of an action box: ``("D 500ms", ["oX"])``,
    ``("↑iPieza", ["sN := sN + 1"])`` for ``on ↑iPieza do sN := sN + 1``; comments are
    left out, a body keeps its line structure (IF ... END_IF) and long lines are wrapped."""
    text = _COMMENT.sub("", a.text).strip()
    if a.qualifier is Qualifier.EVENT:
        m = re.match(r"on\s+(.*?)\s+do\s+(.*)$", text, re.IGNORECASE | re.DOTALL)
        if m:
            return " ".join(m.group(1).split()), body_lines(m.group(2))
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
        q = f"{q} {format_time(a.time_ns)}"
    return q, body_lines(body)


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
    """A condition on one line, or split after its ``·``/``+`` when too long (3 lines at
    most)."""
    if len(text) <= width:
        return [text]
    pieces = re.split(r"(?<=·)|(?<= \+ )", text)
    lines = [""]
    for p in pieces:
        if lines[-1] and len(lines[-1]) + len(p) > width:
            lines.append(p.lstrip())
        else:
            lines[-1] += p
    if len(lines) > 3:
        lines = lines[:2] + ["".join(lines[2:])]
    return [ln if len(ln) <= width + 12 else ln[:width + 11] + "…" for ln in lines]


def macro_of_transition(g: Grafcet) -> dict[int, str]:
    """Transition position -> the innermost macro-step whose expansion writes it."""
    out: dict[int, str] = {}
    ids = {id(t): k for k, t in enumerate(g.transitions)}
    inner_first = sorted((s for s in g.steps.values() if s.macro is not None),
                         key=lambda s: -_depth(g, s.name))
    for s in inner_first:
        assert s.macro is not None
        for t in s.macro.transitions:
            k = ids.get(id(t))
            if k is not None and k not in out:
                out[k] = s.name
    return out


def _depth(g: Grafcet, name: str) -> int:
    d, p = 0, g.steps[name].parent
    while p is not None:
        d, p = d + 1, g.steps[p].parent
    return d


# -- the chart as a graph of steps and transitions ------------------------------------------
CHAR_H = 14.0  # line height of 11-12 px text
STEP_H = 34.0
BAR_W = 34.0
GAP = 24.0  # between neighbours of a row
ACTION_GAP = 22.0  # from a step's right side to its action block
TOP = 62.0  # room for the title and the links into the first row
LANE = 16.0  # between lanes
FRAME_PAD = 10.0  # between a macro-step's frame and what it holds


@dataclass
class Node:
    id: str  # "s:NAME" or "t:K"
    left: float  # extent left of the centre, name included
    right: float  # extent right of the centre, conditions and actions included
    height: float
    layer: int = 0
    x: float = 0.0
    macro: str | None = None  # the innermost macro-step whose expansion holds it


@dataclass
class Chart:
    """The chart's links split into forward links (a DAG) and links that go back up, and
    its rows."""

    g: Grafcet
    nodes: dict[str, Node]
    out: dict[str, list[str]]  # children in the order they are drawn, left to right
    inc: dict[str, list[str]]
    back: set[tuple[str, str]]
    dfs: list[str]  # discovery order
    actions: dict[str, list[tuple[str, list[str]]]]
    action_cols: dict[str, tuple[float, float]]
    labels: dict[str, list[str]]
    names: dict[str, str]
    layers: list[list[str]] = field(default_factory=list)

    def fout(self, n: str) -> list[str]:
        return [c for c in self.out[n] if (n, c) not in self.back]

    def fin(self, n: str) -> list[str]:
        return [p for p in self.inc[n] if (p, n) not in self.back]

    def primary_pred(self, n: str) -> str | None:
        """The predecessor an element goes under: the nearest one (deepest row), then the
        first in file order."""
        preds = self.fin(n)
        if not preds:
            return None
        return max(preds, key=lambda p: (self.nodes[p].layer, -self.inc[n].index(p)))

    def is_back_transition(self, t: str) -> bool:
        return bool(self.out[t]) and all((t, d) in self.back for d in self.out[t])


def build_chart(g: Grafcet) -> Chart:
    nodes: dict[str, Node] = {}
    actions: dict[str, list[tuple[str, list[str]]]] = {}
    cols: dict[str, tuple[float, float]] = {}
    labels: dict[str, list[str]] = {}
    names: dict[str, str] = {}
    for s in g.leaf_steps():
        w = max(64.0, text_w(s.name) + 22)
        right, height = w / 2, STEP_H
        if s.actions:
            rows = [action_parts(a) for a in s.actions]
            actions[s.name] = rows
            q = max(text_w(r[0], 11) for r in rows) + 12
            b = max(text_w(ln, 11) for r in rows for ln in r[1]) + 14
            cols[s.name] = (q, b)
            right += ACTION_GAP + q + b
            height = max(height, sum(_row_h(r[1]) for r in rows))
        nodes["s:" + s.name] = Node("s:" + s.name, w / 2, right, height)
    for k, t in enumerate(g.transitions):
        tid = f"t:{k}"
        labels[tid] = condition_lines(seed_text(t.cond))
        left = BAR_W / 2
        if t.name:
            names[tid] = t.name
            left += text_w(t.name) + 8
        right = BAR_W / 2 + 6 + max(text_w(x) for x in labels[tid])
        nodes[tid] = Node(tid, left, right, max(12.0, CHAR_H * len(labels[tid])))
    out: dict[str, list[str]] = {n: [] for n in nodes}
    inc: dict[str, list[str]] = {n: [] for n in nodes}
    for k, t in enumerate(g.transitions):
        tid = f"t:{k}"
        for src in dict.fromkeys(t.src_steps):
            out["s:" + src].append(tid)
            inc[tid].append("s:" + src)
        for d in dict.fromkeys(t.dst_steps):
            out[tid].append("s:" + d)
            inc["s:" + d].append(tid)
    back, dfs = _back_links(g, nodes, out)
    for st in g.leaf_steps():
        nodes["s:" + st.name].macro = st.parent
    for k, m in macro_of_transition(g).items():
        nodes[f"t:{k}"].macro = m
    c = Chart(g, nodes, out, inc, back, dfs, actions, cols, labels, names)
    _layers(c)
    # a step's transitions, left to right: those that lead back up first (the lanes of the
    # ones leading higher further out), then the others in file order
    for n in nodes:
        if n.startswith("s:"):
            def key(t: str) -> tuple[int, int, int]:
                if c.is_back_transition(t):
                    return (0, -min(c.nodes[d].layer for d in c.out[t]), int(t[2:]))
                # a transition whose target goes right under it continues the line; one
                # whose targets are drawn elsewhere (reached by a channel) goes aside
                under = any(c.primary_pred(d) == t for d in c.fout(t))
                return (1 if under else 2, 0, int(t[2:]))
            out[n].sort(key=key)
    return c


def _row_h(lines: list[str]) -> float:
    return max(20.0, CHAR_H * len(lines) + 6)


def _back_links(g: Grafcet, nodes: dict[str, Node],
                out: dict[str, list[str]]) -> tuple[set[tuple[str, str]], list[str]]:
    """Links that close a cycle in a depth-first walk from the initial steps (transitions in
    file order): they are drawn going back up."""
    roots = ["s:" + s.name for s in g.leaf_steps() if s.initial]
    roots += [f"t:{k}" for k, t in enumerate(g.transitions) if not t.src_steps]
    roots += list(nodes)
    state: dict[str, int] = {}  # 1 on the current path, 2 done
    back: set[tuple[str, str]] = set()
    order: list[str] = []
    for root in roots:
        if root in state:
            continue
        state[root] = 1
        order.append(root)
        stack = [(root, iter(list(out[root])))]
        while stack:
            n, it = stack[-1]
            c = next(it, None)
            if c is None:
                state[n] = 2
                stack.pop()
            elif state.get(c) == 1:
                back.add((n, c))
            elif c not in state:
                state[c] = 1
                order.append(c)
                stack.append((c, iter(list(out[c]))))
    return back, order


def _layers(c: Chart) -> None:
    """Longest path over the forward links: steps on even rows, transitions on odd ones."""
    indeg = {n: len(c.fin(n)) for n in c.nodes}
    for n, node in c.nodes.items():
        node.layer = 0 if n.startswith("s:") else 1
    queue = deque(n for n in c.dfs if indeg[n] == 0)
    while queue:
        n = queue.popleft()
        for ch in c.fout(n):
            c.nodes[ch].layer = max(c.nodes[ch].layer, c.nodes[n].layer + 1)
            indeg[ch] -= 1
            if indeg[ch] == 0:
                queue.append(ch)
    depth = max((nd.layer for nd in c.nodes.values()), default=0) + 1
    c.layers = [[] for _ in range(depth)]
    rank = {n: i for i, n in enumerate(c.dfs)}
    for n in sorted(c.nodes, key=lambda n: rank[n]):
        c.layers[c.nodes[n].layer].append(n)


# -- horizontal placement --------------------------------------------------------------------
def _sep(a: Node | None, b: Node | None) -> float:
    """Least distance between the centres of neighbours ``a`` and ``b`` (None: a line)."""
    ra = a.right if a is not None else 3.0
    lb = b.left if b is not None else 3.0
    gap = GAP if a is not None and b is not None else 12.0
    if a is not None and b is not None and a.macro != b.macro:
        gap += 2 * FRAME_PAD  # a frame runs between them
    return ra + gap + lb


def _spread(desired: list[float], weights: list[float], seps: list[float]) -> list[float]:
    """Positions in this order, each at least ``seps[i]`` right of the previous one, as near
    as possible to ``desired`` (weighted least squares: pool-adjacent-violators)."""
    offs = [0.0]
    for s in seps:
        offs.append(offs[-1] + s)
    blocks: list[list[float]] = []  # [value, weight, count]
    for d, o, w in zip(desired, offs, weights, strict=True):
        blocks.append([d - o, w, 1])
        while len(blocks) > 1 and blocks[-2][0] > blocks[-1][0]:
            v2, w2, n2 = blocks.pop()
            v1, w1, n1 = blocks.pop()
            blocks.append([(v1 * w1 + v2 * w2) / (w1 + w2), w1 + w2, n1 + n2])
    out: list[float] = []
    for v, _, n in blocks:
        out += [v] * int(n)
    return [v + o for v, o in zip(out, offs, strict=True)]


def and_links(c: Chart) -> list[tuple[str, str]]:
    """(source step, AND convergence) links that skip rows: a vertical line through them."""
    out = []
    for n in c.nodes:
        if n.startswith("t:") and len(c.fin(n)) > 1:
            for s in c.fin(n):
                if c.nodes[n].layer - c.nodes[s].layer > 1:
                    out.append((s, n))
    return out


def place(c: Chart, hint: dict[str, float] | None = None) -> None:
    """x of every element, row by row from the top. ``hint``: a left-to-right order (dot's
    x) instead of the one the rule gives. Elements with no predecessor (a second initial
    step, a source transition) start a group of their own: placed once, then again to the
    right of everything in the rows their group takes."""
    members: dict[str, list[str]] = {}
    for n in c.dfs:
        root = n
        while (p := c.primary_pred(root)) is not None:
            root = p
        members.setdefault(root, []).append(n)
    roots = [r for r in c.dfs if c.primary_pred(r) is None]
    later = {n for r in roots[1:] for n in members[r]}
    _place(c, hint, {}, later)  # the first group alone
    root_x: dict[str, float] = {}
    for r in roots[1:]:
        mine = set(members[r])
        later -= mine
        rows = {c.nodes[n].layer for n in mine}
        placed = [n for n in c.nodes if n not in mine and n not in later]
        rights = [c.nodes[n].x + c.nodes[n].right for n in placed if c.nodes[n].layer in rows]
        for lo, hi, x1 in _frame_rights(c, placed):  # frames of the groups already placed
            if any(lo <= row <= hi for row in rows):
                rights.append(x1)
        right = max(rights, default=None)
        if right is not None:
            root_x[r] = right + GAP + max(c.nodes[n].left for n in mine)
        _place(c, hint, root_x, later)


def _frame_rights(c: Chart, nodes: list[str]) -> list[tuple[int, int, float]]:
    """(first row, last row, right edge) of the frame of every macro-step among ``nodes``,
    as route() will draw it (nested frames add their padding, a caption may widen it)."""
    boxes: dict[str, list[float]] = {}  # macro -> [first row, last row, left, right]
    for n in nodes:
        nd = c.nodes[n]
        m = nd.macro
        while m is not None:
            b = boxes.setdefault(m, [nd.layer, nd.layer, nd.x - nd.left, nd.x + nd.right])
            b[0], b[1] = min(b[0], nd.layer), max(b[1], nd.layer)
            b[2], b[3] = min(b[2], nd.x - nd.left), max(b[3], nd.x + nd.right)
            m = c.g.steps[m].parent
    out = []
    for m, (lo, hi, x0, x1) in boxes.items():
        levels = 1 + max((_depth(c.g, n) - _depth(c.g, m) for n in boxes
                          if _within(c.g, n, m)), default=0)
        cap = text_w(f"{m} (macro-step)", 10) + 12
        out.append((int(lo), int(hi), max(x1 + FRAME_PAD * levels,
                                          x0 - FRAME_PAD * levels + cap)))
    return out


def _place(c: Chart, hint: dict[str, float] | None, root_x: dict[str, float],
           skip: set[str]) -> None:
    long_and = [(s, t) for s, t in and_links(c) if s not in skip and t not in skip]
    for layer, every in enumerate(c.layers):
        ids = [n for n in every if n not in skip]
        desired: dict[str, float] = {}
        weight: dict[str, float] = {}
        groups: dict[str, list[str]] = {}
        roots: list[str] = []
        for n in ids:
            p = c.primary_pred(n)
            if p is None:
                roots.append(n)
            else:
                groups.setdefault(p, []).append(n)
        for p, kids in groups.items():
            pref = {k: float(i) for i, k in enumerate(c.out[p])}
            kids.sort(key=(hint or pref).__getitem__)
            i0 = kids.index(min(kids, key=pref.__getitem__))
            desired[kids[i0]] = c.nodes[p].x
            # the main line stays straight; a convergence may move (its links bend anyway)
            weight[kids[i0]] = 1000.0 if len(c.fin(kids[i0])) == 1 else 3.0
            for i in range(i0 + 1, len(kids)):
                desired[kids[i]] = desired[kids[i - 1]] + _sep(c.nodes[kids[i - 1]],
                                                               c.nodes[kids[i]])
                weight[kids[i]] = 1.0
            for i in range(i0 - 1, -1, -1):
                desired[kids[i]] = desired[kids[i + 1]] - _sep(c.nodes[kids[i]],
                                                               c.nodes[kids[i + 1]])
                weight[kids[i]] = 1.0
        right_end = max((desired[n] + c.nodes[n].right for n in desired), default=None)
        for r in roots:
            node = c.nodes[r]
            desired[r] = 0.0 if right_end is None else right_end + GAP + node.left
            desired[r] = max(desired[r], root_x.get(r, desired[r]))
            weight[r] = 1.0
            right_end = desired[r] + node.right
        rank = {n: i for i, n in enumerate(ids)}
        if hint:
            order: list[str] = sorted(ids, key=lambda n: hint[n])
        else:
            order = sorted(ids, key=lambda n: (desired[n], rank[n]))
        # vertical lines that pass through this row (AND convergences skipping rows)
        lines = sorted(c.nodes[s].x for s, t in long_and
                       if c.nodes[s].layer < layer < c.nodes[t].layer)
        items: list[str | float] = []
        for n in order:
            while lines and lines[0] <= desired[n]:
                items.append(lines.pop(0))
            items.append(n)
        items += lines
        if not items:
            continue
        des = [desired[i] if isinstance(i, str) else i for i in items]
        wts = [weight[i] if isinstance(i, str) else 1e6 for i in items]
        seps = [_sep(c.nodes[a] if isinstance(a, str) else None,
                     c.nodes[b] if isinstance(b, str) else None)
                for a, b in itertools.pairwise(items)]
        for item, x in zip(items, _spread(des, wts, seps), strict=True):
            if isinstance(item, str):
                c.nodes[item].x = x


def dot_order(c: Chart, dot: str = "dot") -> dict[str, float]:
    """Graphviz's left-to-right order of the elements in each row (x of dot's layout)."""
    ids = {n: f"n{i}" for i, n in enumerate(c.dfs)}
    lines = ["digraph G {", "  graph [rankdir=TB, nodesep=0.25, ranksep=0.3, ordering=out];",
             "  node [shape=box, fixedsize=true, label=\"\"];"]
    for n in c.dfs:
        nd = c.nodes[n]
        lines.append(f"  {ids[n]} [width={(nd.left + nd.right) / 72:.3f}, "
                     f"height={nd.height / 72:.3f}];")
    for row in c.layers:
        if row:
            lines.append("  {rank=same; " + "; ".join(ids[n] for n in row) + "}")
    for n in c.dfs:
        for ch in c.fout(n):
            lines.append(f"  {ids[n]} -> {ids[ch]} "
                         f"[minlen={c.nodes[ch].layer - c.nodes[n].layer}];")
    lines.append("}")
    proc = subprocess.run([dot, "-Tplain"], input="\n".join(lines).encode(),
                          capture_output=True, timeout=60, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"dot failed: {proc.stderr.decode(errors='replace').strip()}")
    back = {v: k for k, v in ids.items()}
    xs: dict[str, float] = {}
    for line in proc.stdout.decode("utf-8").splitlines():
        parts = line.split()
        if len(parts) > 3 and parts[0] == "node" and parts[1] in back:
            n = back[parts[1]]
            xs[n] = float(parts[2]) * 72 - c.nodes[n].left + (c.nodes[n].left
                                                               + c.nodes[n].right) / 2
    missing = [n for n in c.nodes if n not in xs]
    if missing:
        raise RuntimeError(f"dot left out {len(missing)} element(s)")
    return xs


# -- routing: lanes, channels, frames, rows --------------------------------------------------
@dataclass
class Routes:
    """Where the lines that are not a node's own go, and the y of every row."""

    lane: dict[str, float] = field(default_factory=dict)  # target -> x of its back lane
    bus: dict[str, float] = field(default_factory=dict)  # step -> x of its channel
    frames: dict[str, list[float]] = field(default_factory=dict)  # macro -> x0 y0 x1 y1
    top: list[float] = field(default_factory=list)
    height: list[float] = field(default_factory=list)
    leave: dict[tuple[str, str], float] = field(default_factory=dict)  # link -> y of its
    # horizontal part below its source (back lanes and channels)
    caption_w: dict[str, float] = field(default_factory=dict)
    and_channel: dict[tuple[str, str], float] = field(default_factory=dict)  # an AND
    # convergence's source whose straight line down would cross an element: x of a channel
    lane_level: dict[str, int] = field(default_factory=dict)  # lanes into the same row on
    # the same side arrive one above the other (outer ones higher)
    pad: list[float] = field(default_factory=list)  # room below a row for closing frames


def long_links(c: Chart, step: str) -> list[str]:
    """Transitions that lead to ``step`` from more than one row above (a channel)."""
    return [t for t in c.fin(step) if c.nodes[step].layer - c.nodes[t].layer > 1]


def _extent(c: Chart, layer: int, extra: dict[int, list[tuple[float, float]]]
            ) -> tuple[float, float]:
    xs = [(c.nodes[n].x - c.nodes[n].left, c.nodes[n].x + c.nodes[n].right)
          for n in c.layers[layer]] + extra.get(layer, [])
    if not xs:
        return (float("inf"), float("-inf"))
    return min(a for a, _ in xs), max(b for _, b in xs)


def _macro_members(c: Chart) -> dict[str, set[str]]:
    """Macro-step -> the elements of its expansion (nested ones included)."""
    g = c.g
    owner = macro_of_transition(g)
    out: dict[str, set[str]] = {}
    for s in g.steps.values():
        if s.macro is None:
            continue
        mem = {"s:" + n for n in s.macro.steps if "s:" + n in c.nodes}
        mem |= {f"t:{k}" for k, m in owner.items() if _within(g, m, s.name)}
        out[s.name] = mem
    return out


def _within(g: Grafcet, inner: str, outer: str) -> bool:
    p: str | None = inner
    while p is not None:
        if p == outer:
            return True
        p = g.steps[p].parent
    return False


def route(c: Chart) -> Routes:
    r = Routes()
    extra: dict[int, list[tuple[float, float]]] = {}
    for s, t in and_links(c):
        for layer in range(c.nodes[s].layer + 1, c.nodes[t].layer):
            x = c.nodes[s].x
            extra.setdefault(layer, []).append((x - 3, x + 3))
    members = _macro_members(c)
    groups: dict[str, list[str]] = {}
    for a, b in sorted(c.back):
        groups.setdefault(b, []).append(a)

    def span(v: str) -> range:
        lo = c.nodes[v].layer
        hi = max(c.nodes[u].layer for u in groups[v])
        return range(min(lo, hi), max(lo, hi) + 1)

    def inner_macro(v: str) -> str | None:
        best = None
        for m, mem in members.items():
            if v in mem and all(u in mem for u in groups[v]) and (
                    best is None or _within(c.g, m, best)):
                best = m
        return best

    def crossings(v: str, lane: float) -> int:
        """Links that the horizontals to and from a lane at ``lane`` would cross."""
        def between(row: int, x: float, skip: str) -> int:
            lo, hi = min(x, lane), max(x, lane)
            return sum(1 for n in c.layers[row] if n != skip and lo < c.nodes[n].x < hi)
        return (sum(between(c.nodes[u].layer, c.nodes[u].x, u) for u in groups[v])
                + between(c.nodes[v].layer, c.nodes[v].x, v))

    def place_lanes(targets: list[str]) -> None:
        """Each target's lane, on the side where its horizontals cross fewer links (the
        left on a tie); a lane that spans another goes outside it."""
        for v in sorted(targets, key=lambda v: (len(span(v)), -c.nodes[v].layer)):
            left = min(_extent(c, layer, extra)[0] for layer in span(v)) - LANE
            right = max(_extent(c, layer, extra)[1] for layer in span(v)) + LANE
            x = left if crossings(v, left) <= crossings(v, right) else right
            r.lane[v] = x
            row = c.nodes[v].layer
            r.lane_level[v] = sum(1 for w in r.lane if w != v and c.nodes[w].layer == row
                                  and (r.lane[w] < c.nodes[w].x) == (x < c.nodes[v].x))
            for layer in span(v):
                extra.setdefault(layer, []).append((x - 3, x + 3))

    def place_buses(targets: list[str]) -> None:
        for v in sorted(targets, key=lambda n: c.nodes[n].layer):
            srcs = long_links(c, v)
            first = min(c.nodes[t].layer for t in srcs)
            rows = range(first + 1, c.nodes[v].layer)
            x = max([_extent(c, layer, extra)[1] for layer in rows]
                    + [c.nodes[t].x for t in srcs]) + LANE
            r.bus[v] = x
            for layer in rows:
                extra.setdefault(layer, []).append((x - 3, x + 3))

    def inside(v: str, srcs: list[str]) -> bool:
        return any(v in mem and all(u in mem for u in srcs) for mem in members.values())

    internal = [v for v in groups if inner_macro(v) is not None]
    place_lanes(internal)
    channels = [n for n in c.nodes if n.startswith("s:") and long_links(c, n)]
    place_buses([v for v in channels if inside(v, long_links(c, v))])
    for m in sorted(members, key=lambda m: -_depth(c.g, m)):  # innermost frames first
        mem = members[m]
        if not mem:
            continue
        layers = sorted({c.nodes[n].layer for n in mem})
        x0 = min(c.nodes[n].x - c.nodes[n].left for n in mem)
        x1 = max(c.nodes[n].x + c.nodes[n].right for n in mem)
        for v in internal:
            if v in mem:
                x0, x1 = min(x0, r.lane[v] - 3), max(x1, r.lane[v] + 3)
        for v, bx in r.bus.items():
            if v in mem:
                x1 = max(x1, bx + 3)
        for other, box in r.frames.items():
            if other != m and _within(c.g, other, m):
                x0, x1 = min(x0, box[0]), max(x1, box[2])
        cap = text_w(f"{m} (macro-step)", 10) + 12
        x0, x1 = x0 - FRAME_PAD, max(x1 + FRAME_PAD, x0 - FRAME_PAD + cap)
        r.frames[m] = [x0, float(layers[0]), x1, float(layers[-1])]  # rows for now
        r.caption_w[m] = cap
        for layer in range(layers[0], layers[-1] + 1):
            extra.setdefault(layer, []).append((x0, x1))
    place_buses([v for v in channels if v not in r.bus])
    for src, t in and_links(c):  # a straight line down, unless something is in the way
        xs = c.nodes[src].x
        rows = range(c.nodes[src].layer + 1, c.nodes[t].layer)
        if any(c.nodes[n].x - c.nodes[n].left - 4 < xs < c.nodes[n].x + c.nodes[n].right + 4
               for layer in rows for n in c.layers[layer]):
            x = max([_extent(c, layer, extra)[1] for layer in rows] + [xs]) + LANE
            r.and_channel[(src, t)] = x
            for layer in rows:
                extra.setdefault(layer, []).append((x - 3, x + 3))
    place_lanes([v for v in groups if v not in r.lane])
    _rows(c, r, groups)
    return r


def _rows(c: Chart, r: Routes, groups: dict[str, list[str]]) -> None:
    """y of each row, and of each horizontal that leaves a row: links going back up leave
    to the left (the rightmost lowest, so that none crosses another's drop), links into a
    channel to the right (the leftmost lowest). Frames get room above and below."""
    leaving: dict[int, list[tuple[str, str, int]]] = {}
    for v, us in groups.items():
        for u in us:
            side = -1 if r.lane[v] < c.nodes[u].x else 1
            leaving.setdefault(c.nodes[u].layer, []).append((u, v, side))
    arriving: dict[int, int] = {}
    for v, k in r.lane_level.items():
        row = c.nodes[v].layer
        arriving[row] = max(arriving.get(row, 0), k)
    for v in r.bus:
        for t in long_links(c, v):
            leaving.setdefault(c.nodes[t].layer, []).append((t, v, 1))
    for src, t in r.and_channel:
        leaving.setdefault(c.nodes[src].layer, []).append((src, t, 1))
    starts: dict[int, list[str]] = {}
    ends: dict[int, list[str]] = {}
    for m, box in r.frames.items():
        starts.setdefault(int(box[1]), []).append(m)
        ends.setdefault(int(box[3]), []).append(m)
    y = TOP
    for layer, ids in enumerate(c.layers):
        opening = sorted(starts.get(layer, []), key=lambda m: _depth(c.g, m))
        y += 16 * len(opening) + 6 * arriving.get(layer, 0)
        h = max((c.nodes[n].height for n in ids), default=STEP_H)
        r.top.append(y)
        r.height.append(h)
        for i, m in enumerate(opening):  # outer frames first, higher
            r.frames[m][1] = y - 16 * (len(opening) - i)
        closing = sorted(ends.get(layer, []), key=lambda m: -_depth(c.g, m))
        bottom = y + h
        for i, m in enumerate(closing):  # inner frames first, higher
            r.frames[m][3] = bottom + 6 + 8 * i
        pad = 6 + 8 * len(closing) if closing else 0.0
        r.pad.append(pad)
        base = bottom + pad
        mid = y + h / 2
        first = max(mid + 20, base + 12) if layer % 2 else base + 14
        out = leaving.get(layer, [])
        lefts = sorted((o for o in out if o[2] < 0), key=lambda o: c.nodes[o[0]].x)
        rights = sorted((o for o in out if o[2] > 0), key=lambda o: -c.nodes[o[0]].x)
        for i, (u, v, _) in enumerate(lefts + rights):
            r.leave[(u, v)] = first + 6 * i
        gap = max(30.0, first - bottom + 6 * len(out) + 14)
        y = bottom + gap


# -- rendering ---------------------------------------------------------------------------------
class Svg:
    def __init__(self) -> None:
        self.parts: list[str] = []
        self.x0 = self.y0 = float("inf")
        self.x1 = self.y1 = float("-inf")

    def _grow(self, x: float, y: float) -> None:
        self.x0, self.y0 = min(self.x0, x), min(self.y0, y)
        self.x1, self.y1 = max(self.x1, x), max(self.y1, y)

    def add(self, s: str) -> None:
        self.parts.append(s)

    def line(self, pts: list[tuple[float, float]], width: float = 1.2, cls: str = "") -> None:
        pts = [p for i, p in enumerate(pts) if i == 0 or p != pts[i - 1]]
        if len(pts) < 2:
            return
        for x, y in pts:
            self._grow(x, y)
        d = " ".join(f"{x:.1f},{y:.1f}" for x, y in pts)
        extra = f' class="{cls}"' if cls else ""
        self.add(f'<polyline points="{d}" fill="none" stroke="black" '
                 f'stroke-width="{width}"{extra}/>')

    def rect(self, x: float, y: float, w: float, h: float, fill: str = "white",
             extra: str = "") -> None:
        self._grow(x, y)
        self._grow(x + w, y + h)
        self.add(f'<rect x="{x:.1f}" y="{y:.1f}" width="{w:.1f}" height="{h:.1f}" '
                 f'fill="{fill}" stroke="black" stroke-width="1.2"{extra}/>')

    def text(self, x: float, y: float, s: str, size: float = 12, anchor: str = "start",
             extra: str = "") -> None:
        w = text_w(s, size)
        left = {"start": x, "middle": x - w / 2, "end": x - w}[anchor]
        self._grow(left, y - size)
        self._grow(left + w, y + 4)
        self.add(f'<text x="{x:.1f}" y="{y:.1f}" font-size="{size}" text-anchor="{anchor}"'
                 f'{extra}>{html.escape(s, quote=False)}</text>')

    def arrow_up(self, x: float, y: float) -> None:
        self.add(f'<polygon points="{x - 4:.1f},{y + 5:.1f} {x + 4:.1f},{y + 5:.1f} '
                 f'{x:.1f},{y - 4:.1f}" fill="black" class="arrow"/>')


class Drawing:
    """Draws a placed and routed chart."""

    def __init__(self, c: Chart, r: Routes, active: set[str]) -> None:
        self.c, self.r, self.active = c, r, active
        self.svg = Svg()
        self.arrivals: dict[str, list[float]] = {}  # step -> x of links reaching its line

    # geometry -------------------------------------------------------------------------
    def x(self, n: str) -> float:
        return self.c.nodes[n].x

    def mid(self, n: str) -> float:
        layer = self.c.nodes[n].layer
        return self.r.top[layer] + self.r.height[layer] / 2

    def bottom(self, layer: int) -> float:
        return self.r.top[layer] + self.r.height[layer] + self.r.pad[layer]

    def step_top(self, s: str) -> float:
        return self.mid(s) - STEP_H / 2

    def step_bottom(self, s: str) -> float:
        return self.mid(s) + STEP_H / 2

    def join_y(self, s: str) -> float:
        """The OR convergence line above a step: where every link into it arrives."""
        return self.r.top[self.c.nodes[s].layer] - 8

    def split_y(self, s: str) -> float:
        """The OR divergence line below a step (below its action block)."""
        return self.bottom(self.c.nodes[s].layer) + 8

    def and_in_y(self, t: str) -> float:
        layer = self.c.nodes[t].layer
        return min(self.mid(t) - 12, self.r.top[layer] - 4)

    def and_out_y(self, t: str) -> float:
        layer = self.c.nodes[t].layer
        return max(self.mid(t) + 12, self.r.top[layer] + self.r.height[layer] + 4)

    # links ----------------------------------------------------------------------------
    def draw_links(self) -> None:
        c = self.c
        for n in c.dfs:
            if n.startswith("s:"):
                self.step_out(n)
            else:
                self.transition_in(n)
                self.transition_out(n)
        for v, x in self.r.bus.items():
            srcs = long_links(c, v)
            y0 = min(self.r.leave[(t, v)] for t in srcs)
            self.svg.line([(x, y0), (x, self.join_y(v))], cls="channel")
            self.arrivals.setdefault(v, []).append(x)
        for v, x in self.r.lane.items():
            self.lane(v, x)
        for s, xs in self.arrivals.items():
            xs = [*xs, self.x(s)]
            y = self.join_y(s)
            cls = "or" if len(set(xs)) > 2 or len(self.c.inc[s]) > 1 else ""
            self.svg.line([(min(xs), y), (max(xs), y)], cls=cls)
            self.svg.line([(self.x(s), y), (self.x(s), self.step_top(s))])

    def step_out(self, s: str) -> None:
        c, xs = self.c, self.x(s)
        outs = c.fout(s)
        if not outs:
            return
        ends: list[tuple[float, float]] = []
        for t in list(outs):
            if (s, t) in self.r.and_channel:  # round what is in the way
                x, y = self.r.and_channel[(s, t)], self.r.leave[(s, t)]
                self.svg.line([(xs, self.step_bottom(s)), (xs, y), (x, y),
                               (x, self.and_in_y(t) - 2)], cls="channel")
                outs.remove(t)
            elif len(c.fin(t)) > 1:
                ends.append((xs, self.and_in_y(t) - 2))
            else:
                ends.append((self.x(t), self.mid(t) - 2))
        if not outs:
            return
        y = self.split_y(s)
        if len(outs) == 1:
            ex, ey = ends[0]
            if abs(ex - xs) < 0.5:
                self.svg.line([(xs, self.step_bottom(s)), (ex, ey)])
            else:
                self.svg.line([(xs, self.step_bottom(s)), (xs, y), (ex, y), (ex, ey)])
            return
        self.svg.line([(xs, self.step_bottom(s)), (xs, y)])
        span = [xs] + [ex for ex, _ in ends]
        self.svg.line([(min(span), y), (max(span), y)], cls="or")
        for ex, ey in ends:
            self.svg.line([(ex, y), (ex, ey)])

    def transition_in(self, t: str) -> None:
        c = self.c
        srcs = c.fin(t)
        if len(srcs) < 2:
            return
        y = self.and_in_y(t)
        xs = [self.r.and_channel.get((s, t), self.x(s)) for s in srcs] + [self.x(t)]
        for dy in (-2.0, 2.0):
            self.svg.line([(min(xs) - 12, y + dy), (max(xs) + 12, y + dy)], cls="and")
        self.svg.line([(self.x(t), y + 2), (self.x(t), self.mid(t) - 2)])

    def transition_out(self, t: str) -> None:
        c, xt, bar = self.c, self.x(t), self.mid(t)
        fw = c.fout(t)
        short = [d for d in fw if d not in self.r.bus or t not in long_links(c, d)]
        for d in fw:
            if d not in short:  # into a channel on the right
                y = self.r.leave[(t, d)]
                self.svg.line([(xt, bar + 2), (xt, y), (self.r.bus[d], y)])
        if len(short) > 1 or (len(fw) > 1 and short):  # AND divergence
            y = self.and_out_y(t)
            xs = [self.x(d) for d in short] + [xt]
            self.svg.line([(xt, bar + 2), (xt, y - 2)])
            for dy in (-2.0, 2.0):
                self.svg.line([(min(xs) - 12, y + dy), (max(xs) + 12, y + dy)], cls="and")
            for d in short:
                self.arrive(d, self.x(d), y + 2)
        elif short:
            self.arrive(short[0], xt, bar + 2)

    def arrive(self, s: str, x: float, y: float) -> None:
        """A line from (x, y) down to the step's OR convergence line."""
        self.svg.line([(x, y), (x, self.join_y(s))])
        self.arrivals.setdefault(s, []).append(x)

    def lane(self, v: str, x: float) -> None:
        """Links back up to ``v``: left, up the lane, right into ``v``."""
        c = self.c
        lows = []
        for u in sorted({a for a, b in c.back if b == v}):
            y = self.r.leave[(u, v)]
            start = self.mid(u) + 2 if u.startswith("t:") else self.step_bottom(u)
            self.svg.line([(self.x(u), start), (self.x(u), y), (x, y)], cls="back")
            lows.append(y)
        if v.startswith("s:"):
            top = self.join_y(v) - 6 * self.r.lane_level.get(v, 0)
            self.arrivals.setdefault(v, [])
            if top < self.join_y(v):
                self.svg.line([(self.x(v), top), (self.x(v), self.join_y(v))])
        else:  # a transition reached again from below (an AND convergence in a cycle)
            top = self.and_in_y(v) - 8 if len(c.fin(v)) > 1 else self.mid(v) - 14
            self.svg.line([(self.x(v), top), (self.x(v), self.mid(v) - 2)])
        low = max(lows)
        self.svg.line([(x, low), (x, top), (self.x(v), top)], cls="back")
        self.svg.arrow_up(x, (top + min(lows)) / 2 if min(lows) - top > 30 else (top + low) / 2)

    # elements -----------------------------------------------------------------------------
    def draw_frames(self) -> None:
        for m, (x0, y0, x1, y1) in self.r.frames.items():
            self.svg.rect(x0, y0, x1 - x0, y1 - y0, "none",
                          extra=' stroke-dasharray="5,3" class="macro"')
            self.svg.text(x1 - 5, y0 + 11, f"{m} (macro-step)", 10, "end",
                          extra=' class="macro-name"')

    def draw_transitions(self) -> None:
        c = self.c
        for n in c.dfs:
            if not n.startswith("t:"):
                continue
            x, y = self.x(n), self.mid(n)
            self.svg.line([(x - BAR_W / 2, y), (x + BAR_W / 2, y)], width=4, cls="transition")
            lines = c.labels[n]
            y0 = y + 4 - CHAR_H * (len(lines) - 1) / 2
            for i, ln in enumerate(lines):
                self.svg.text(x + BAR_W / 2 + 6, y0 + CHAR_H * i, ln, 12,
                              extra=' class="condition"')
            if n in c.names:
                self.svg.text(x - BAR_W / 2 - 6, y + 4, c.names[n], 12, "end",
                              extra=' class="transition-name"')

    def draw_steps(self) -> None:
        c = self.c
        for st in c.g.leaf_steps():
            n = "s:" + st.name
            x, y = self.x(n), self.mid(n)
            w = 2 * c.nodes[n].left
            x0, y0 = x - w / 2, y - STEP_H / 2
            fill = ACTIVE_FILL if st.name in self.active else "white"
            self.svg.add('<g class="step-group">')
            if st.description:
                self.svg.add(f"<title>{html.escape(st.description, quote=False)}</title>")
            self.svg.rect(x0, y0, w, STEP_H, fill, extra=' class="step"')
            if st.initial:
                self.svg.rect(x0 + 3.5, y0 + 3.5, w - 7, STEP_H - 7, fill,
                              extra=' class="initial"')
            self.svg.text(x, y + 4, st.name, 12, "middle", extra=' class="step-name"')
            if st.name in self.active:
                self.svg.add(f'<circle cx="{x:.1f}" cy="{y0 + STEP_H - 5:.1f}" r="2.5" '
                             'fill="black" class="token"/>')
            self.svg.add("</g>")
            if st.name in c.actions:
                self.draw_actions(st.name, x + w / 2, y)

    def draw_actions(self, step: str, x_right: float, y: float) -> None:
        rows = self.c.actions[step]
        qw, bw = self.c.action_cols[step]
        ax = x_right + ACTION_GAP
        total = sum(_row_h(lines) for _, lines in rows)
        yy = y - total / 2
        self.svg.line([(x_right, y), (ax, y)])
        self.svg.add(f'<g class="actions" data-step="{html.escape(step)}">')
        for q, lines in rows:
            h = _row_h(lines)
            self.svg.rect(ax, yy, qw, h)
            self.svg.rect(ax + qw, yy, bw, h)
            y0 = yy + h / 2 + 4 - CHAR_H * (len(lines) - 1) / 2
            self.svg.text(ax + qw / 2, yy + h / 2 + 4, q, 11, "middle",
                          extra=' class="qualifier"')
            for i, ln in enumerate(lines):
                body = ln.lstrip("\u00a0")  # indentation as an offset: SVG drops spaces
                indent = text_w(ln[:len(ln) - len(body)], 11)
                self.svg.text(ax + qw + 6 + indent, y0 + CHAR_H * i, body, 11,
                              extra=' class="action"')
            yy += h
        self.svg.add("</g>")


def render(c: Chart, r: Routes, active: set[str], title: str) -> str:
    d = Drawing(c, r, active)
    d.draw_frames()
    d.draw_links()
    d.draw_transitions()
    d.draw_steps()
    svg = d.svg
    title_svg = (f'<text x="0" y="26" font-size="15" font-weight="bold" class="title">'
                 f'{html.escape(title or c.g.name, quote=False)}</text>')
    x0 = min(svg.x0, 0.0) - 20
    width = max(svg.x1, text_w(title or c.g.name, 15)) - x0 + 20
    height = svg.y1 + 20
    head = (f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.0f}" '
            f'height="{height:.0f}" viewBox="{x0:.0f} 0 {width:.0f} {height:.0f}" '
            f'font-family="{FONT}">')
    title_svg = title_svg.replace('x="0"', f'x="{min(svg.x0, 0.0):.0f}"')
    return "\n".join([head, f"<title>{html.escape(c.g.name, quote=False)}</title>",
                      f'<rect x="{x0:.0f}" width="{width:.0f}" height="100%" fill="white"/>',
                      title_svg, *svg.parts, "</svg>"]) + "\n"


def chart_svg(g: Grafcet, active: set[str] | None = None, title: str = "",
              layout: str = "auto") -> tuple[str, str]:
    """(SVG text, layout used: "dot" or "python")."""
    c = build_chart(g)
    dot = shutil.which("dot") if layout in ("auto", "dot") else None
    if layout == "dot" and dot is None:
        raise RuntimeError("--layout dot: Graphviz's 'dot' is not installed "
                           "(apt-get install graphviz)")
    hint = dot_order(c, dot) if dot is not None else None
    place(c, hint)
    r = route(c)
    return render(c, r, active or set(), title), ("dot" if dot is not None else "python")


# -- trace -----------------------------------------------------------------------------------
def active_from_trace(g: Grafcet, trace: str, cycle: int,
                      instance: str | None) -> tuple[set[str], str, dict[str, object]]:
    """Steps of ``g`` active in scan ``cycle`` of the trace, the instance, and the row."""
    row = None
    with open(trace, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            line = line.strip()
            if not line:
                continue
            try:
                r = json.loads(line)
            except json.JSONDecodeError as exc:
                raise SourceError(Loc(trace, n, exc.colno), f"bad JSON: {exc.msg}") from None
            if r.get("cycle") == cycle:
                row = r
                break
    if row is None:
        raise SourceError(Loc(trace, 1, 1), f"no scan with cycle {cycle} in the trace")
    names = [s.name for s in g.leaf_steps()]
    if instance is None:
        found = [k[:-len(f".{names[0]}.X")] for k in row if k.endswith(f".{names[0]}.X")]
        found = [i for i in found if all(f"{i}.{n}.X" in row for n in names)]
        if not found:
            raise SourceError(Loc(trace, 1, 1), f"no instance of grafcet {g.name} in the "
                                                 f"trace (no key '*.{names[0]}.X')")
        if len(found) > 1:
            raise SourceError(Loc(trace, 1, 1), f"several instances run grafcet {g.name} "
                              f"in the trace ({', '.join(found)}): pick one with --instance")
        instance = found[0]
    missing = [n for n in names if f"{instance}.{n}.X" not in row]
    if len(missing) == len(names):
        raise SourceError(Loc(trace, 1, 1), f"the trace has no step of instance '{instance}'"
                                             f" (no key '{instance}.{names[0]}.X')")
    active = {n for n in names if row.get(f"{instance}.{n}.X")}
    return active, instance, row


# -- command line ------------------------------------------------------------------------------
def load_chart(path: str, instance: str | None) -> tuple[Grafcet, str | None]:
    """The grafcet of FILE (a grafcet file, or a plant file's instance)."""
    from runtime.check import file_kind
    from runtime.language import load_grafcet
    from runtime.plantfile import load_plant

    if file_kind(path) == "plant":
        p = load_plant(path)
        if instance is None:
            instance = next(iter(p.instances))
        if instance not in p.instances:
            raise SourceError(Loc(path, 1, 1), f"no instance '{instance}' in the plant "
                                               f"(instances: {', '.join(p.instances)})")
        return p.instances[instance].grafcet, instance
    return load_grafcet(path), instance


def draw(path: str, out: str, trace: str | None = None, cycle: int | None = None,
         instance: str | None = None, layout: str = "auto") -> str:
    """Write the SVG; returns the layout used ("dot" or "python")."""
    g, instance = load_chart(path, instance)
    active: set[str] = set()
    title = g.name
    if trace is not None:
        k = 0 if cycle is None else cycle
        active, instance, row = active_from_trace(g, trace, k, instance)
        title = f"{g.name} ({instance}) — cycle {k}, t = {row.get('t_ms', '?')} ms"
    svg, used = chart_svg(g, active, title, layout)
    with open(out, "w", encoding="utf-8") as f:
        f.write(svg)
    return used


def cmd_draw(args: argparse.Namespace) -> int:
    if args.cycle is not None and args.trace is None:
        sys.stderr.write("softplc draw: error: --cycle needs --trace\n")
        return 2
    try:
        used = draw(args.file, args.output, args.trace, args.cycle, args.instance, args.layout)
    except SourceError as exc:
        sys.stderr.write(f"{exc}\n")
        return 2
    except (OSError, RuntimeError) as exc:
        sys.stderr.write(f"softplc draw: error: {exc}\n")
        return 2
    sys.stderr.write(f"{args.output}: written ({used} layout)\n")
    return 0


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    d = sub.add_parser("draw", help="draw a chart in IEC 60848 style (SVG)",
                       description="Draw a grafcet (or a plant instance's grafcet) as SVG; "
                                   "with --trace/--cycle, mark the steps active in that scan.")
    d.add_argument("file", metavar="FILE", help="grafcet file, or plant file (see --instance)")
    d.add_argument("-o", "--output", required=True, metavar="OUT.svg")
    d.add_argument("--trace", metavar="TRACE.jsonl", help="trace written by simulate --trace")
    d.add_argument("--cycle", type=int, metavar="K", help="scan of the trace to show "
                                                          "(default 0)")
    d.add_argument("--instance", metavar="NAME", help="instance whose steps the trace shows "
                                                      "(needed when several run the chart)")
    d.add_argument("--layout", choices=("auto", "dot", "python"), default="auto",
                   help="auto: Graphviz's dot if installed, else the built-in layout")
    d.set_defaults(func=cmd_draw)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="softplc")
    sub = p.add_subparsers(dest="command", required=True)
    register(sub)
    args = p.parse_args(["draw", *(argv if argv is not None else sys.argv[1:])])
    return int(args.func(args))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

