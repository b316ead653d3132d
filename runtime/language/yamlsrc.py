"""YAML loading that keeps where every key and value was written, for error messages.

It is also the one place that reads the project's YAML files (charts, plants, scripts), so
the limits that keep a hostile file from hanging or exhausting the controller live here:
a source file is a regular file below ``MAX_FILE_BYTES``, its YAML nests at most
``MAX_DEPTH`` levels, uses at most ``MAX_ALIASES`` aliases, and once aliases are expanded
holds at most ``node_budget(size)`` nodes and ``text_budget(size)`` characters of values; its
integers fit 64 bits (``INT_MIN`` .. ``INT_MAX``). Each is refused with one
``FILE:LINE:COL`` error.

libyaml (PyYAML's C parser, in its wheels) parses; the composer that enforces the limits
and keeps the places is PyYAML's own, in Python, over libyaml's events, whose marks are the
pure-Python parser's (line, column and index in characters). The pure-Python parser parses
where libyaml is missing, where the two read a text differently (``_DIVERGENT``), and
words every syntax error (a file libyaml refuses is parsed again to word it), so a file
loads or is refused alike, in the same words, on every machine. A text's characters are
placed (``YStr.pos``) the first time one is asked for. Loading with libyaml costs about
8 µs per node (30 µs in pure Python) and a negligible time per character of text (a file of
one 1 MiB text: 0.04 s, 0.55 s in pure Python); the densest file the limits let through
(1 MiB of one-character flow items) is refused at the node budget after 1.6 s of CPU and
95 MB (7 s and 180 MB in pure Python), measured on a loaded 2-core machine.
"""

from __future__ import annotations

import re
from typing import Any

import yaml

try:  # libyaml, in PyYAML's wheels
    from yaml._yaml import CParser as _CParser

    _HAS_LIBYAML = True
except ImportError:  # pragma: no cover - a PyYAML built without it
    _HAS_LIBYAML = False

from drivers.durations import MAX_NS
from runtime.errors import Loc, SourceError
from runtime.language.safefile import UnfitFile, read_bounded
from runtime.language.yamlslip import anchor_alone, explain

#: the largest chart, plant or script file read, in bytes (1 MiB: the example charts and
#: plants are under 7 kB, a plant of 1000 drawer testers is 300 kB; a file of one 1 MiB
#: text loads in about 0.04 s with libyaml, 0.55 s without)
MAX_FILE_BYTES = 1024 * 1024
#: mappings and lists inside one another (a plant nests 5 levels, a chart ~3 per macro-step);
#: far below Python's recursion limit, which the loaders' recursion would otherwise meet
MAX_DEPTH = 64
#: aliases (``*name``) in one file: anchors share a few values, they are not a macro system
MAX_ALIASES = 100
#: nodes (mappings, lists and values) a file may hold beyond a quarter of its size in bytes,
#: aliases expanded (``node_budget``): the largest example has 340; a file written by hand or
#: by a generator needs more than 4 bytes a node, so only aliases (or a file of one-letter
#: flow items) reach the budget
NODE_ALLOWANCE = 10_000
#: characters of values that aliases may add beyond the file's own size
EXPANSION_ALLOWANCE = 10_000
#: the integers a file may hold, in YAML or as a literal of an expression: from LINT's
#: least to ULINT's greatest (64 bits)
INT_MIN, INT_MAX = -(2**63), 2**64 - 1
#: the longest time a file may give, in ns: LTIME's greatest (2**63 - 1 ns, about 292 years),
#: the bound of drivers' durations too
TIME_MAX_NS = MAX_NS
#: most significant digits of an integer (64 binary digits), checked before converting
_INT_TEXT_MAX = 64


def node_budget(size: int) -> int:
    """The nodes a file of ``size`` characters may hold, aliases expanded."""
    return NODE_ALLOWANCE + size // 4


