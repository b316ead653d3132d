"""Where an exported chart's elements go: the positions ``softplc draw`` computes
(runtime/drawing/layout.py), read as PLCopen positions and connection pins.

A step is its box of the drawing, a transition its bar, an action block the drawing's
action boxes; a macro-step is the frame the drawing puts round its expansion, and the
expansion's elements keep the places they have in the drawing. Divergences and convergences
sit on the lines the drawing draws for them. Lengths are the drawing's px (integers in the
file).
"""

from __future__ import annotations

from runtime.drawing.chart import Drawing, laid_out
from runtime.drawing.layout import ACTION_GAP, STEP_H, row_h
from runtime.language.model import Grafcet

Point = tuple[float, float]
#: the height of a transition's bar and of a simultaneous divergence's double line, px
BAR_H = 2.0
DOUBLE_H = 3.0
#: a jump step's arrow, px
JUMP_W, JUMP_H = 12.0, 13.0


class Geometry:
    """The drawing of one chart, asked for places by step name and transition position."""

    def __init__(self, g: Grafcet, layout: str = "python") -> None:
        self.g = g
        c, r, self.used = laid_out(g, layout)
        self.c, self.r = c, r
        self.d = Drawing(c, r, set())

    # leaves of the drawing --------------------------------------------------------------
    def entry_leaf(self, step: str) -> str:
        st = self.g.steps[step]
        return self.entry_leaf(st.macro.entry) if st.macro is not None else step

    def exit_leaf(self, step: str) -> str:
        st = self.g.steps[step]
        return self.exit_leaf(st.macro.exit) if st.macro is not None else step

    # steps -----------------------------------------------------------------------------
    def step_box(self, step: str) -> tuple[float, float, float, float]:
        """(x, y, width, height) of a step's box, or of a macro-step's frame."""
        if self.g.steps[step].macro is not None:
            x0, y0, x1, y1 = self.r.frames[step]
            return x0, y0, x1 - x0, y1 - y0
        n = "s:" + step
        w = 2 * self.c.nodes[n].left
        return self.d.x(n) - w / 2, self.d.step_top(n), w, STEP_H

    def step_in(self, step: str) -> Point:
        leaf = "s:" + self.entry_leaf(step)
        if self.g.steps[step].macro is not None:
            return self.d.x(leaf), self.r.frames[step][1]
        return self.d.x(leaf), self.d.step_top(leaf)

    def step_out(self, step: str) -> Point:
        leaf = "s:" + self.exit_leaf(step)
        if self.g.steps[step].macro is not None:
            return self.d.x(leaf), self.r.frames[step][3]
        return self.d.x(leaf), self.d.step_bottom(leaf)

    def action_pin(self, step: str) -> Point:
        x, y, w, h = self.step_box(step)
        return x + w, y + h / 2

    def action_block(self, step: str) -> tuple[float, float, float, list[float]]:
        """(x, y, width, heights of the action rows) of a step's action block."""
        rows = self.c.actions.get(step, [])
        q, b = self.c.action_cols.get(step, (40.0, 80.0))
        heights = [row_h(lines) for _, lines in rows]
        x_right, mid = self.action_pin(step)
        return x_right + ACTION_GAP, mid - sum(heights) / 2, q + b, heights

    # transitions -------------------------------------------------------------------------
    def bar(self, k: int) -> Point:
        """The centre of transition ``k``'s bar."""
        n = f"t:{k}"
        return self.d.x(n), self.d.mid(n)

    def split_y(self, step: str) -> float:
        """The y of the selection divergence under a step (its OR divergence line)."""
        return self.d.split_y("s:" + self.exit_leaf(step))

    def join_y(self, step: str) -> float:
        """The y of the selection convergence above a step (its OR convergence line)."""
        return self.d.join_y("s:" + self.entry_leaf(step)) - 1

    def and_in_y(self, k: int) -> float:
        return self.d.and_in_y(f"t:{k}") - DOUBLE_H

    def and_out_y(self, k: int) -> float:
        return self.d.and_out_y(f"t:{k}")


def route(consumer: Point, producer: Point) -> list[Point]:
    """The points of a connection, from the consumer's input pin to the producer's output pin
    (as the schema asks): straight when they are one above the other, else down, across and
    down."""
    (cx, cy), (px, py) = consumer, producer
    if abs(cx - px) < 0.5:
        return [consumer, producer]
    mid = (cy + py) / 2
    return [consumer, (cx, mid), (px, mid), producer]
