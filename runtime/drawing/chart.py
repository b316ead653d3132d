"""``softplc draw FILE -o OUT.svg``: a chart drawn in IEC 60848 style, as SVG.

What is drawn (seed 000's symbols): steps as boxes, initial steps as double boxes;
transitions as short thick bars with their condition on the right, as the file wrote it
(``--notation seed``: in the seed notation, ``↑iMarcha·iParo'``, whatever notation the file
uses) and their name, if any, on the left;
actions as boxes beside their step (qualifier | body; comments left out, long bodies on
several lines); AND divergences and convergences as double horizontal lines, OR divergences
and convergences as single lines; links that go back up run in lanes on the left with an
upward arrow; links that skip rows (into an OR convergence) run down a channel on the right
of what they pass. Macro-step expansions are framed and captioned with the macro-step's name.

The geometry (rows, x, lanes, channels, frames) is runtime/drawing/layout.py's, the texts
runtime/drawing/text.py's; this module draws them. The left-to-right order in each row comes
from Graphviz's ``dot`` (``--layout dot``, the default when ``dot`` is installed; fewer
crossings on large charts) or from the built-in rule (``--layout python``).

With ``--trace TRACE.jsonl --cycle K`` the steps active in scan K of the trace (keys
``INSTANCE.STEP.X``) are filled and carry the GRAFCET token (a dot).

A legend of the I/O goes under the equations: drawing a plant's instance, each bound
signal with its point (NC when inverted) and what the plant's I/O list says of it
(language/iolist.py), then the memory variables described; drawing a chart alone, its
variables that carry a description (none: no legend).
"""

from __future__ import annotations

import argparse
import itertools
import json
import shutil
import sys

from runtime.drawing.layout import (
    ACTION_GAP,
    BAR_W,
    CHAR_H,
    DROP_GAP,
    LINK_GAP,
    LIVE_SIZE,
    STEP_H,
    TIMES_SIZE,
    TOP,
    Chart,
    Routes,
    arrange,
    build_chart,
    dot_order,
    long_links,
    row_h,
)
from runtime.drawing.svg import Svg, esc, esc_attr
from runtime.drawing.text import NOTATIONS, equation_lines, step_times, text_w
from runtime.errors import Loc, SourceError
from runtime.language.coverage import Shading
from runtime.language.iolist import IOList
from runtime.language.model import Grafcet, PlantDef, VarKind

ACTIVE_FILL = "#ffd54f"
#: ``--coverage``: an element the scenarios reached, one they never reached
COVERED_FILL, MISSED_FILL, MISSED_STROKE = "#c8e6c9", "#ffcdd2", "#c62828"


def shared_and_drops(c: Chart, r: Routes) -> dict[tuple[str, str], float]:
    """(step, transition) -> x where the link reaches the transition's double bar, for the
    AND convergences that share a step with another transition leaving it: each gets its
    own short double bar over its transition (IEC 60848: one synchronisation per
    transition), the links from its steps side by side on it. Other AND convergences span
    their steps (empty here)."""
    out: dict[tuple[str, str], float] = {}
    for t, nd in c.nodes.items():
        if not t.startswith("t:") or len(c.fin(t)) < 2:
            continue
        # a link from higher up comes straight down (or by its channel) as before
        srcs = [s for s in c.fin(t) if nd.layer - c.nodes[s].layer == 1]
        if not any(o != t and len(c.fin(o)) > 1 for s in srcs for o in c.fout(s)):
            continue
        srcs.sort(key=lambda s: c.nodes[s].x)
        for i, s in enumerate(srcs):
            out[(s, t)] = nd.x + (i - (len(srcs) - 1) / 2) * DROP_GAP
    return out