def text_budget(size: int) -> int:
    """The characters of values a file of ``size`` characters may hold, aliases expanded:
    its size (more than a file without aliases can reach) plus ``EXPANSION_ALLOWANCE``."""
    return size + EXPANSION_ALLOWANCE


class YMap(dict[str, Any]):
    """A YAML mapping; ``loc`` is the mapping's place, ``key_locs``/``val_locs`` its items'."""

    loc: Loc
    key_locs: dict[str, Loc]
    val_locs: dict[str, Loc]


class YList(list[Any]):
    """A YAML sequence; ``loc`` is its place, ``locs[i]`` the place of item i."""

    loc: Loc
    locs: list[Loc]


class YStr(str):
    """A YAML string that can map an offset inside it back to a file line and column.

    ``pos(i)`` is the file place of character i of the value, for every scalar style:
    plain, single- and double-quoted (``''`` and escapes such as ``\\u2191`` count as the
    characters they stand for), and block scalars (``|``, ``>``), including folded lines.
    The places are worked out from the scalar's source text the first time one is asked
    for (an error message): loading keeps only where the text is (``_src``).
    """

    loc: Loc
    #: (line, col) of each character, once worked out; None until then
    _pos: list[tuple[int, int]] | None
    #: the file's text, the scalar's start and end index in it, its start line and column
    #: (1-based) and style: what ``_pos`` is worked out from
    _src: tuple[str, int, int, int, int, str | None] | None

    def places(self) -> list[tuple[int, int]]:
        """File (line, col) of every character of the value."""
        if self._pos is None:
            assert self._src is not None
            self._pos = _value_positions(self, *self._src)
        return self._pos

    def pos(self, offset: int) -> Loc:
        """File place of character ``offset`` of this string (past the end: after the last
        visible character, where 'found end of text' points)."""
        p = self.places()
        if 0 <= offset < len(p):
            line, col = p[offset]
            return Loc(self.loc.file, line, col)
        k = min(len(p), len(self)) - 1
        while k >= 0 and self[k].isspace():
            k -= 1
        if k < 0:
            return self.loc
        line, col = p[k]
        return Loc(self.loc.file, line, col + 1)


def placed_str(value: str, places: list[tuple[int, int]], loc: Loc) -> YStr:
    """A YStr whose characters' file places are given (text read from another format,
    such as PLCopen XML): ``places[i]`` is character i's (line, col)."""
    s = YStr(value)
    s.loc = loc
    s._pos = places
    s._src = None
    return s


def synthetic_str(value: str, loc: Loc) -> YStr:
    """A YStr for text that is not in the file as such (a YAML number or bool used as a
    condition): its characters are placed one after the other from ``loc``."""
    s = YStr(value)
    s.loc = loc
    s._pos = [(loc.line, loc.col + i) for i in range(len(value))]
    s._src = None
    return s


class _Resolver(yaml.resolver.Resolver):
    """YAML 1.2 booleans: only true/false (any of True, TRUE ...) are bools.

    YAML 1.1 also reads yes/no/on/off as bools, so an output named ``On`` or a step named
    ``No`` would silently become ``True``/``False``; editors' YAML language servers use 1.2.
    """


_Resolver.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag != "tag:yaml.org,2002:bool"]
    for first, resolvers in yaml.resolver.Resolver.yaml_implicit_resolvers.items()
}
_Resolver.add_implicit_resolver("tag:yaml.org,2002:bool",
                                re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
                                list("tTfF"))


