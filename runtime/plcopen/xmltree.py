"""Reading an XML file safely into a small tree that knows where each element and each
character of text was written.

The parser is defusedxml's expat reader: no entity is declared or expanded (the "billion
laughs"), nothing external is fetched, and the tree is bounded: a regular file below
``MAX_XML_BYTES``, at most ``MAX_ELEMENTS`` elements nested at most ``MAX_XML_DEPTH`` deep.
Each refusal is one ``FILE:LINE:COL`` error (``SourceError``). Lines and columns are
1-based and count characters, as in the rest of softplc.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any
from xml.parsers import expat

from defusedxml.common import EntitiesForbidden, ExternalReferenceForbidden
from defusedxml.ElementTree import DefusedXMLParser

from runtime.errors import Loc, SourceError
from runtime.language.yamlsrc import YStr, placed_str, read_bytes

#: the largest XML file read, bytes (16 MiB: an exported 500-step chart is about 1 MiB; a
#: Beremiz project of a few dozen POUs a few MiB)
MAX_XML_BYTES = 16 * 1024 * 1024
#: elements in one file (an exported 500-step chart has about 30 000; each costs some
#: 400 bytes here, so the bound keeps a hostile file under about 100 MB)
MAX_ELEMENTS = 200_000
#: elements inside one another (a PLCopen file nests about 12, plus 3 per macro-step level)
MAX_XML_DEPTH = 100


@dataclass(slots=True, eq=False)
class Element:
    """One XML element: namespace URI and local name, attributes (unqualified names; a
    namespaced attribute is ``{uri}name``), children, and the text written directly inside
    it as chunks, each with the file place of its first character."""

    ns: str
    tag: str
    attrs: dict[str, str]
    file: str
    line: int
    col: int
    children: list[Element] = field(default_factory=list)
    chunks: list[tuple[str, int, int]] = field(default_factory=list)  # (text, line, col)

    @property
    def loc(self) -> Loc:
        """Where the element's start tag begins."""
        return Loc(self.file, self.line, self.col)

    def __repr__(self) -> str:
        return f"<{self.tag} at {self.loc}>"

    def get(self, name: str, default: str | None = None) -> str | None:
        return self.attrs.get(name, default)

    def find(self, tag: str, ns: str | None = None) -> Element | None:
        """The first child of this local name (and namespace, when given)."""
        for c in self.children:
            if c.tag == tag and (ns is None or c.ns == ns):
                return c
        return None

    def findall(self, tag: str, ns: str | None = None) -> list[Element]:
        return [c for c in self.children if c.tag == tag and (ns is None or c.ns == ns)]

    def iter(self) -> Iterator[Element]:
        """This element and every element below it, parents first."""
        stack = [self]
        while stack:
            e = stack.pop()
            yield e
            stack.extend(reversed(e.children))

    @property
    def text(self) -> str:
        return "".join(c[0] for c in self.chunks)

    def ystr(self, strip: bool = True) -> YStr:
        """The element's text as a YStr whose every character knows its file place (so the
        language's parser reports an error inside it at its line and column in the XML
        file); leading and trailing white space taken off when ``strip``."""
        text = self.text
        places: list[tuple[int, int]] = []
        for chunk, line, col in self.chunks:
            for ch in chunk:
                places.append((line, col))
                if ch == "\n":
                    line, col = line + 1, 1
                else:
                    col += 1
        lead = 0
        end = len(text)
        if strip:
            lead = len(text) - len(text.lstrip())
            end = len(text.rstrip())
            if end < lead:
                end = lead
        return placed_str(text[lead:end], places[lead:end],
                          Loc(self.loc.file, *places[lead]) if lead < len(places) else self.loc)


class _Builder:
    """Builds the tree from expat's events, counting elements and depth; every place is
    read from the parser at the event (1-based lines, 0-based columns from expat)."""

    def __init__(self, path: str, parser: Any) -> None:
        self.path = path
        self.p = parser
        self.stack: list[Element] = []
        self.root: Element | None = None
        self.count = 0

    def here(self) -> Loc:
        return Loc(self.path, self.p.CurrentLineNumber, self.p.CurrentColumnNumber + 1)

    def start(self, name: str, attrs: list[str]) -> None:
        self.count += 1
        if self.count > MAX_ELEMENTS:
            raise SourceError(self.here(), f"the file has more than {MAX_ELEMENTS} XML "
                                           "elements: expected a PLCopen project of a "
                                           "sensible size")
        if len(self.stack) >= MAX_XML_DEPTH:
            raise SourceError(self.here(), f"XML nested deeper than {MAX_XML_DEPTH} levels: "
                                           "expected a PLCopen project (about 12 levels, 3 "
                                           "more per macro-step)")
        ns, _, tag = name.rpartition("}")
        values = dict(zip(attrs[::2], attrs[1::2], strict=True))
        if any("}" in k for k in values):  # namespaced attributes: {uri}name
            values = {("{" + k if "}" in k else k): v for k, v in values.items()}
        p = self.p
        e = Element(ns, tag, values, self.path, p.CurrentLineNumber, p.CurrentColumnNumber + 1)
        if self.stack:
            self.stack[-1].children.append(e)
        else:
            self.root = e
        self.stack.append(e)

    def end(self, name: str) -> None:
        self.stack.pop()

    def data(self, text: str) -> None:
        if self.stack:
            p = self.p
            self.stack[-1].chunks.append((text, p.CurrentLineNumber, p.CurrentColumnNumber + 1))


def parse_xml(path: str, data: bytes | None = None) -> Element:
    """The root element of the XML file at ``path`` (or of ``data``, its bytes, already
    read); SourceError at the place of the first problem."""
    if data is None:
        data = read_bytes(path, MAX_XML_BYTES)
    # defusedxml's parser: its expat refuses entity declarations and external references;
    # the tree is built here from expat's own events, which know their place in the file
    defused = DefusedXMLParser(forbid_dtd=False, forbid_entities=True, forbid_external=True)
    p = defused.parser
    builder = _Builder(path, p)
    p.buffer_text = False  # one event per piece of text, each with its own place
    p.ordered_attributes = True
    p.StartElementHandler = builder.start
    p.EndElementHandler = builder.end
    p.CharacterDataHandler = builder.data
    try:
        p.Parse(data, True)
    except expat.ExpatError as exc:
        loc = Loc(path, exc.lineno or 1, (exc.offset or 0) + 1)
        raise SourceError(loc, f"XML syntax: {expat.ErrorString(exc.code)}") from None
    except EntitiesForbidden as exc:
        if exc.sysid or exc.pubid:
            raise SourceError(builder.here(), f"external entity '{exc.name}' "
                              f"({exc.sysid or exc.pubid}) refused: nothing outside the file "
                              "is read") from None
        raise SourceError(builder.here(), f"entity declaration '{exc.name}' refused: a PLCopen "
                          "file needs no entities (this is how a 'billion laughs' file "
                          "expands)") from None
    except ExternalReferenceForbidden as exc:
        raise SourceError(builder.here(), f"external entity '{exc.sysid}' refused: nothing "
                          "outside the file is read") from None
    if builder.root is None:  # pragma: no cover - expat refuses a file without an element
        raise SourceError(Loc(path, 1, 1), "no XML element in the file")
    return builder.root
