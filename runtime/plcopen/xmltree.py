"""Reading an XML file safely into a small tree that knows where each element and each
character of text was written.

The parser is defusedxml's expat reader: no entity is declared or expanded (the "billion
laughs"), nothing external is fetched, and the tree is bounded: a regular file below
``MAX_XML_BYTES``, at most ``MAX_ELEMENTS`` elements nested at most ``MAX_XML_DEPTH`` deep.
Each refusal is one ``FILE:LINE:COL`` error (``SourceError``). Lines and columns are
1-based and count characters, as in the rest of softplc.
"""

from __future__ import annotations

import io
import xml.sax
import xml.sax.handler
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from defusedxml.common import DTDForbidden, EntitiesForbidden, ExternalReferenceForbidden
from defusedxml.expatreader import DefusedExpatParser

from runtime.errors import Loc, SourceError
from runtime.language.yamlsrc import YStr, read_bytes

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
    loc: Loc
    children: list[Element] = field(default_factory=list)
    chunks: list[tuple[str, int, int]] = field(default_factory=list)  # (text, line, col)

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
        s = YStr(text[lead:end])
        s.loc = Loc(self.loc.file, *places[lead]) if lead < len(places) else self.loc
        s._pos = places[lead:end]
        return s


class _Builder(xml.sax.handler.ContentHandler):
    """Builds the tree while counting elements and depth."""

    def __init__(self, path: str) -> None:
        super().__init__()
        self.path = path
        self.locator: Any = None
        self.stack: list[Element] = []
        self.root: Element | None = None
        self.count = 0

    def setDocumentLocator(self, locator: Any) -> None:  # noqa: N802 - SAX's name
        self.locator = locator

    def here(self) -> Loc:
        if self.locator is None:
            return Loc(self.path, 1, 1)
        return Loc(self.path, self.locator.getLineNumber() or 1,
                   (self.locator.getColumnNumber() or 0) + 1)

    def startElementNS(self, name: tuple[str | None, str], qname: str | None,  # noqa: N802
                       attrs: Any) -> None:
        self.count += 1
        loc = self.here()
        if self.count > MAX_ELEMENTS:
            raise SourceError(loc, f"the file has more than {MAX_ELEMENTS} XML elements: "
                                   "expected a PLCopen project of a sensible size")
        if len(self.stack) >= MAX_XML_DEPTH:
            raise SourceError(loc, f"XML nested deeper than {MAX_XML_DEPTH} levels: expected "
                                   "a PLCopen project (about 12 levels, 3 more per macro-step)")
        values: dict[str, str] = {}
        for (uri, local), value in attrs.items():
            values[f"{{{uri}}}{local}" if uri else local] = value
        e = Element(name[0] or "", name[1], values, loc)
        if self.stack:
            self.stack[-1].children.append(e)
        else:
            self.root = e
        self.stack.append(e)

    def endElementNS(self, name: tuple[str | None, str], qname: str | None) -> None:  # noqa: N802
        self.stack.pop()

    def characters(self, content: str) -> None:
        if self.stack:
            loc = self.here()
            self.stack[-1].chunks.append((content, loc.line, loc.col))


def parse_xml(path: str, data: bytes | None = None) -> Element:
    """The root element of the XML file at ``path`` (or of ``data``, its bytes, already
    read); SourceError at the place of the first problem."""
    if data is None:
        data = read_bytes(path, MAX_XML_BYTES)
    builder = _Builder(path)
    parser = DefusedExpatParser(forbid_dtd=False, forbid_entities=True, forbid_external=True)
    parser.setFeature(xml.sax.handler.feature_namespaces, True)
    parser.setContentHandler(builder)
    source = xml.sax.xmlreader.InputSource(path)
    source.setByteStream(io.BytesIO(data))
    try:
        parser.parse(source)
    except xml.sax.SAXParseException as exc:
        loc = Loc(path, exc.getLineNumber() or 1, (exc.getColumnNumber() or 0) + 1)
        raise SourceError(loc, f"XML syntax: {exc.getMessage()}") from None
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
    except DTDForbidden:  # pragma: no cover - DTDs without entities are let through
        raise SourceError(builder.here(), "document type declaration refused") from None
    if builder.root is None:  # pragma: no cover - expat refuses a file without an element
        raise SourceError(Loc(path, 1, 1), "no XML element in the file")
    return builder.root
