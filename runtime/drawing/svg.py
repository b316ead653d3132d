"""The one SVG writer of the drawings: the chart (``chart.py``) and the chronogram
(``chronogram.py``) write their elements through an ``Svg`` and escape their texts with
``esc`` (``esc_attr`` in attributes); the document around them (size, view box, font) is
written here."""

from __future__ import annotations

import html

from runtime.drawing.text import FONT, text_w


def esc(s: str) -> str:
    """Text for an element's content (``<``, ``>``, ``&`` escaped; a seed-notation ``'``
    stays as written)."""
    return html.escape(s, quote=False)


def esc_attr(s: str) -> str:
    """Text for an attribute value (quotes escaped too)."""
    return html.escape(s, quote=True)


class Svg:
    """An SVG document being written: its elements in order and the extent they cover (the
    chart sizes itself from it). Coordinates are written to 0.1 px, sizes as given."""

    def __init__(self) -> None:
        self.parts: list[str] = []
        self.polylines: list[tuple[list[tuple[float, float]], str]] = []  # points, class
        self.x0 = self.y0 = float("inf")
        self.x1 = self.y1 = float("-inf")

    def _grow(self, x: float, y: float) -> None:
        self.x0, self.y0 = min(self.x0, x), min(self.y0, y)
        self.x1, self.y1 = max(self.x1, x), max(self.y1, y)

    def add(self, s: str) -> None:
        """Append an element written by the caller (escape its texts with ``esc``)."""
        self.parts.append(s)

    def insert(self, at: int, s: str) -> None:
        """Put an element at position ``at`` (under the ones after it)."""
        self.parts.insert(at, s)

    def line(self, pts: list[tuple[float, float]], width: float = 1.2, cls: str = "") -> None:
        pts = [p for i, p in enumerate(pts) if i == 0 or p != pts[i - 1]]
        if len(pts) < 2:
            return
        for x, y in pts:
            self._grow(x, y)
        self.polylines.append((pts, cls))
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
                 f'{extra}>{esc(s)}</text>')

    def arrow_up(self, x: float, y: float) -> None:
        self.add(f'<polygon points="{x - 4:.1f},{y + 5:.1f} {x + 4:.1f},{y + 5:.1f} '
                 f'{x:.1f},{y - 4:.1f}" fill="black" class="arrow"/>')

    def document(self, width: float, height: float, x0: float, before: list[str]) -> str:
        """The whole document, ``width`` x ``height`` px from ``x0``: the ``before``
        elements (title, background), then the elements added."""
        head = (f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.0f}" '
                f'height="{height:.0f}" viewBox="{x0:.0f} 0 {width:.0f} {height:.0f}" '
                f'font-family="{FONT}">')
        return "\n".join([head, *before, *self.parts, "</svg>"]) + "\n"
