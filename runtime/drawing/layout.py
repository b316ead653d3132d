"""Where everything of a drawn chart goes: rows, x of every element, lanes, channels, frames.

Steps and transitions in alternating rows, a step below every transition that leads to it
(links that go back up excepted). In a row, an element goes right under its main
predecessor (the first branch of a divergence continues straight down, the next ones go to
its right; transitions that lead back up come first, so that their lanes do not cross the
others), and the row is spread with the least displacement that keeps elements, conditions
and action blocks apart. The left-to-right order in each row comes from that rule
(``place(c)``) or from Graphviz's ``dot`` (``place(c, dot_order(c))``; fewer crossings on
large charts); the rest is common, so both look alike. Lengths are in px.
"""

from __future__ import annotations

import itertools
import subprocess
from collections import deque
from dataclasses import dataclass, field

from runtime.drawing.text import (
    action_parts,
    condition_lines,
    expression_text,
    step_times,
    text_w,
)
from runtime.language.model import Grafcet


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
TIMES_SIZE = 9.0  # font size of a step's min/max, under its name
STEP_H = 34.0
BAR_W = 34.0
GAP = 24.0  # between neighbours of a row
ACTION_GAP = 22.0  # from a step's right side to its action block
TOP = 62.0  # room for the title and the links into the first row
LANE = 16.0  # between lanes
#: between the horizontals of links leaving one row (issue 27: 6 px looked like one line)
LINK_GAP = 12.0
FRAME_PAD = 10.0  # between a macro-step's frame and what it holds
LIVE_SIZE = 10.0  # font size of an active step's time on the live page
#: a live drawing's room right of each step box, for its time (``9999.9 s``, ``9999 min``:
#: the page writes longer times in minutes, then hours), before its action block
LIVE_TIME_W = text_w("9999 min", LIVE_SIZE) + 6


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
    tree: dict[str, str] = field(default_factory=dict)  # element -> the one it was
    # discovered from in the depth-first walk (the sequence it continues)
    follow_tree: bool = False  # primary_pred: that one first
    notation: str = "written"  # conditions as the file wrote them, or "seed" (text.py)
    live_room: float = 0.0  # right of each step box, for the live page's step time (px)

    def fout(self, n: str) -> list[str]:
        return [c for c in self.out[n] if (n, c) not in self.back]

    def fin(self, n: str) -> list[str]:
        return [p for p in self.inc[n] if (p, n) not in self.back]

    def primary_pred(self, n: str) -> str | None:
        """The predecessor an element goes under: the nearest one (deepest row), then the
        first in file order; with ``follow_tree``, the one the depth-first walk reached it
        from first (the sequence it continues: a link from higher up then runs straight
        down to it past what the nearer one leads to)."""
        preds = self.fin(n)
        if not preds:
            return None
        if self.follow_tree and self.tree.get(n) in preds:
            return self.tree[n]
        return max(preds, key=lambda p: (self.nodes[p].layer, -self.inc[n].index(p)))

    def is_back_transition(self, t: str) -> bool:
        return bool(self.out[t]) and all((t, d) in self.back for d in self.out[t])


def build_chart(g: Grafcet, follow_tree: bool = False, notation: str = "written",
                live: bool = False) -> Chart:
    """The chart's graph and the room each element takes; ``live``: room right of each
    step box for the time the live page writes there (``LIVE_TIME_W``)."""
    room = LIVE_TIME_W if live else 0.0
    nodes: dict[str, Node] = {}
    actions: dict[str, list[tuple[str, list[str]]]] = {}
    cols: dict[str, tuple[float, float]] = {}
    labels: dict[str, list[str]] = {}
    names: dict[str, str] = {}
    for s in g.leaf_steps():
        w = max(64.0, text_w(s.name) + 22, text_w(step_times(s), TIMES_SIZE) + 16)
        right, height = w / 2 + room, STEP_H
        if s.actions:
            rows = [action_parts(a, notation) for a in s.actions]
            actions[s.name] = rows
            q = max(text_w(r[0], 11) for r in rows) + 12
            b = max(text_w(ln, 11) for r in rows for ln in r[1]) + 14
            cols[s.name] = (q, b)
            right += ACTION_GAP + q + b
            height = max(height, sum(row_h(r[1]) for r in rows))
        nodes["s:" + s.name] = Node("s:" + s.name, w / 2, right, height)
    for k, t in enumerate(g.transitions):
        tid = f"t:{k}"
        labels[tid] = condition_lines(expression_text(t.text, t.cond, notation))
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
    back, dfs, tree = _back_links(g, nodes, out)
    for st in g.leaf_steps():
        nodes["s:" + st.name].macro = st.parent
    for k, m in macro_of_transition(g).items():
        nodes[f"t:{k}"].macro = m
    c = Chart(g, nodes, out, inc, back, dfs, actions, cols, labels, names, tree=tree,
              follow_tree=follow_tree, notation=notation, live_room=room)
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


