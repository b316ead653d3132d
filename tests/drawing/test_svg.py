"""The one SVG writer of the chart and the chronogram."""

from __future__ import annotations

import xml.etree.ElementTree as ET

from runtime.drawing.svg import Svg, esc, esc_attr
from runtime.drawing.text import text_w


def test_texts_are_escaped_for_content_and_attributes() -> None:
    assert esc("↑iMarcha·iParo' & <x>") == "↑iMarcha·iParo' &amp; &lt;x&gt;"
    assert esc_attr('a "b"') == "a &quot;b&quot;"


def test_the_document_covers_what_was_drawn() -> None:
    svg = Svg()
    svg.rect(10, 20, 30, 40)
    svg.line([(0, 0), (0, 0), (5, 70)])  # a repeated point is dropped
    svg.text(12, 30, "gs<1>'")
    svg.insert(0, '<g class="under"/>')
    # the text reaches past the rectangle, to its measured width
    assert (svg.x0, svg.y0, svg.x1, svg.y1) == (0, 0, 12 + text_w("gs<1>'", 12), 70)
    doc = svg.document(100, 80, -20, ['<rect width="100%" height="100%" fill="white"/>'])
    root = ET.fromstring(doc)
    assert root.get("viewBox") == "-20 0 100 80"
    assert [e.tag.rsplit("}", 1)[1] for e in root] == ["rect", "g", "rect", "polyline", "text"]
    assert root[1].get("class") == "under"
    assert root[4].text == "gs<1>'"
    assert root[3].get("points") == "0.0,0.0 5.0,70.0"
