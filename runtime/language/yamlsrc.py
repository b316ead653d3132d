"""YAML loading that keeps where every key and value was written, for error messages."""

from __future__ import annotations

import re
from typing import Any

import yaml

from runtime.errors import Loc, SourceError


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
    """


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


def load_yaml(path: str, text: str | None = None) -> Any:
    """Load a YAML file into YMap/YList/YStr/scalars; raise SourceError on bad YAML."""
    if text is None:
        try:
            with open(path, encoding="utf-8") as f:
                text = f.read()
        except OSError as exc:
            raise SourceError(Loc(path, 1, 1), f"cannot read file: {exc.strerror}") from None
        except UnicodeDecodeError as exc:
            raise SourceError(Loc(path, 1, 1), f"file is not UTF-8: {exc.reason}") from None
    try:
        node = yaml.compose(text, Loader=_Loader)
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
    constructor = _Loader(text)

    def convert(n: yaml.Node) -> Any:
        if isinstance(n, yaml.MappingNode):
            m = YMap()
            m.loc = _mark(path, n.start_mark)
            m.key_locs, m.val_locs = {}, {}
            for kn, vn in n.value:
                if not isinstance(kn, yaml.ScalarNode):
                    raise SourceError(_mark(path, kn.start_mark), "expected a plain key")
                key = str(constructor.construct_object(kn))
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
        value = constructor.construct_object(n)
        if isinstance(value, str) and isinstance(n, yaml.ScalarNode):
            return _make_str(value, n, path, text)
        return value

    try:
        return convert(node)
    except yaml.constructor.ConstructorError as exc:
        mark = exc.problem_mark
        raise SourceError(_mark(path, mark) if mark else Loc(path, 1, 1),
                          str(exc.problem)) from None