# -- rendering ---------------------------------------------------------------------------------
class Drawing:
    """Draws a placed and routed chart."""

    def __init__(self, c: Chart, r: Routes, active: set[str],
                 shading: Shading | None = None) -> None:
        self.c, self.r, self.active = c, r, active
        self.shading = shading
        self.svg = Svg()
        self.side_x = 0.0  # where the boxes right of the chart start (equations, legend)
        self.arrivals: dict[str, list[float]] = {}  # step -> x of links reaching its line
        self.drops = shared_and_drops(c, r)
        # steps of a row whose divergence lines would run on one y: one below the other
        self.split_level: dict[str, int] = {}
        rows: dict[int, list[str]] = {}
        for s, _ in self.drops:
            rows.setdefault(c.nodes[s].layer, []).append(s)
        for steps in rows.values():
            for k, s in enumerate(sorted(set(steps), key=lambda n: c.nodes[n].x)):
                self.split_level[s] = k

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
        return (self.r.top[self.c.nodes[s].layer] - 8
                - LINK_GAP * self.r.join_level.get(s, 0))

    def split_y(self, s: str) -> float:
        """The OR divergence line below a step (below its action block)."""
        return self.bottom(self.c.nodes[s].layer) + 8 + 6 * self.split_level.get(s, 0)

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
                ends.append((self.drops.get((s, t), xs), self.and_in_y(t) - 2))
            else:
                ends.append((self.x(t), self.mid(t) - 2))
        if not outs:
            return
        y = self.split_y(s)
        if len(outs) == 1 and (s, outs[0]) not in self.drops:
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
        xs = [self.r.and_channel.get((s, t), self.drops.get((s, t), self.x(s)))
              for s in srcs] + [self.x(t)]
        for dy in (-2.0, 2.0):
            self.svg.line([(min(xs) - 12, y + dy), (max(xs) + 12, y + dy)],
                          cls="and convergence")
        self.svg.line([(self.x(t), y + 2), (self.x(t), self.mid(t) - 2)])

    def transition_out(self, t: str) -> None:
        c, xt, bar = self.c, self.x(t), self.mid(t)
        fw = c.fout(t)
        short = [d for d in fw if d not in self.r.bus or t not in long_links(c, d)]
        y = self.and_out_y(t)
        for d in fw:
            if d not in short:  # into a channel on the right (from its own double bar)
                x, start = self.r.split_drops.get((t, d), xt), bar + 2
                if (t, d) in self.r.split_drops:
                    start = y + 2
                ly = self.r.leave[(t, d)]
                self.svg.line([(x, start), (x, ly), (self.r.bus[d], ly)])
        if len(fw) > 1 and (short or any((t, d) in self.r.split_drops for d in fw)):
            # AND divergence
            drop = {d: self.r.split_drops.get((t, d), self.x(d)) for d in fw
                    if d in short or (t, d) in self.r.split_drops}
            xs = [*drop.values(), xt]
            self.svg.line([(xt, bar + 2), (xt, y - 2)])
            for dy in (-2.0, 2.0):
                self.svg.line([(min(xs) - 12, y + dy), (max(xs) + 12, y + dy)],
                              cls="and divergence")
            for d in short:
                self.arrive(d, drop[d], y + 2)
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
            # one group per transition, named by its index (the page marks it live)
            self.svg.add(f'<g class="transition-group" data-transition="{n[2:]}">')
            self.svg.line([(x - BAR_W / 2, y), (x + BAR_W / 2, y)], width=4, cls="transition")
            if self.shading and self.shading.transitions.get(int(n[2:])) is False:
                self.svg.add(f'<polyline points="{x - BAR_W / 2:.1f},{y:.1f} '
                             f'{x + BAR_W / 2:.1f},{y:.1f}" fill="none" '
                             f'stroke="{MISSED_STROKE}" stroke-width="4" class="missed"/>')
            lines = c.labels[n]
            y0 = y + 4 - CHAR_H * (len(lines) - 1) / 2
            for i, ln in enumerate(lines):
                self.svg.text(x + BAR_W / 2 + 6, y0 + CHAR_H * i, ln, 12,
                              extra=' class="condition"')
            if n in c.names:
                self.svg.text(x - BAR_W / 2 - 6, y + 4, c.names[n], 12, "end",
                              extra=' class="transition-name"')
            self.svg.add("</g>")

    def draw_steps(self) -> None:
        c = self.c
        for st in c.g.leaf_steps():
            n = "s:" + st.name
            x, y = self.x(n), self.mid(n)
            w = 2 * c.nodes[n].left
            x0, y0 = x - w / 2, y - STEP_H / 2
            fill = ACTIVE_FILL if st.name in self.active else self.shade(
                self.shading.steps.get(st.name) if self.shading else None)
            self.svg.add(f'<g class="step-group" data-step="{esc_attr(st.name)}">')
            if st.description:
                self.svg.add(f"<title>{esc(st.description)}</title>")
            self.svg.rect(x0, y0, w, STEP_H, fill, extra=' class="step"')
            if st.initial:
                self.svg.rect(x0 + 3.5, y0 + 3.5, w - 7, STEP_H - 7, fill,
                              extra=' class="initial"')
            times = step_times(st)
            self.svg.text(x, y + (-1 if times else 4), st.name, 12, "middle",
                          extra=' class="step-name"')
            if times:  # supervision times, as a vendor's SFC editor shows them
                self.svg.text(x, y + 11, times, TIMES_SIZE, "middle",
                              extra=' class="step-times"')
            if c.live_room:  # the live page writes the step's time here, above the link
                self.svg.text(x + w / 2 + 3, y - 4, "", LIVE_SIZE, extra=' class="live-t"')
            if st.name in self.active:  # top left, clear of the name and the times
                self.svg.add(f'<circle cx="{x0 + 8:.1f}" cy="{y0 + 8:.1f}" r="2.5" '
                             'fill="black" class="token"/>')
            self.svg.add("</g>")
            if st.name in c.actions:
                self.draw_actions(st.name, x + w / 2, y)

    def draw_actions(self, step: str, x_right: float, y: float) -> None:
        rows = self.c.actions[step]
        qw, bw = self.c.action_cols[step]
        ax = x_right + self.c.live_room + ACTION_GAP
        total = sum(row_h(lines) for _, lines in rows)
        yy = y - total / 2
        self.svg.line([(x_right, y), (ax, y)])
        self.svg.add(f'<g class="actions" data-step="{esc_attr(step)}">')
        for k, (q, lines) in enumerate(rows):
            h = row_h(lines)
            fill = self.shade(self.shading.actions.get((step, k)) if self.shading else None)
            self.svg.rect(ax, yy, qw, h, fill)
            self.svg.rect(ax + qw, yy, bw, h, fill)
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


    @staticmethod
    def shade(reached: bool | None) -> str:
        """The fill of an element by coverage: reached, never reached, not measured."""
        return "white" if reached is None else COVERED_FILL if reached else MISSED_FILL

    def draw_equations(self) -> float:
        """pre and post, right of the chart: what runs every scan outside the steps.
        Returns the y below them (where the legend goes)."""
        g = self.c.g
        x, y = self.svg.x1 + 40, TOP
        self.side_x = x
        for title, stmts in (("pre (every scan, before the chart)", g.pre),
                             ("post (every scan, after the chart)", g.post)):
            if not stmts:
                continue
            lines = [ln for st in stmts for ln in equation_lines(st, self.c.notation)]
            y = self._box(x, y, title, lines, "equation")
        return y

    def _box(self, x: float, y: float, title: str, lines: list[str], kind: str) -> float:
        """A titled box of text lines at (x, y); the y below it."""
        w = max([text_w(ln, 11) for ln in lines] + [text_w(title, 11)]) + 16
        h = CHAR_H * len(lines) + 8
        self.svg.text(x, y + 11, title, 11, extra=f' class="{kind}s-title"')
        self.svg.rect(x, y + 16, w, h, extra=f' class="{kind}s"')
        for i, ln in enumerate(lines):
            body = ln.lstrip("\u00a0")
            indent = text_w(ln[:len(ln) - len(body)], 11)
            self.svg.text(x + 8 + indent, y + 16 + 4 + CHAR_H * (i + 1) - 3, body, 11,
                          extra=f' class="{kind}"')
        return y + 16 + h + 16

    def draw_legend(self, title: str, rows: list[tuple[str, str, str]], y: float) -> None:
        """The legend of the signals (name, binding, meaning), under the equations."""
        if not rows:
            return
        widths = [max(len(r[k]) for r in rows) for k in range(2)]
        lines = ["\u00a0\u00a0".join([r[0].ljust(widths[0]).replace(" ", "\u00a0"),
                                     r[1].ljust(widths[1]).replace(" ", "\u00a0"),
                                     r[2]]).rstrip("\u00a0") for r in rows]
        self._box(self.side_x, y, title, lines, "legend")