class _Constructor(yaml.constructor.SafeConstructor):
    """The safe constructor with integers bounded to 64 bits."""

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        """An integer of at most 64 bits (the language's LINT .. ULINT), refused before
        converting a long text (Python refuses over 4300 digits, with a traceback)."""
        text = str(node.value).replace("_", "")
        digits = text.lstrip("+-")
        digits = digits[2:] if digits[:2] in ("0x", "0b", "0o") else digits
        value = None
        if len(digits.lstrip("0")) <= _INT_TEXT_MAX:
            value = super().construct_yaml_int(node)
        if value is None or not INT_MIN <= value <= INT_MAX:
            shown = text if len(text) <= 24 else f"{text[:10]}...{text[-6:]} ({len(text)} " \
                                                 "characters)"
            raise yaml.constructor.ConstructorError(
                None, None, f"integer out of range: expected a 64-bit integer, from "
                f"{INT_MIN} to {INT_MAX}, found {shown}", node.start_mark)
        return value


_Constructor.yaml_constructors = {**yaml.constructor.SafeConstructor.yaml_constructors,
                                  "tag:yaml.org,2002:int": _Constructor.construct_yaml_int}


class _Composer(yaml.composer.Composer, _Resolver):
    """PyYAML's composer (over either parser's events) with the limits of this module:
    composing enforces the nesting, alias and expansion limits, raising SourceError at the
    node or alias that crosses one."""

    def __init__(self, path: str, size: int) -> None:
        yaml.composer.Composer.__init__(self)
        _Resolver.__init__(self)
        self.path = path
        self.text_budget = text_budget(size)
        self.node_budget = node_budget(size)
        self.nodes = 0  # so far, aliases expanded
        self.chars = 0  # of scalar values so far, aliases expanded
        self.aliases = 0
        self.open_anchors: list[str | None] = []  # of the nodes being composed, outermost first
        self.sizes: dict[str, tuple[int, int]] = {}  # anchor -> (nodes, chars), expanded
        #: whether a node has a tag of its own (``!!str``, ``!x``) or is a plain text with
        #: a ``?`` inside a flow collection: what libyaml reads otherwise than PyYAML
        self.divergent = False
        self.flow = 0  # flow collections open
        self.source: str | None = None  # the text libyaml parses (None: PyYAML parses)
        #: (index, mark): a node starting at that index is placed at that mark instead
        self.end: tuple[int, Any] = (-1, None)

    def _refuse(self, mark: Any, message: str) -> SourceError:
        return SourceError(_mark(self.path, mark), message)

    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()  # type: ignore[attr-defined]
        if isinstance(event, yaml.AliasEvent):
            name = str(event.anchor)
            if name in self.open_anchors:
                raise self._refuse(event.start_mark, f"recursive alias '*{name}': it stands "
                                   "for a node that contains it")
            node = super().compose_node(parent, index)  # an undefined alias is refused here
            self.aliases += 1
            if self.aliases > MAX_ALIASES:
                raise self._refuse(event.start_mark, f"too many aliases: expected at most "
                                   f"{MAX_ALIASES} in one file, found '*{name}' beyond them")
            self._charge(*self.sizes.get(name, (1, 0)), event.start_mark,
                         f"alias '*{name}' expands the file to")
            return node
        if len(self.open_anchors) >= MAX_DEPTH:
            raise self._refuse(event.start_mark, f"YAML nested deeper than {MAX_DEPTH} levels "
                               "(mappings and lists inside one another)")
        if isinstance(event, yaml.ScalarEvent) and not event.style:
            if event.anchor is not None and not event.value:
                raise self._refuse(event.start_mark, anchor_alone(event.anchor))
            if self.flow and "?" in event.value:
                self.divergent = True
            elif self.flow and not event.value and self.source is not None:
                self._place_empty(event)
        if event.tag is not None:
            self.divergent = True
        if event.start_mark.index == self.end[0]:
            event.start_mark = event.end_mark = self.end[1]
        nodes, chars = self.nodes, self.chars
        self._charge(1, len(getattr(event, "value", "") or ""), event.start_mark,
                     "the file has")
        flow = 1 if getattr(event, "flow_style", False) else 0
        self.flow += flow
        self.open_anchors.append(event.anchor)
        try:
            node = super().compose_node(parent, index)
        finally:
            self.open_anchors.pop()
            self.flow -= flow
        if event.anchor is not None:
            self.sizes[event.anchor] = (self.nodes - nodes, self.chars - chars)
        return node

    def _place_empty(self, event: Any) -> None:
        """An empty value after ``key:`` in a flow mapping (``{a: , b: 1}``) is placed by
        PyYAML right after the ``:``, by libyaml at the next token: placed here as PyYAML
        does (after spaces on one line), or the text is read by PyYAML (across lines)."""
        text, mark = str(self.source), event.start_mark
        i = j = mark.index
        while j > 0 and text[j - 1] == " ":
            j -= 1
        if j > 0 and text[j - 1] in "\n\r":
            self.divergent = True
        elif j > 0 and text[j - 1] == ":" and j != i:
            event.start_mark = event.end_mark = yaml.Mark(
                mark.name, j, mark.line, mark.column - (i - j), None, 0)

    def _charge(self, nodes: int, chars: int, mark: Any, what: str) -> None:
        self.nodes += nodes
        self.chars += chars
        if self.nodes > self.node_budget:
            raise self._refuse(mark, f"{what} more than {self.node_budget} nodes (mappings, "
                               f"lists and values, aliases expanded; {NODE_ALLOWANCE} plus a "
                               "quarter of its size)")
        if self.chars > self.text_budget:
            raise self._refuse(mark, f"{what} more than {self.text_budget} characters of "
                               f"values (its size plus {EXPANSION_ALLOWANCE}, aliases "
                               "expanded): expected anchors that share a few values")


