"""YAML loading that keeps where every key and value was written, for error messages.

It is also the one place that reads the project's YAML files (charts, plants, scripts), so
the limits that keep a hostile file from hanging or exhausting the controller live here:
a source file is a regular file below ``MAX_FILE_BYTES``, its YAML nests at most
``MAX_DEPTH`` levels, uses at most ``MAX_ALIASES`` aliases, and once aliases are expanded
holds at most ``node_budget(size)`` nodes and ``text_budget(size)`` characters of values; its
integers fit 64 bits (``INT_MIN`` .. ``INT_MAX``). Each is refused with one
``FILE:LINE:COL`` error. Loading costs about 25 µs and 1.5 kB per node and 0.8 µs and
220 bytes per character of text (pure-Python YAML and the places kept for messages,
measured on a loaded 2-core machine): a file of ordinary density loads in about 0.3 s per
10 000 nodes; the densest file the limits let through (1 MiB of one-character flow items)
takes about 7 s and 400 MB, which is the price of loading a 1000-instance plant from one
file.
"""

from __future__ import annotations

import os
import re
import stat
from typing import Any

import yaml

from drivers.durations import MAX_NS
from runtime.errors import Loc, SourceError

#: the largest chart, plant or script file read, in bytes (1 MiB: the example charts and
#: plants are under 7 kB, a plant of 1000 drawer testers is 300 kB; a file of one 1 MiB
#: text loads in about 0.8 s and 225 MB)
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

    ``_pos[i]`` is the file (line, col) of character i of the value, for every scalar style:
    plain, single- and double-quoted (``''`` and escapes such as ``\\u2191`` count as the
    characters they stand for), and block scalars (``|``, ``>``), including folded lines.
    """

    loc: Loc
    _pos: list[tuple[int, int]]

    def pos(self, offset: int) -> Loc:
        """File place of character ``offset`` of this string (past the end: after the last
        visible character, where 'found end of text' points)."""
        p = self._pos
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


def synthetic_str(value: str, loc: Loc) -> YStr:
    """A YStr for text that is not in the file as such (a YAML number or bool used as a
    condition): its characters are placed one after the other from ``loc``."""
    s = YStr(value)
    s.loc = loc
    s._pos = [(loc.line, loc.col + i) for i in range(len(value))]
    return s


class _Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 booleans: only true/false (any of True, TRUE ...) are bools.

    YAML 1.1 also reads yes/no/on/off as bools, so an output named ``On`` or a step named
    ``No`` would silently become ``True``/``False``; editors' YAML language servers use 1.2.

    Composing enforces the nesting, alias and expansion limits (raising SourceError at the
    node or alias that crosses one), and integers are bounded to 64 bits.
    """

    def __init__(self, text: str, path: str = "<yaml>") -> None:
        super().__init__(text)
        self.path = path
        self.text_budget = text_budget(len(text))
        self.node_budget = node_budget(len(text))
        self.nodes = 0  # so far, aliases expanded
        self.chars = 0  # of scalar values so far, aliases expanded
        self.aliases = 0
        self.open_anchors: list[str | None] = []  # of the nodes being composed, outermost first
        self.sizes: dict[str, tuple[int, int]] = {}  # anchor -> (nodes, chars), expanded

    def _refuse(self, mark: Any, message: str) -> SourceError:
        return SourceError(_mark(self.path, mark), message)

    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()  # type: ignore[no-untyped-call]
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
        nodes, chars = self.nodes, self.chars
        self._charge(1, len(getattr(event, "value", "") or ""), event.start_mark,
                     "the file has")
        self.open_anchors.append(event.anchor)
        try:
            node = super().compose_node(parent, index)
        finally:
            self.open_anchors.pop()
        if event.anchor is not None:
            self.sizes[event.anchor] = (self.nodes - nodes, self.chars - chars)
        return node

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


_Loader.add_constructor("tag:yaml.org,2002:int", _Loader.construct_yaml_int)


_Loader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag != "tag:yaml.org,2002:bool"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_Loader.add_implicit_resolver("tag:yaml.org,2002:bool",
                              re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
                              list("tTfF"))


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


def _value_positions(value: str, node: yaml.ScalarNode, text: str) -> list[tuple[int, int]]:
    """File (line, col) of each character of a scalar's value, by aligning the value with
    its source text (folded line breaks and indentation are skipped)."""
    sm, em = node.start_mark, node.end_mark
    raw = text[sm.index:em.index]
    # file place of every raw character
    places: list[tuple[int, int]] = []
    line, col = sm.line + 1, sm.column + 1
    for ch in raw:
        places.append((line, col))
        if ch in _BREAKS:
            line, col = line + 1, 1
        elif ch != "\r":
            col += 1
    places.append((line, col))
    _, units = _raw_units(raw, node.style)
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
            out.append(places[units[k][0]])
            u = k + 1
        else:  # not found (should not happen): keep the current place
            out.append(places[units[u][0]] if u < len(units) else places[-1])
    return out