def render(c: Chart, r: Routes, active: set[str], title: str,
           legend: tuple[str, list[tuple[str, str, str]]] = ("", []),
           shading: Shading | None = None) -> str:
    d = Drawing(c, r, active, shading)
    d.draw_frames()
    d.draw_links()
    d.draw_transitions()
    d.draw_steps()
    d.draw_legend(legend[0], legend[1], d.draw_equations())
    svg = d.svg
    title_svg = (f'<text x="0" y="26" font-size="15" font-weight="bold" class="title">'
                 f'{esc(title or c.g.name)}</text>')
    x0 = min(svg.x0, 0.0) - 20
    width = max(svg.x1, text_w(title or c.g.name, 15)) - x0 + 20
    height = svg.y1 + 20
    title_svg = title_svg.replace('x="0"', f'x="{min(svg.x0, 0.0):.0f}"')
    return svg.document(width, height, x0, [
        f"<title>{esc(c.g.name)}</title>",
        f'<rect x="{x0:.0f}" width="{width:.0f}" height="100%" fill="white"/>', title_svg])


def link_crossings(c: Chart, r: Routes) -> int:
    """Points where a link runs straight across another (a vertical through a horizontal,
    neither ending there; bars and double bars left out)."""
    d = Drawing(c, r, set())
    d.draw_links()
    flat, upright = [], []
    for pts, cls in d.svg.polylines:
        if {"transition", "and"} & set(cls.split()):
            continue
        for (x0, y0), (x1, y1) in itertools.pairwise(pts):
            if abs(y0 - y1) < 0.01 < abs(x0 - x1):
                flat.append((y0, min(x0, x1), max(x0, x1)))
            elif abs(x0 - x1) < 0.01 < abs(y0 - y1):
                upright.append((x0, min(y0, y1), max(y0, y1)))
    return sum(1 for y, a, b in flat for x, lo, hi in upright
               if a + 0.5 < x < b - 0.5 and lo + 0.5 < y < hi - 0.5)