def row_h(lines: list[str]) -> float:
    return max(20.0, CHAR_H * len(lines) + 6)


def _back_links(g: Grafcet, nodes: dict[str, Node], out: dict[str, list[str]]
                ) -> tuple[set[tuple[str, str]], list[str], dict[str, str]]:
    """Links that close a cycle in a depth-first walk from the initial steps (transitions in
    file order): they are drawn going back up. Also the discovery order, and the element
    each one was discovered from."""
    roots = ["s:" + s.name for s in g.leaf_steps() if s.initial]
    roots += [f"t:{k}" for k, t in enumerate(g.transitions) if not t.src_steps]
    roots += list(nodes)
    state: dict[str, int] = {}  # 1 on the current path, 2 done
    back: set[tuple[str, str]] = set()
    order: list[str] = []
    tree: dict[str, str] = {}
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
                tree[c] = n
                stack.append((c, iter(list(out[c]))))
    return back, order, tree


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
    pred = {n: c.primary_pred(n) for n in c.nodes}
    root_of: dict[str, str] = {}  # each element's group: the root up its primary predecessors
    members: dict[str, list[str]] = {}
    for n in c.dfs:
        path, root = [], n
        while root not in root_of and (p := pred[root]) is not None:
            path.append(root)
            root = p
        root = root_of.get(root, root)
        for m in path:
            root_of[m] = root
        members.setdefault(root, []).append(n)
    roots = [r for r in c.dfs if pred[r] is None]
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
    long_and = [(s, t) for s, t in [*and_links(c), *straight_links(c)]
                if s not in skip and t not in skip]
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
            i0 = kids.index(_straight(c, kids, pref))
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


def _straight(c: Chart, kids: list[str], pref: dict[str, float]) -> str:
    """The child that goes right under its parent: the first transition whose target goes
    under it (the main line goes on), not a link back up or aside; else the first. A step's
    first transition in file order that leads back up (the normal sequence closing the
    cycle) stays on the main line: the others (a failure) go aside, their steps off the
    main line (issue 27: the failure step sat under the normal sequence)."""
    first = sorted(kids, key=pref.__getitem__)
    ts = [k for k in kids if k.startswith("t:")]
    if len(ts) > 1 and len(ts) == len(kids):
        by_file = min(ts, key=lambda k: int(k[2:]))
        if c.is_back_transition(by_file):
            return by_file
    for k in first:
        if k.startswith("t:") and any(c.primary_pred(d) == k for d in c.fout(k)):
            return k
    return first[0]


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
    split_drops: dict[tuple[str, str], float] = field(default_factory=dict)  # (AND
    # divergence, step) -> x where its link leaves the transition's own short double bar
    join_level: dict[str, int] = field(default_factory=dict)  # steps those links reach:
    # their OR convergence lines one above the other (LINK_GAP per level)


#: between the links that reach a short double bar of an AND convergence, px
DROP_GAP = 8.0