def _make_str(value: str, node: yaml.ScalarNode, path: str, text: str) -> YStr:
    s = YStr(value)
    s._pos = _value_positions(value, node, text)
    if s._pos:
        s.loc = Loc(path, *s._pos[0])
    else:
        s.loc = _mark(path, node.start_mark)
    return s


_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))


def file_problem(mode: int, size: int, limit: int | None = None) -> str | None:
    """Why a file of this ``st_mode`` and size (bytes) is no source file: not a regular
    file, or not below ``limit`` bytes (MAX_FILE_BYTES unless told); None if it is one."""
    limit = MAX_FILE_BYTES if limit is None else limit
    if not stat.S_ISREG(mode):
        found = next((what for test, what in _KINDS if test(mode)), "no regular file")
    elif size >= limit:
        found = f"a file of {size} bytes"
    else:
        return None
    return (f"must be a regular file below {limit // 1024} KiB ({limit} bytes), found {found}")


def source_problem(path: str, limit: int | None = None) -> str | None:
    """Why ``path`` cannot be read as a chart, plant or script, or as a file of at most
    ``limit`` bytes (None: it can be tried)."""
    try:
        st = os.stat(path)
    except OSError as exc:
        return f"cannot read file: {exc.strerror}"
    return file_problem(st.st_mode, st.st_size, limit)


def read_bytes(path: str, limit: int | None = None) -> bytes:
    """The bytes of a user's file; SourceError if it is no regular file below ``limit``
    bytes (MAX_FILE_BYTES unless told).

    The status is checked before opening (opening a device can have effects of its own), the
    file is opened non-blocking (a FIFO put in its place meanwhile cannot hang the open) and
    checked again, and at most ``limit`` bytes are read whatever its size said.
    """
    limit = MAX_FILE_BYTES if limit is None else limit
    problem = source_problem(path, limit)
    data = b""
    if problem is None:
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError as exc:
            raise SourceError(Loc(path, 1, 1), f"cannot read file: {exc.strerror}") from None
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(fd)
            problem = file_problem(st.st_mode, st.st_size, limit)
            if problem is None:
                data = f.read(limit)
                problem = file_problem(st.st_mode, len(data), limit)  # it grew meanwhile
    if problem is not None:
        raise SourceError(Loc(path, 1, 1), problem)
    return data


def read_source(path: str) -> str:
    """The text of a chart, plant or script file; SourceError if it is no regular file below
    MAX_FILE_BYTES (``read_bytes``) or not UTF-8."""
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


def load_yaml(path: str, text: str | None = None) -> Any:
    """Load a YAML file into YMap/YList/YStr/scalars; raise SourceError on bad YAML or a
    file beyond the limits of the module's docstring."""
    if text is None:
        text = read_source(path)
    try:
        loader = _Loader(text, path)
        try:
            node = loader.get_single_node()
        finally:
            loader.dispose()
    except yaml.reader.ReaderError as exc:
        raise SourceError(_index_loc(path, text, exc.position), f"character "
                          f"U+{exc.character:04X} is not allowed in YAML (control characters "
                          "other than tab and line breaks, U+FFFE and U+FFFF): remove it"
                          ) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        loc = _mark(path, mark) if mark else Loc(path, 1, 1)
        what = exc.problem or "invalid YAML"
        if what == "mapping values are not allowed here":
            what = "found ':' where no mapping value is allowed (quote a text holding ': ')"
        ctx = f" ({exc.context})" if exc.context else ""
        raise SourceError(loc, f"YAML syntax: {what}{ctx}") from None
    if node is None:
        raise SourceError(Loc(path, 1, 1), "empty file: expected a YAML mapping")
    constructor = _Loader(text, path)

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
                key = str(scalar(kn))
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
        value = scalar(n)
        if isinstance(value, str) and isinstance(n, yaml.ScalarNode):
            return _make_str(value, n, path, text)
        return value

    try:
        return convert(node)
    except yaml.constructor.ConstructorError as exc:
        mark = exc.problem_mark
        raise SourceError(_mark(path, mark) if mark else Loc(path, 1, 1),
                          str(exc.problem)) from None