def laid_out(g: Grafcet, layout: str = "auto", notation: str = "written",
             live: bool = False) -> tuple[Chart, Routes, str]:
    """The chart placed and routed, and the layout used ("dot" or "python"). Each step goes
    under its nearest predecessor; if links then cross, it goes under the one the
    depth-first walk reached it from instead (the normal sequence, a link from higher up
    running straight down past a branch: issue 27, a return link into the third step
    across the failure channel), when that crosses fewer."""
    dot = shutil.which("dot") if layout in ("auto", "dot") else None
    if layout == "dot" and dot is None:
        raise RuntimeError("--layout dot: Graphviz's 'dot' is not installed "
                           "(apt-get install graphviz)")
    best: tuple[int, Chart, Routes] | None = None
    for follow in (False, True):
        c = build_chart(g, follow_tree=follow, notation=notation, live=live)
        r = arrange(c, dot_order(c, dot) if dot is not None else None)
        n = link_crossings(c, r)
        if best is None or n < best[0]:
            best = (n, c, r)
        if n == 0:
            break
    assert best is not None
    return best[1], best[2], ("dot" if dot is not None else "python")


def chart_svg(g: Grafcet, active: set[str] | None = None, title: str = "",
              layout: str = "auto",
              legend: tuple[str, list[tuple[str, str, str]]] = ("", []),
              notation: str = "written", live: bool = False,
              shading: Shading | None = None) -> tuple[str, str]:
    """(SVG text, layout used: "dot" or "python"); ``legend``: its title and rows;
    ``notation``: conditions as written or in the seed notation (text.py); ``live``: the
    live page's drawing, with an empty ``text.live-t`` right of each step box (room kept
    for it) where the page writes the active step's time; ``shading``: the chart's coverage
    (steps, transitions and actions reached in green, never reached in red)."""
    c, r, used = laid_out(g, layout, notation, live)
    return render(c, r, active or set(), title, legend, shading), used


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
def legend(g: Grafcet, pdef: PlantDef | None, instance: str | None
           ) -> tuple[str, list[tuple[str, str, str]]]:
    """The legend of the I/O (language/iolist.py): for a plant's instance, each bound
    signal with its point (NC when inverted) and meaning, then the memory variables
    described; for a chart alone, its variables that carry a description."""
    rows: list[tuple[str, str, str]] = []
    if pdef is not None and instance is not None:
        iolist = IOList(pdef)
        idef = pdef.instances[instance]
        for way, section in (("<-", idef.inputs), ("->", idef.outputs)):
            for sig, b in section.items():
                m = iolist.meaning(f"{instance}.{sig}")
                unit = f" [{m.unit.symbol}]" if m.unit is not None else ""
                rows.append((sig, f"{way} {b.source}{' NC' if b.invert else ''}",
                             m.description + unit))
        memory = [v for v in g.variables.values()
                  if v.kind is VarKind.MEMORY and v.description]
        rows += [(v.name, "", v.description) for v in memory]
        return f"I/O of {instance} ({pdef.instances[instance].description or g.name})", rows
    rows = [(v.name, "", v.description) for v in g.variables.values() if v.description]
    return "signals", rows