class _Loader(yaml.reader.Reader, yaml.scanner.Scanner, yaml.parser.Parser, _Composer):
    """PyYAML's pure-Python reader, scanner and parser under the composer with limits: the
    parser where libyaml is missing, and the one that words every syntax error."""

    def __init__(self, text: str, path: str = "<yaml>") -> None:
        yaml.reader.Reader.__init__(self, text)
        yaml.scanner.Scanner.__init__(self)
        yaml.parser.Parser.__init__(self)
        _Composer.__init__(self, path, len(text))


if _HAS_LIBYAML:
    class _CLoader(_Composer, _CParser):
        """libyaml's parser (PyYAML's C extension) under the composer with limits: its
        events carry the same marks (line, column, index in characters) as the
        pure-Python parser's, so the nodes, and every place kept, are the same."""

        def __init__(self, text: str, path: str) -> None:
            _CParser.__init__(self, text)
            _Composer.__init__(self, path, len(text))
            self.source = text
            if text and not text.endswith(("\n", "\r")):
                # libyaml puts the end of a text without a final line break on a line of
                # its own; PyYAML after its last character, where an empty value at the
                # very end is placed
                end = _index_loc(path, text, len(text))
                self.end = (len(text), yaml.Mark(path, len(text), end.line - 1, end.col - 1,
                                                 None, 0))


def _mark(path: str, mark: Any) -> Loc:
    return Loc(path, mark.line + 1, mark.column + 1)


_BREAKS = "\n\x85\u2028\u2029"
_ESC_LEN = {"x": 2, "u": 4, "U": 8}


def _raw_units(raw: str, style: str | None) -> tuple[int, list[tuple[int, str | None]]]:
    """Split a scalar's source text into units that each stand for at most one character of
    its value: (raw index, the character, or None for an escape that matches any)."""
    if style in ("|", ">"):
        first = raw.find("\n")
        start = len(raw) if first < 0 else first + 1
    elif style in ("'", '"'):
        start = 1
    else:
        start = 0
    units: list[tuple[int, str | None]] = []
    i, n = start, len(raw)
    while i < n:
        c = raw[i]
        if style == "'" and c == "'":
            if i + 1 < n and raw[i + 1] == "'":
                units.append((i, "'"))
                i += 2
                continue
            break  # closing quote
        if style == '"' and c == '"':
            break
        if style == '"' and c == "\\" and i + 1 < n:
            e = raw[i + 1]
            if e in _BREAKS or e == "\r":  # line continuation: stands for nothing
                i += 2
                continue
            units.append((i, None))
            i += 2 + _ESC_LEN.get(e, 0)
            continue
        units.append((i, c))
        i += 1
    return start, units


