"""YAML loading that keeps where every key and value was written, for error messages."""

from __future__ import annotations

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
    """A YAML string that can map an offset inside it back to a file line and column."""

    loc: Loc
    _lines: list[tuple[int, int, int]]  # (offset in value, file line, file col) per value line

    def pos(self, offset: int) -> Loc:
        """File place of character ``offset`` of this string."""
        line, col, start = self.loc.line, self.loc.col, 0
        for start_off, fline, fcol in self._lines:
            if start_off <= offset:
                start, line, col = start_off, fline, fcol
        return Loc(self.loc.file, line, col + offset - start)


def _mark(path: str, mark: Any) -> Loc:
    return Loc(path, mark.line + 1, mark.column + 1)


def _make_str(value: str, node: yaml.ScalarNode, path: str, text_lines: list[str]) -> YStr:
    s = YStr(value)
    s.loc = _mark(path, node.start_mark)
    style = node.style
    if style in ("|", ">"):
        # block scalar: content starts on the line after the indicator, at its indentation
        first = node.start_mark.line + 1
        lines: list[tuple[int, int, int]] = []
        off = 0
        indent = None
        for i, part in enumerate(value.split("\n")):
            fl = first + i
            src = text_lines[fl] if fl < len(text_lines) else ""
            if indent is None and src.strip():
                indent = len(src) - len(src.lstrip(" "))
            lines.append((off, fl + 1, (indent or 0) + 1))
            off += len(part) + 1
        s._lines = lines
        if lines:
            s.loc = Loc(path, lines[0][1], lines[0][2])
    else:
        col = node.start_mark.column + (1 if style in ("'", '"') else 0) + 1
        s._lines = [(0, node.start_mark.line + 1, col)]
        if "\n" not in value:
            s.loc = Loc(path, node.start_mark.line + 1, col)
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
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        loc = _mark(path, mark) if mark else Loc(path, 1, 1)
        what = exc.problem or "invalid YAML"
        ctx = f" ({exc.context})" if exc.context else ""
        raise SourceError(loc, f"YAML syntax: {what}{ctx}") from None
    if node is None:
        raise SourceError(Loc(path, 1, 1), "empty file: expected a YAML mapping")
    constructor = yaml.SafeLoader(text)
    text_lines = text.split("\n")

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
                    raise SourceError(_mark(path, kn.start_mark), f"duplicate key '{key}'")
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
        if isinstance(value, str):
            return _make_str(value, n, path, text_lines)
        return value

    try:
        return convert(node)
    except yaml.constructor.ConstructorError as exc:
        mark = exc.problem_mark
        raise SourceError(_mark(path, mark) if mark else Loc(path, 1, 1), str(exc.problem))