def load_chart(path: str, instance: str | None
               ) -> tuple[Grafcet, str | None, PlantDef | None]:
    """The grafcet of FILE (a grafcet file, or a plant file's instance), the instance,
    and the plant (None for a grafcet file)."""
    from runtime.language.filekind import read_document
    from runtime.language.grafcetfile import load_grafcet
    from runtime.language.plantfile import load_plant

    kind, doc = read_document(path)
    if kind == "plant":
        p = load_plant(path, doc=doc)
        if instance is None:
            instance = next(iter(p.instances))
        if instance not in p.instances:
            raise SourceError(Loc(path, 1, 1), f"no instance '{instance}' in the plant "
                                               f"(instances: {', '.join(p.instances)})")
        return p.instances[instance].grafcet, instance, p
    return load_grafcet(path, doc=doc), instance, None


def draw(path: str, out: str, trace: str | None = None, cycle: int | None = None,
         instance: str | None = None, layout: str = "auto", notation: str = "written",
         coverage: str | None = None) -> str:
    """Write the SVG; returns the layout used ("dot" or "python")."""
    g, instance, pdef = load_chart(path, instance)
    active: set[str] = set()
    title = g.name
    key = legend(g, pdef, instance)
    if trace is not None:
        k = 0 if cycle is None else cycle
        active, instance, row = active_from_trace(g, trace, k, instance)
        title = f"{g.name} ({instance}) — cycle {k}, t = {row.get('t_ms', '?')} ms"
    shading = None
    if coverage is not None:
        shading, said = coverage_of(g, coverage)
        title = f"{title} — {said}"
    svg, used = chart_svg(g, active, title, layout, key, notation, shading=shading)
    with open(out, "w", encoding="utf-8") as f:
        f.write(svg)
    return used


def coverage_of(g: Grafcet, path: str) -> tuple[Shading, str]:
    """The shading of ``g`` from the coverage file at ``path`` (``softplc test
    --coverage-file``), and what the title says of it; SourceError if the file holds no
    coverage of ``g``."""
    from runtime.language import coverage as C

    cov = C.of_chart(C.load(path), g)
    if cov is None:
        raise SourceError(Loc(path, 1, 1), f"no coverage of grafcet {g.name} ({g.path}) in "
                                           "this file")
    return C.shading(g, cov), (f"coverage {cov.percent():.1f}% over {cov.scenarios} "
                               "scenario(s): green reached, red never")


def cmd_draw(args: argparse.Namespace) -> int:
    if args.cycle is not None and args.trace is None:
        sys.stderr.write("softplc draw: error: --cycle needs --trace\n")
        return 2
    try:
        used = draw(args.file, args.output, args.trace, args.cycle, args.instance, args.layout,
                    args.notation, args.coverage)
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
    d.add_argument("--notation", choices=NOTATIONS, default="written",
                   help="conditions, action conditions and equations as the file wrote them "
                        "(written), or in the seed's notation: ↑ · + ' (seed)")
    d.add_argument("--coverage", metavar="COVERAGE.json",
                   help="shade the chart by the coverage softplc test --coverage-file wrote: "
                        "reached in green, never reached in red")
    d.set_defaults(func=cmd_draw)
