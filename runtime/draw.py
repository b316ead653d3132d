"""``softplc draw FILE -o OUT.svg``: a chart drawn in IEC 60848 style, as SVG.

Steps are boxes (initial steps double boxes), transitions short thick bars with their
condition as written, actions boxes beside their step (qualifier | body), AND divergences
and convergences double horizontal lines, OR divergences and convergences single lines,
links that go back up carry an arrow. Macro-step expansions are framed with the macro-step's
name.

Graphviz's ``dot`` lays the chart out when it is installed (Debian package ``graphviz``);
otherwise, or with ``--layout python``, a small layered layout written here is used (steps
by breadth-first depth from the initial steps, top to bottom), so the command works on a
controller without Graphviz.

With ``--trace TRACE.jsonl --cycle K`` the steps active in scan K of the trace (keys
``INSTANCE.STEP.X``) are filled and carry the GRAFCET token (a dot).
"""

from __future__ import annotations

import argparse
import html
import json
import re
import shutil
import subprocess
import sys
from collections import deque
from dataclasses import dataclass, field

from runtime.errors import Loc, SourceError
from runtime.model import Action, Grafcet, Qualifier
from runtime.parser import format_time

ACTIVE_FILL = "#ffd54f"
FONT = "DejaVu Sans, Helvetica, Arial, sans-serif"


# -- what is drawn -----------------------------------------------------------------------
def action_parts(a: Action) -> tuple[str, str]:
    """(qualifier cell, body cell) of an action box: ``("D 500ms", "oX")``,
    ``("↑iPieza", "sN := sN + 1")`` for ``on ↑iPieza do sN := sN + 1``."""
    text = " ".join(a.text.split())
    if a.qualifier is Qualifier.EVENT:
        m = re.match(r"on\s+(.*?)\s+do\s+(.*)$", text, re.IGNORECASE)
        if m:
            return m.group(1), m.group(2)
        return "on", text
    q = a.qualifier.value
    words = text.split(" ", 1)
    body = text
    if words[0].upper() == q and len(words) > 1:
        body = words[1]
        if a.time_ns is not None:
            parts = body.split(" ", 1)
            body = parts[1] if len(parts) > 1 else ""
    if a.time_ns is not None:
        q = f"{q} {format_time(a.time_ns)}"
    return q, body


def short(text: str, width: int = 48) -> str:
    text = " ".join(text.split())
    return text if len(text) <= width else text[:width - 1] + "…"


def macro_of_transition(g: Grafcet) -> dict[int, str]:
    """Transition position -> the innermost macro-step whose expansion writes it."""
    out: dict[int, str] = {}
    ids = {id(t): k for k, t in enumerate(g.transitions)}
    for s in g.steps.values():
        if s.macro is None:
            continue
        for t in s.macro.transitions:
            k = ids.get(id(t))
            if k is not None:
                out[k] = s.name
    return out


def back_links(g: Grafcet) -> set[tuple[int, str]]:
    """(transition, step) links that go back up: found by a depth-first walk from the
    initial steps (a link to a step on the current path is a back link)."""
    steps = [s.name for s in g.leaf_steps()]
    outs: dict[str, list[int]] = {s: [] for s in steps}
    for k, t in enumerate(g.transitions):
        for s in dict.fromkeys(t.src_steps):
            outs[s].append(k)
    state: dict[str, int] = {}  # 1 on the path, 2 done
    back: set[tuple[int, str]] = set()
    roots = [s.name for s in g.leaf_steps() if s.initial]
    roots += [d for t in g.transitions if not t.src_steps for d in t.dst_steps]
    roots += steps

    for root in roots:
        if root in state:
            continue
        stack: list[tuple[str, int, int]] = [(root, 0, 0)]  # step, transition idx, target idx
        state[root] = 1
        while stack:
            s, i, j = stack[-1]
            if i >= len(outs[s]):
                state[s] = 2
                stack.pop()
                continue
            t = g.transitions[outs[s][i]]
            if j >= len(t.dst_steps):
                stack[-1] = (s, i + 1, 0)
                continue
            stack[-1] = (s, i, j + 1)
            d = t.dst_steps[j]
            if state.get(d) == 1:
                back.add((outs[s][i], d))
            elif d not in state:
                state[d] = 1
                stack.append((d, 0, 0))
    return back


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


