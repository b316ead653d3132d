"""Writing XML: a tree of ``Node``s serialised with two-space indentation, attributes in the
order given, ST bodies as CDATA (as Beremiz writes them)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(slots=True, eq=False)
class Node:
    """An element to write: ``tag`` with its prefix if any (``xhtml:p``), attributes in
    order, children, and either a text or a CDATA text."""

    tag: str
    attrs: dict[str, str] = field(default_factory=dict)
    children: list[Node] = field(default_factory=list)
    text: str | None = None
    cdata: str | None = None

    def add(self, tag: str, attrs: dict[str, str] | None = None, *, text: str | None = None,
            cdata: str | None = None) -> Node:
        """A new child, returned."""
        child = Node(tag, dict(attrs or {}), [], text, cdata)
        self.children.append(child)
        return child


def escape(text: str, quote: bool = False) -> str:
    text = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    if quote:
        text = text.replace('"', "&quot;").replace("\n", "&#10;").replace("\t", "&#9;")
        text = text.replace("\r", "&#13;")
    return text.replace("\r", "&#13;")


def _cdata(text: str) -> str:
    return "<![CDATA[" + text.replace("]]>", "]]]]><![CDATA[>") + "]]>"


def serialize(root: Node) -> str:
    """The document: an XML declaration and ``root``."""
    out = ['<?xml version="1.0" encoding="utf-8"?>\n']
    _write(root, 0, out)
    return "".join(out)


def _write(n: Node, depth: int, out: list[str]) -> None:
    pad = "  " * depth
    attrs = "".join(f' {k}="{escape(v, True)}"' for k, v in n.attrs.items())
    if not n.children and n.text is None and n.cdata is None:
        out.append(f"{pad}<{n.tag}{attrs}/>\n")
        return
    if not n.children:
        body = _cdata(n.cdata) if n.cdata is not None else escape(n.text or "")
        out.append(f"{pad}<{n.tag}{attrs}>{body}</{n.tag}>\n")
        return
    out.append(f"{pad}<{n.tag}{attrs}>\n")
    for c in n.children:
        _write(c, depth + 1, out)
    out.append(f"{pad}</{n.tag}>\n")