def shared_splits(c: Chart, r: Routes) -> dict[str, list[str]]:
    """AND divergence -> its targets in the order their links leave its double bar, left
    to right (the steps drawn under it by x, then those reached by a channel by the
    channel's x), for the divergences that share a target step with another one, or whose
    targets are all reached by channels. IEC 60848 has a double bar follow one
    transition: each of these gets its own short bar under its transition, rather than
    one bar spanning the steps, which several transitions would share (or none at all)."""
    def long(t: str, d: str) -> bool:
        return d in r.bus and t in long_links(c, d)
    splits = {t: c.fout(t) for t in c.nodes if t.startswith("t:") and len(c.fout(t)) > 1}
    out = {}
    for t, ds in splits.items():
        if (all(long(t, d) for d in ds)
                or any(o != t and d in splits[o] for o in splits for d in ds)):
            out[t] = sorted(ds, key=lambda d: (long(t, d), r.bus[d] if long(t, d)
                                               else c.nodes[d].x))
    return out


def _split_links(c: Chart, r: Routes) -> None:
    """Where the links leave the short double bars of shared_splits(), and the levels of
    the OR convergence lines of the steps they reach under the bars: in each row, the
    order (left one highest, or right one highest) whose lines are crossed least by the
    links and the steps' own verticals."""
    for t, ds in shared_splits(c, r).items():
        for j, d in enumerate(ds):
            r.split_drops[(t, d)] = c.nodes[t].x + (j - (len(ds) - 1) / 2) * LINK_GAP
    rows: dict[int, set[str]] = {}
    for t, d in r.split_drops:
        if d not in r.bus or t not in long_links(c, d):
            rows.setdefault(c.nodes[d].layer, set()).add(d)
    for steps in rows.values():
        into = {d: [x for (t, e), x in r.split_drops.items() if e == d
                    and (d not in r.bus or t not in long_links(c, d))]
                + ([r.bus[d]] if d in r.bus else []) for d in steps}
        span = {d: (min(into[d] + [c.nodes[d].x]), max(into[d] + [c.nodes[d].x]))
                for d in steps}
        by_x = sorted(steps, key=lambda d: c.nodes[d].x)
        order = min((by_x, by_x[::-1]), key=lambda o: _joins_crossed(c, o, into, span))
        for k, d in enumerate(order):
            r.join_level[d] = len(order) - 1 - k


def _joins_crossed(c: Chart, order: list[str], into: dict[str, list[float]],
                   span: dict[str, tuple[float, float]]) -> int:
    """Crossings of OR convergence lines one above the other in ``order`` (the first
    highest): links into a lower line across a higher one, a higher one's step's vertical
    across a lower line."""
    n = 0
    for hi, lo in itertools.combinations(order, 2):
        a, b = span[hi]
        n += sum(1 for x in into[lo] if a < x < b)
        n += 1 if span[lo][0] < c.nodes[hi].x < span[lo][1] else 0
    return n


def long_links(c: Chart, step: str) -> list[str]:
    """Transitions that lead to ``step`` from more than one row above (a channel), but the
    one it goes under (a straight line down, see straight_links)."""
    return [t for t in c.fin(step) if c.nodes[step].layer - c.nodes[t].layer > 1
            and c.primary_pred(step) != t]