# -- layouts ---------------------------------------------------------------------------------
CHAR_W = 7.0  # average width of a character at 12 px
STEP_H = 34.0
BAR_W = 34.0
ROW_GAP = 22.0
ACTION_ROW = 20.0
ACTION_GAP = 24.0  # from a step's right side to its action block


def text_w(text: str, size: float = 12) -> float:
    return len(text) * CHAR_W * size / 12


@dataclass
class Sizes:
    """What every element needs, in px, whatever lays it out."""

    step_w: dict[str, float]
    actions: dict[str, list[tuple[str, str]]]
    action_w: dict[str, tuple[float, float]]  # qualifier column, body column
    label: dict[int, str]

    @classmethod
    def of(cls, g: Grafcet) -> Sizes:
        step_w, actions, action_w = {}, {}, {}
        for s in g.leaf_steps():
            w = max(64.0, text_w(s.name) + 20)
            if s.parent:
                w = max(w, text_w(f"({s.parent})", 9) + 12)
            step_w[s.name] = w
            if s.actions:
                parts = [(q, short(b)) for q, b in map(action_parts, s.actions)]
                actions[s.name] = parts
                action_w[s.name] = (max(text_w(q, 11) for q, _ in parts) + 12,
                                    max(text_w(b, 11) for _, b in parts) + 14)
        label = {k: short(t.text, 40) for k, t in enumerate(g.transitions)}
        return cls(step_w, actions, action_w, label)

    def actions_width(self, step: str) -> float:
        if step not in self.action_w:
            return 0.0
        q, b = self.action_w[step]
        return q + b

    def label_width(self, k: int) -> float:
        return text_w(self.label[k]) + 8


@dataclass
class Layout:
    """Centres of step boxes and transition bars; where action blocks and conditions
    start; macro-step frames. y grows downwards."""

    steps: dict[str, tuple[float, float]] = field(default_factory=dict)
    trans: dict[int, tuple[float, float]] = field(default_factory=dict)
    actions: dict[str, float] = field(default_factory=dict)  # left x of the block
    labels: dict[int, float] = field(default_factory=dict)  # left x of the text
    frames: list[tuple[str, float, float, float, float]] = field(default_factory=list)