def _value_positions(value: str, text: str, start: int, end: int, line: int, col: int,
                     style: str | None) -> list[tuple[int, int]]:
    """File (line, col) of each character of a scalar's value, by aligning the value with
    its source text ``text[start:end]``, which begins at ``line``, ``col`` (folded line
    breaks and indentation are skipped)."""
    raw = text[start:end]
    # file place of every raw character
    places: list[tuple[int, int]] = []
    for ch in raw:
        places.append((line, col))
        if ch in _BREAKS:
            line, col = line + 1, 1
        elif ch != "\r":
            col += 1
    places.append((line, col))
    skip = _content_start(raw)
    _, units = _raw_units(raw[skip:], style)
    out: list[tuple[int, int]] = []
    u = 0
    for ch in value:
        k = u
        while k < len(units):
            rc = units[k][1]
            if rc is None or rc == ch or (ch.isspace() and rc.isspace()):
                break
            k += 1
        if k < len(units):
            out.append(places[skip + units[k][0]])
            u = k + 1
        else:  # not found (should not happen): keep the current place
            out.append(places[skip + units[u][0]] if u < len(units) else places[-1])
    return out


def _content_start(raw: str) -> int:
    """Where a scalar's content begins in its source text: after its properties (an anchor
    ``&a``, a tag ``!!str``, which a node's start includes) and the spaces, line breaks and
    comments after them. No content begins with ``&`` or ``!``: they are properties."""
    i, n = 0, len(raw)
    while i < n and raw[i] in "&!":
        while i < n and not raw[i].isspace():
            i += 1
        while i < n and (raw[i].isspace() or raw[i] == "#"):
            if raw[i] == "#":
                while i < n and raw[i] not in _BREAKS and raw[i] != "\r":
                    i += 1
            else:
                i += 1
    return i


def _make_str(value: str, node: yaml.ScalarNode, path: str, text: str) -> YStr:
    s = YStr(value)
    sm = node.start_mark
    src = (text, sm.index, node.end_mark.index, sm.line + 1, sm.column + 1, node.style)
    s._src, s._pos = src, None
    if not value:
        s.loc = Loc(path, src[3], src[4])
    elif text[sm.index] not in "&!" and (node.style in (None, "") or (
            node.style in ("'", '"') and not _has_break(text, sm.index, node.end_mark.index))):
        # a plain scalar's value begins at its first character, a quoted one's on one line
        # at the character after the quote (either without properties before it): the
        # place without working out the others
        quoted = 1 if node.style else 0
        s.loc = Loc(path, src[3], src[4] + quoted)
    else:
        s.loc = Loc(path, *s.places()[0])
    return s


def _has_break(text: str, start: int, end: int) -> bool:
    """Whether ``text[start:end]`` holds a line break."""
    return _LINE_BREAK.search(text, start, end) is not None


class SourceFileError(SourceError):
    """A chart, plant or script file that cannot be read at all: no regular file below
    its limit (a FIFO, ``/dev/zero``, a directory, a huge file) or an error of the system
    (``/proc/self/mem``: EIO). ``problem`` is the message without the place, for a plant to
    say it at the line that names the file."""

    def __init__(self, path: str, problem: str) -> None:
        super().__init__(Loc(path, 1, 1), problem)
        self.problem = problem