def straight_links(c: Chart) -> list[tuple[str, str]]:
    """(transition, step) links that skip rows into a step drawn under the transition: a
    vertical line through the rows between, which the elements of those rows keep clear
    of (the main line goes on straight past a branch drawn beside it)."""
    return [(t, n) for n in c.nodes if n.startswith("s:")
            and (t := c.primary_pred(n)) is not None and c.nodes[n].layer - c.nodes[t].layer > 1]


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
    for s, t in [*and_links(c), *straight_links(c)]:
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

    def horizontals(v: str, lane: float) -> list[tuple[int, float, float]]:
        """(row, x0, x1) of the horizontals to and from a lane of ``v`` at ``lane``."""
        ends = [*groups[v], v]
        return [(c.nodes[u].layer, min(c.nodes[u].x, lane), max(c.nodes[u].x, lane))
                for u in ends]

    def crossings(v: str, lane: float) -> int:
        """Links that the horizontals to and from a lane at ``lane`` would cross: the
        elements between, and the lanes placed already (their verticals crossed by these
        horizontals, or their horizontals crossing this lane's vertical; issue 27: a
        return link across another)."""
        def between(row: int, x: float, skip: str) -> int:
            lo, hi = min(x, lane), max(x, lane)
            return sum(1 for n in c.layers[row] if n != skip and lo < c.nodes[n].x < hi)
        n = (sum(between(c.nodes[u].layer, c.nodes[u].x, u) for u in groups[v])
             + between(c.nodes[v].layer, c.nodes[v].x, v))
        rows = span(v)
        for w, wx in r.lane.items():
            wrows = span(w)
            n += sum(1 for row, x0, x1 in horizontals(v, lane)
                     if x0 < wx < x1 and wrows.start < row < wrows.stop - 1)
            n += sum(1 for row, x0, x1 in horizontals(w, wx)
                     if x0 < lane < x1 and rows.start < row < rows.stop - 1)
        return n

    def place_lanes(targets: list[str]) -> None:
        """Each target's lane, on the side where its horizontals cross fewer links (on a
        tie, the left, unless every link into it comes from the right of it); a lane that
        spans another goes outside it."""
        for v in sorted(targets, key=lambda v: (len(span(v)), -c.nodes[v].layer)):
            left = min(_extent(c, layer, extra)[0] for layer in span(v)) - LANE
            right = max(_extent(c, layer, extra)[1] for layer in span(v)) + LANE
            cl, cr = crossings(v, left), crossings(v, right)
            # on a tie, the side its links come from (a return link from a branch on the
            # right goes up on the right, leaving the left to the main line's)
            aside = min(c.nodes[u].x for u in groups[v]) > c.nodes[v].x
            x = left if cl < cr or (cl == cr and not aside) else right
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
    _split_links(c, r)
    _rows(c, r, groups)
    return r


def arrange(c: Chart, hint: dict[str, float] | None = None) -> Routes:
    """Place and route; then, if a link back up leaves to a lane on the right of a
    transition that goes on down (its line would cross that branch), put the transition
    leading back up right of its neighbours and place and route again."""
    place(c, hint)
    r = route(c)
    moved = False
    for n in c.nodes:
        if not n.startswith("s:"):
            continue
        kids = c.out[n]
        right = [t for t in kids if c.is_back_transition(t) and _lane_right(c, r, t)]
        last = max((c.nodes[k].x for k in kids if k not in right), default=None)
        late = [t for t in right if last is not None and c.nodes[t].x < last]
        if not late:
            continue
        moved = True
        c.out[n] = [k for k in kids if k not in late] + late
        if hint is not None:
            top = max(hint[k] for k in kids)
            for i, t in enumerate(late, 1):
                hint[t] = top + i * 1e-3
    if not moved:
        return r
    place(c, hint)
    return route(c)


def _lane_right(c: Chart, r: Routes, t: str) -> bool:
    return any(r.lane.get(d, c.nodes[t].x) > c.nodes[t].x for d in c.out[t])


def _rows(c: Chart, r: Routes, groups: dict[str, list[str]]) -> None:
    """y of each row, and of each horizontal that leaves a row: links going back up leave
    to the left (the rightmost lowest, so that none crosses another's drop), links into a
    channel to the right (the leftmost lowest). Frames get room above and below."""
    leaving: dict[int, list[tuple[str, str, int]]] = {}
    for v, us in groups.items():
        for u in us:
            side = -1 if r.lane[v] < c.nodes[u].x else 1
            leaving.setdefault(c.nodes[u].layer, []).append((u, v, side))
    arriving: dict[int, float] = {}  # room above a row for lines one above the other, px
    for v in {*r.lane_level, *r.join_level}:
        row = c.nodes[v].layer
        k = 6.0 * r.lane_level.get(v, 0)
        if v in r.join_level:  # and the highest line apart from the bars above
            k += LINK_GAP * (r.join_level[v] + 1)
        arriving[row] = max(arriving.get(row, 0.0), k)
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
        y += 16 * len(opening) + arriving.get(layer, 0.0)
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
        rights = sorted((o for o in out if o[2] > 0),
                        key=lambda o: -r.split_drops.get((o[0], o[1]), c.nodes[o[0]].x))
        for i, (u, v, _) in enumerate(lefts + rights):  # apart enough to be told apart
            r.leave[(u, v)] = first + LINK_GAP * i
        gap = max(30.0, first - bottom + LINK_GAP * len(out) + 14)
        y = bottom + gap