# -- Graphviz: dot places the nodes, the renderer below draws the links ------------------------
def _q(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def to_dot(g: Grafcet, sz: Sizes | None = None) -> str:
    """The chart as a dot graph whose nodes have the sizes of the drawn elements: steps,
    transitions, and beside them their action blocks and conditions (same rank)."""
    sz = sz or Sizes.of(g)
    back = back_links(g)
    owner = macro_of_transition(g)
    body: dict[str | None, list[str]] = {}

    def put(container: str | None, text: str) -> None:
        body.setdefault(container, []).append(text)

    # a step, the transitions below it and the steps they lead to line up when they form
    # a simple chain: same dot group
    group: dict[str, str] = {}
    for t in g.transitions:
        if len(t.src_steps) == 1 and len(t.dst_steps) <= 1:
            group.setdefault(f"t:{t.index}", t.src_steps[0])

    def node(name: str, w: float, h: float, grp: str | None = None) -> str:
        extra = f", group={_q(grp)}" if grp else ""
        return f"{_q(name)} [width={w / 72:.3f}, height={h / 72:.3f}{extra}]"

    for s in g.leaf_steps():
        tall = max(STEP_H, ACTION_ROW * len(sz.actions.get(s.name, [])))
        put(s.parent, node("s:" + s.name, sz.step_w[s.name], tall, s.name))
        if s.name in sz.actions:
            h = ACTION_ROW * len(sz.actions[s.name])
            put(s.parent, node("a:" + s.name, sz.actions_width(s.name), h))
            put(s.parent, f'{{rank=same; {_q("s:" + s.name)}; {_q("a:" + s.name)}}}')
            put(s.parent, f'{_q("s:" + s.name)} -> {_q("a:" + s.name)} [minlen=1, weight=20];')
    edges: list[str] = []
    for k, t in enumerate(g.transitions):
        tid, lid = f"t:{k}", f"l:{k}"
        put(owner.get(k), node(tid, BAR_W, 12, group.get(tid)))
        put(owner.get(k), node(lid, sz.label_width(k), 14))
        put(owner.get(k), f"{{rank=same; {_q(tid)}; {_q(lid)}}}")
        put(owner.get(k), f"{_q(tid)} -> {_q(lid)} [minlen=1, weight=20];")
        for src in dict.fromkeys(t.src_steps):
            edges.append(f'{_q("s:" + src)} -> {_q(tid)};')
        for d in dict.fromkeys(t.dst_steps):
            extra = " [constraint=false]" if (k, d) in back else ""
            edges.append(f'{_q(tid)} -> {_q("s:" + d)}{extra};')
    lines = [f"digraph {_q(g.name)} {{",
             "  graph [rankdir=TB, nodesep=0.3, ranksep=0.3, splines=false];",
             "  node [shape=box, fixedsize=true, label=\"\"];"]

    def cluster(name: str | None, indent: str) -> None:
        if name is not None:
            lines.append(f"{indent}subgraph {_q('cluster_' + name)} {{")
            lines.append(f"{indent}  margin=12; fontsize=10; labeljust=l; "
                         f"label={_q(name + ' (macro-step)')};")
        lines.extend(indent + "  " + x for x in body.get(name, []))
        for st in g.steps.values():
            if st.macro is not None and st.parent == name:
                cluster(st.name, indent + "  ")
        if name is not None:
            lines.append(f"{indent}}}")

    cluster(None, "")
    lines += ["  " + e for e in edges]
    lines.append("}")
    return "\n".join(lines) + "\n"


def dot_layout(g: Grafcet, sz: Sizes, dot: str = "dot") -> Layout:
    proc = subprocess.run([dot, "-Tjson0"], input=to_dot(g, sz).encode(), capture_output=True,
                          timeout=60, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"dot failed: {proc.stderr.decode(errors='replace').strip()}")
    data = json.loads(proc.stdout.decode("utf-8"))
    height = float(data["bb"].split(",")[3])
    top = 46.0  # room for the title

    def pos(obj: dict[str, object]) -> tuple[float, float]:
        x, y = (float(v) for v in str(obj["pos"]).split(","))
        return x + 20, height - y + top

    lay = Layout()
    for obj in data.get("objects", []):
        name = str(obj.get("name", ""))
        if name.startswith("cluster_") and "bb" in obj:
            x0, y0, x1, y1 = (float(v) for v in str(obj["bb"]).split(","))
            lay.frames.append((name[len("cluster_"):], x0 + 20, height - y1 + top, x1 + 20,
                               height - y0 + top))
            continue
        if "pos" not in obj:
            continue
        x, y = pos(obj)
        w = float(str(obj.get("width", 0))) * 72
        kind, _, key = name.partition(":")
        if kind == "s":
            lay.steps[key] = (x, y)
        elif kind == "t":
            lay.trans[int(key)] = (x, y)
        elif kind == "a":
            lay.actions[key] = x - w / 2
    for k, (x, _) in lay.trans.items():  # the condition right beside its bar
        lay.labels[k] = x + BAR_W / 2 + 6
    return lay


# -- the pure-Python layout --------------------------------------------------------------------
@dataclass
class _Node:
    key: tuple[str, str | int]
    w: float  # the element itself
    extra: float  # room on its right (actions, condition)
    layer: int = 0
    x: float = -1.0
    preds: list[_Node] = field(default_factory=list)


def python_layout(g: Grafcet, sz: Sizes) -> Layout:
    """Layers by breadth-first depth from the initial steps (and source transitions);
    in a layer, each element goes under its predecessors when there is room."""
    trans = g.transitions
    nodes: dict[tuple[str, str | int], _Node] = {}
    for s in g.leaf_steps():
        extra = ACTION_GAP + sz.actions_width(s.name) if s.name in sz.actions else 0.0
        nodes[("s", s.name)] = _Node(("s", s.name), sz.step_w[s.name], extra)
    for k in range(len(trans)):
        nodes[("t", k)] = _Node(("t", k), BAR_W, 6 + sz.label_width(k))
    succ: dict[tuple[str, str | int], list[tuple[str, str | int]]] = {n: [] for n in nodes}
    for k, t in enumerate(trans):
        for src in dict.fromkeys(t.src_steps):
            succ[("s", src)].append(("t", k))
        for d in dict.fromkeys(t.dst_steps):
            succ[("t", k)].append(("s", d))
    depth: dict[tuple[str, str | int], int] = {}
    order: list[tuple[str, str | int]] = []
    Key = tuple[str, str | int]
    starts: list[tuple[Key, int]] = [(("s", s.name), 0) for s in g.leaf_steps() if s.initial]
    starts += [(("t", k), 1) for k, t in enumerate(trans) if not t.src_steps]
    starts += [(n, 0 if n[0] == "s" else 1) for n in nodes]
    for root, d0 in starts:
        if root in depth:
            continue
        depth[root] = d0
        queue = deque([root])
        while queue:
            n = queue.popleft()
            order.append(n)
            for c in succ[n]:
                if c not in depth:
                    depth[c] = depth[n] + 1
                    queue.append(c)
    for n, node in nodes.items():
        node.layer = depth[n]
        for c in succ[n]:
            if depth[c] > depth[n]:
                nodes[c].preds.append(node)
    nlayers = max(depth.values(), default=0) + 1
    layers: list[list[_Node]] = [[] for _ in range(nlayers)]
    for n in order:
        layers[depth[n]].append(nodes[n])
    lay = Layout()
    y = 46.0
    for i, layer in enumerate(layers):
        h = STEP_H if i % 2 == 0 else 12.0
        tallest = max((ACTION_ROW * len(sz.actions.get(str(nd.key[1]), [])) for nd in layer
                       if nd.key[0] == "s"), default=0.0)
        h = max(h, tallest)
        cy = y + h / 2
        for nd in layer:
            nd.x = sum(p.x for p in nd.preds) / len(nd.preds) if nd.preds else -1.0
        layer.sort(key=lambda nd: nd.x)
        right = 20.0
        for nd in layer:
            nd.x = max(nd.x, right + nd.w / 2)
            right = nd.x + nd.w / 2 + nd.extra + 24
            if nd.key[0] == "s":
                name = str(nd.key[1])
                lay.steps[name] = (nd.x, cy)
                if name in sz.actions:
                    lay.actions[name] = nd.x + nd.w / 2 + ACTION_GAP
            else:
                k = int(nd.key[1])
                lay.trans[k] = (nd.x, cy)
                lay.labels[k] = nd.x + BAR_W / 2 + 6
        y += h + ROW_GAP
    return lay


# -- rendering -----------------------------------------------------------------------------------
class Svg:
    def __init__(self) -> None:
        self.parts: list[str] = []
        self.right = 0.0
        self.bottom = 0.0

    def _grow(self, x: float, y: float) -> None:
        self.right = max(self.right, x)
        self.bottom = max(self.bottom, y)

    def add(self, s: str) -> None:
        self.parts.append(s)

    def line(self, pts: list[tuple[float, float]], width: float = 1.2, extra: str = "") -> None:
        for x, y in pts:
            self._grow(x, y)
        d = " ".join(f"{x:.1f},{y:.1f}" for x, y in pts)
        self.add(f'<polyline points="{d}" fill="none" stroke="black" '
                 f'stroke-width="{width}"{extra}/>')

    def rect(self, x: float, y: float, w: float, h: float, fill: str = "white",
             extra: str = "") -> None:
        self._grow(x + w, y + h)
        self.add(f'<rect x="{x:.1f}" y="{y:.1f}" width="{w:.1f}" height="{h:.1f}" '
                 f'fill="{fill}" stroke="black" stroke-width="1.2"{extra}/>')

    def text(self, x: float, y: float, s: str, size: float = 12, anchor: str = "start",
             extra: str = "") -> None:
        w = text_w(s, size)
        self._grow(x + (w if anchor == "start" else w / 2), y + 4)
        self.add(f'<text x="{x:.1f}" y="{y:.1f}" font-size="{size}" text-anchor="{anchor}"'
                 f'{extra}>{html.escape(s, quote=False)}</text>')

    def arrow_up(self, x: float, y: float) -> None:
        self.add(f'<polygon points="{x - 4:.1f},{y + 5:.1f} {x + 4:.1f},{y + 5:.1f} '
                 f'{x:.1f},{y - 4:.1f}" fill="black"/>')


def render(g: Grafcet, lay: Layout, sz: Sizes, active: set[str], title: str) -> str:
    svg = Svg()
    content_right = max([x + sz.step_w[n] / 2 for n, (x, _) in lay.steps.items()]
                        + [lay.actions[n] + sz.actions_width(n) for n in lay.actions]
                        + [lay.labels[k] + sz.label_width(k) for k in lay.labels]
                        + [f[3] for f in lay.frames] + [200.0])
    lane = content_right + 10
    for name, x0, y0, x1, y1 in lay.frames:
        svg.rect(x0, y0, x1 - x0, y1 - y0, "none",
                 extra=' stroke-dasharray="5,3" class="macro"')
        svg.text(x0 + 4, y0 + 12, f"{name} (macro-step)", 10, extra=' class="macro-name"')
    half = STEP_H / 2

    def step_bottom(s: str) -> tuple[float, float]:
        x, y = lay.steps[s]
        return x, y + half

    def clearance(s: str) -> float:
        """Below the step and its action block: where a divergence line may run."""
        return lay.steps[s][1] + max(half, ACTION_ROW * len(sz.actions.get(s, [])) / 2)

    def step_top(s: str) -> tuple[float, float]:
        x, y = lay.steps[s]
        return x, y - half

    lanes: dict[tuple[float, float], float] = {}  # back links into one step share a lane

    def down(src: tuple[float, float], dst: tuple[float, float],
             clear: float | None = None) -> None:
        """From a bottom connection down to a top connection (the horizontal part just
        below ``clear``, the source by default), or round the right side with an upward
        arrow when the target is not below."""
        nonlocal lane
        (x0, y0), (x1, y1) = src, dst
        if y1 > y0 + 4:
            mid = min(max(y0, clear or y0) + 9, y1 - 4)
            if abs(x1 - x0) <= 0.5:
                mid = y0
            svg.line([(x0, y0), (x0, mid), (x1, mid), (x1, y1)])
            return
        if dst not in lanes:
            lane += 12
            lanes[dst] = lane
            svg.line([(lane, y1 - 10), (x1, y1 - 10), (x1, y1)])
        x = lanes[dst]
        svg.line([(x0, y0), (x0, y0 + 8), (x, y0 + 8), (x, y1 - 10)])
        svg.arrow_up(x, (y0 + y1) / 2)

    for k, t in enumerate(g.transitions):
        tx, ty = lay.trans[k]
        srcs = list(dict.fromkeys(t.src_steps))
        dsts = list(dict.fromkeys(t.dst_steps))
        if len(srcs) > 1:  # AND convergence: double line above the bar
            xs = [lay.steps[n][0] for n in srcs] + [tx]
            yy = ty - 14
            for dy in (-2.0, 2.0):
                svg.line([(min(xs) - 12, yy + dy), (max(xs) + 12, yy + dy)],
                         extra=' class="and"')
            for n in srcs:
                down(step_bottom(n), (lay.steps[n][0], yy - 2), clearance(n))
            svg.line([(tx, yy + 2), (tx, ty - 2)])
        else:
            for n in srcs:
                down(step_bottom(n), (tx, ty - 2), clearance(n))
        if len(dsts) > 1:  # AND divergence: double line below the bar
            xs = [lay.steps[d][0] for d in dsts] + [tx]
            yy = ty + 14
            svg.line([(tx, ty + 2), (tx, yy - 2)])
            for dy in (-2.0, 2.0):
                svg.line([(min(xs) - 12, yy + dy), (max(xs) + 12, yy + dy)],
                         extra=' class="and"')
            for d in dsts:
                dx, dtop = step_top(d)
                if dtop > yy + 4:
                    svg.line([(dx, yy + 2), (dx, dtop)])
                else:
                    down((dx, yy + 2), (dx, dtop))
        else:
            for d in dsts:
                down((tx, ty + 2), step_top(d))
        svg.line([(tx - BAR_W / 2, ty), (tx + BAR_W / 2, ty)], width=4,
                 extra=' class="transition"')
        svg.text(lay.labels.get(k, tx + BAR_W / 2 + 6), ty + 4, sz.label[k], 12,
                 extra=' class="condition"')
    for s in g.leaf_steps():
        x, y = lay.steps[s.name]
        w = sz.step_w[s.name]
        x0, y0 = x - w / 2, y - half
        fill = ACTIVE_FILL if s.name in active else "white"
        svg.rect(x0, y0, w, STEP_H, fill, extra=' class="step"')
        if s.initial:
            svg.rect(x0 + 3.5, y0 + 3.5, w - 7, STEP_H - 7, fill, extra=' class="initial"')
        svg.text(x, y + (0 if s.parent else 4), s.name, 12, "middle",
                 extra=' class="step-name"')
        if s.parent:
            svg.text(x, y + 12, f"({s.parent})", 9, "middle")
        if s.name in active:
            svg.add(f'<circle cx="{x:.1f}" cy="{y0 + STEP_H - 7:.1f}" r="3" fill="black" '
                    f'class="token"/>')
        if s.name in sz.actions:
            ax = lay.actions[s.name]
            qw, bw = sz.action_w[s.name]
            rows = sz.actions[s.name]
            ay = y - ACTION_ROW * len(rows) / 2
            svg.line([(x + w / 2, y), (ax, y)])
            for i, (q, body) in enumerate(rows):
                yy = ay + i * ACTION_ROW
                svg.rect(ax, yy, qw, ACTION_ROW)
                svg.rect(ax + qw, yy, bw, ACTION_ROW)
                svg.text(ax + qw / 2, yy + 14, q, 11, "middle", extra=' class="qualifier"')
                svg.text(ax + qw + 6, yy + 14, body, 11, extra=' class="action"')
    width, height = svg.right + 24, svg.bottom + 24
    head = (f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.0f}" '
            f'height="{height:.0f}" viewBox="0 0 {width:.0f} {height:.0f}" '
            f'font-family="{FONT}">')
    title_svg = (f'<text x="20" y="26" font-size="15" font-weight="bold" class="title">'
                 f'{html.escape(title or g.name, quote=False)}</text>')
    return "\n".join([head, f"<title>{html.escape(g.name, quote=False)}</title>",
                      '<rect width="100%" height="100%" fill="white"/>', title_svg,
                      *svg.parts, "</svg>"]) + "\n"


def chart_svg(g: Grafcet, active: set[str] | None = None, title: str = "",
              layout: str = "auto") -> tuple[str, str]:
    """(SVG text, layout used: "dot" or "python")."""
    sz = Sizes.of(g)
    dot = shutil.which("dot") if layout in ("auto", "dot") else None
    if layout == "dot" and dot is None:
        raise RuntimeError("--layout dot: Graphviz's 'dot' is not installed "
                           "(apt-get install graphviz)")
    if dot is not None:
        lay, used = dot_layout(g, sz, dot), "dot"
    else:
        lay, used = python_layout(g, sz), "python"
    return render(g, lay, sz, active or set(), title), used


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