def read_bytes(path: str, limit: int | None = None) -> bytes:
    """The bytes of a user's file; SourceFileError if it is no regular file below ``limit``
    bytes (MAX_FILE_BYTES unless told) or cannot be read.

    Read by ``safefile.read_bounded``, following a symbolic link (a deployment may link
    its plant file): never blocking, never past the limit."""
    limit = MAX_FILE_BYTES if limit is None else limit
    try:
        return read_bounded(path, limit - 1, follow_links=True)
    except UnfitFile as exc:
        raise SourceFileError(path, f"must be a regular file below {limit // 1024} KiB "
                              f"({limit} bytes), found {exc.found}") from None
    except OSError as exc:
        raise SourceFileError(path, f"cannot read file: {exc.strerror or exc}") from None


def read_source(path: str) -> str:
    """The text of a chart, plant or script file; SourceFileError if it is no regular file
    below MAX_FILE_BYTES (``read_bytes``) or cannot be read, SourceError if it is not
    UTF-8."""
    data = read_bytes(path)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        good = data[:exc.start].decode("utf-8")
        raise SourceError(_index_loc(path, good, len(good)), f"file is not UTF-8: byte "
                          f"0x{data[exc.start]:02X}: {exc.reason}") from None


_LINE_BREAK = re.compile("\r\n|[\r\n\x85\u2028\u2029]")


def _index_loc(path: str, text: str, index: int) -> Loc:
    """File place of character ``index`` of ``text``, counting line breaks as YAML does."""
    line, start = 1, 0
    for m in _LINE_BREAK.finditer(text, 0, index):
        line, start = line + 1, m.end()
    return Loc(path, line, index - start + 1)


#: parse with libyaml where PyYAML has it (the tests set it False to run the other path)
USE_LIBYAML = _HAS_LIBYAML
#: what libyaml reads otherwise than PyYAML's pure-Python parser (found by comparing them
#: on random texts, tests/language/test_yaml_paths.py): a tab (libyaml accepts one after a
#: value, PyYAML refuses it), the line breaks NEL, LS and PS (in a comment), U+FEFF
#: (PyYAML counts it in no column) and a block scalar's header followed at once by a
#: comment (PyYAML refuses ``|#``). A text holding one is parsed by PyYAML alone, and so is
#: one that libyaml reads with a tag (it accepts tags PyYAML refuses) or with a ``?`` in a
#: plain text inside a flow collection (PyYAML reads ``{a: b?}`` as ``b`` and a key
#: indicator), which is seen while composing (``_Composer.divergent``): the same file
#: loads, or is refused, alike on every machine.
_DIVERGENT = re.compile("[\t\x85\u2028\u2029\ufeff]|[|>][-+0-9]*#")


def _compose(path: str, text: str) -> Any:
    """The file's node tree (None for an empty file), composed under the limits; libyaml
    parses where it can (``_DIVERGENT``). A syntax error is always worded by the
    pure-Python parser (it words them as this project's messages and tests expect): on
    libyaml's error the file is parsed again in Python, which costs time only on a file
    that does not load."""
    if USE_LIBYAML and _DIVERGENT.search(text) is None:
        cloader = _CLoader(text, path)
        try:
            node = cloader.get_single_node()
            if not cloader.divergent:
                return node
        except yaml.YAMLError:
            pass  # worded below
        except SourceError:  # a limit: PyYAML would stop there too, unless it read the
            if not cloader.divergent:  # text otherwise before
                raise
        finally:
            cloader.dispose()
    try:
        loader = _Loader(text, path)
        try:
            return loader.get_single_node()
        finally:
            loader.dispose()
    except yaml.reader.ReaderError as exc:
        raise SourceError(_index_loc(path, text, exc.position), f"character "
                          f"U+{exc.character:04X} is not allowed in YAML (control characters "
                          "other than tab and line breaks, U+FFFE and U+FFFF): remove it"
                          ) from None
    except yaml.MarkedYAMLError as exc:
        raise _syntax_error(path, text, exc) from None


def _syntax_error(path: str, text: str, exc: yaml.MarkedYAMLError) -> SourceError:
    """PyYAML's error as one line: a newcomer's slip in the file's words with what to
    write instead (yamlslip.py), any other in PyYAML's words."""
    mark = exc.problem_mark or exc.context_mark
    slip = explain(exc.problem or "", exc.problem_mark, exc.context, exc.context_mark,
                   text) if exc.problem_mark is not None else None
    if slip is not None:
        return SourceError(Loc(path, slip[0] + 1, slip[1] + 1), f"YAML syntax: {slip[2]}")
    loc = _mark(path, mark) if mark else Loc(path, 1, 1)
    ctx = f" ({exc.context})" if exc.context else ""
    return SourceError(loc, f"YAML syntax: {exc.problem or 'invalid YAML'}{ctx}")


#: the tag of a text: its value is the node's, as it is
_STR_TAG = "tag:yaml.org,2002:str"


def load_yaml(path: str, text: str | None = None) -> Any:
    """Load a YAML file into YMap/YList/YStr/scalars; raise SourceError on bad YAML or a
    file beyond the limits of the module's docstring."""
    if text is None:
        text = read_source(path)
    node = _compose(path, text)
    if node is None:
        raise SourceError(Loc(path, 1, 1), "empty file: expected a YAML mapping")
    constructor = _Constructor()

    def scalar(n: yaml.Node) -> Any:
        try:
            return constructor.construct_object(n)
        except (ValueError, TypeError, KeyError, IndexError, OverflowError) as exc:
            # a tagged or implicit value the tag cannot hold: '!!int abc', 2001-99-99
            kind = str(n.tag).rsplit(":", 1)[-1]
            raw = str(n.value) if isinstance(n.value, str) else "..."
            shown = raw if len(raw) <= 40 else raw[:37] + "..."
            raise SourceError(_mark(path, n.start_mark), f"cannot read '{shown}' as a YAML "
                              f"{kind} ({exc}): quote it to make it a text") from None

    def convert(n: yaml.Node) -> Any:
        if isinstance(n, yaml.MappingNode):
            m = YMap()
            m.loc = _mark(path, n.start_mark)
            m.key_locs, m.val_locs = {}, {}
            for kn, vn in n.value:
                if not isinstance(kn, yaml.ScalarNode):
                    raise SourceError(_mark(path, kn.start_mark), "expected a plain key")
                key = kn.value if kn.tag == _STR_TAG else str(scalar(kn))
                if key in m:
                    raise SourceError(_mark(path, kn.start_mark),
                                      f"duplicate key: expected each key once, found "
                                      f"'{key}' again")
                m[key] = convert(vn)
                m.key_locs[key] = _mark(path, kn.start_mark)
                m.val_locs[key] = (
                    m[key].loc if isinstance(m[key], YStr) else _mark(path, vn.start_mark)
                )
            return m
        if isinstance(n, yaml.SequenceNode):
            lst = YList()
            lst.loc = _mark(path, n.start_mark)
            lst.locs = []
            for item in n.value:
                v = convert(item)
                lst.append(v)
                lst.locs.append(v.loc if isinstance(v, YStr) else _mark(path, item.start_mark))
            return lst
        if isinstance(n, yaml.ScalarNode) and n.tag == _STR_TAG:
            return _make_str(n.value, n, path, text)
        value = scalar(n)
        if isinstance(value, str) and isinstance(n, yaml.ScalarNode):
            return _make_str(value, n, path, text)
        return value

    try:
        return convert(node)
    except yaml.constructor.ConstructorError as exc:
        mark = exc.problem_mark
        slip = explain(str(exc.problem), mark, None, None, text) if mark else None
        if slip is not None:  # a tag of the file's own: '!iVaso'
            raise SourceError(Loc(path, slip[0] + 1, slip[1] + 1),
                              f"YAML syntax: {slip[2]}") from None
        raise SourceError(_mark(path, mark) if mark else Loc(path, 1, 1),
                          str(exc.problem)) from None
