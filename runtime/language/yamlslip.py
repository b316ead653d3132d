"""The words of a YAML syntax error: the slips a newcomer makes, said with the file's own
words and what to write instead.

PyYAML words an error as its parser sees it (``found character '\\t' that cannot start
any token``, ``expected <block end>, but found '-'``). For the slips met when writing
charts from the course notes (a tab, a value that begins with one of YAML's indicators
such as ``!iVaso``, ``*iVaso`` or ``&iVaso`` alone, a value quoted or bracketed in part,
a plain text holding ': ' (``description: Pump P1: stopped``), a list item among a
mapping's keys, a key among a list's items, a key out of line),
``explain`` says what was expected and what the file has, and how to write it; any other
error keeps PyYAML's words. The place is the slip's: the tab, the indicator, the line out
of place.
"""

from __future__ import annotations

import re
from typing import Any

#: the longest piece of the file quoted in a message, in characters
SHOWN = 40
_BREAK = re.compile("\r\n|[\r\n\x85\u2028\u2029]")
_NAME = re.compile(r"[A-Za-z_]\w*")


def explain(problem: str, problem_mark: Any, context: str | None, context_mark: Any,
            text: str) -> tuple[int, int, str] | None:
    """(line, column, both from 0, the message after ``YAML syntax: ``) for a slip of the
    list above, or None. The marks are PyYAML's (``line``, ``column``, ``index``)."""
    found = _explain(problem, problem_mark, context or "", context_mark, text)
    if found is None:
        return None
    mark, message = found
    if isinstance(mark, tuple):
        return mark[0], mark[1], message
    return mark.line, mark.column, message


def _explain(problem: str, at: Any, ctx: str, context_mark: Any,
             text: str) -> tuple[Any, str] | None:
    if problem == "found character '\\t' that cannot start any token":
        return at, _tab(text, at.index)
    if problem == "mapping values are not allowed here":
        return _deeper_key(text, at) or _colon_in_value(text, at, flow=False) or (
            at, "found ':' where no mapping value is allowed (quote a text holding ': ')")
    if problem in ("expected ',' or '}', but got ':'", "expected ',' or ']', but got ':'"):
        return _colon_in_value(text, at, flow=True)
    if ctx == "while scanning a tag" and context_mark is not None:
        return context_mark, _tag(_word(text, context_mark.index))
    if problem.startswith("could not determine a constructor for the tag '!") and (
            not problem.startswith("could not determine a constructor for the tag '!!")):
        return at, _tag(_word(text, at.index))
    if problem.startswith("found undefined alias"):
        word = _word(text, at.index)
        return at, _reads_as(word, f"an undefined alias (a copy of the value marked "
                                   f"&{word[1:]}, and none is)")
    if ctx in ("while scanning an alias", "while scanning an anchor") and context_mark:
        word = _word(text, context_mark.index)
        return context_mark, _reads_as(word, "an alias" if word[0] == "*" else "an anchor")
    m = re.fullmatch(r"found character '(.)' that cannot start any token", problem)
    if m and m.group(1) in "@`%":
        word = _word(text, at.index)
        return at, (f"expected a value, found '{word}': YAML reserves '{m.group(1)}' at the "
                    f"start of a value: quote it: {_quoted(word)}")
    if ctx == "while scanning a block scalar" and context_mark is not None:
        return context_mark, _block_header(_rest(text, context_mark.index))
    if problem == "expected <block end>, but found '<scalar>'":
        return _continued(text, at, flow=False)
    if problem in ("expected ',' or '}', but got '<scalar>'",
                   "expected ',' or ']', but got '<scalar>'"):
        return _continued(text, at, flow=True)
    if context_mark is None:
        return None
    if problem == "expected <block end>, but found '-'":
        return at, _item_among_keys(context_mark.line, _rest(text, context_mark.index),
                                    _rest(text, at.index))
    if problem == "expected <block end>, but found '?'":
        return at, _key_among_items(context_mark.line, _rest(text, at.index))
    if problem == "expected <block end>, but found '<block mapping start>'":
        return at, _out_of_line(text, at, context_mark, ctx)
    return None


def _reads_as(word: str, what: str) -> str:
    """A value that begins with one of YAML's indicators, read as ``what``."""
    return (f"expected a value, found '{word}', which YAML reads as {what}: quote a text "
            f"that begins with '{word[0]}': {_quoted(word)}")


def _tag(word: str) -> str:
    negation = (f"; a negation is NOT {word[1:]} or {word[1:]}'"
                if _NAME.fullmatch(word[1:]) else "")
    return _reads_as(word, "a tag") + negation


def _block_header(words: str) -> str:
    """A value that begins with ``|`` or ``>``: YAML's block text, whose header is alone
    on its line."""
    return (f"expected a block text ('{words[0]}' alone at the end of the line, the text on "
            f"the lines below), found '{_short(words)}': quote a value that begins with "
            f"'{words[0]}': {_quoted(words)}")


def _item_among_keys(line: int, first: str, item: str) -> str:
    """A list item where the keys of a mapping (the first one ``first``, at ``line``, from
    0) go on: the mapping was meant as the list's first item."""
    return (f"expected a key of the mapping that begins at line {line + 1} "
            f"('{_short(first)}'), found a list item ('{_short(item)}'): the items of a list "
            f"each begin with '- ' at one indentation: write '- {_short(first)}'")


def _key_among_items(line: int, key: str) -> str:
    """A key where the items of a list (the first at ``line``, from 0) go on."""
    return (f"expected an item ('- ') of the list that begins at line {line + 1}, found a "
            f"key ('{_short(key)}'): begin it with '- ' ('- {_short(key)}'), the keys that "
            "go with it indented under it")


def _tab(text: str, index: int) -> str:
    start = _line_start(text, index)
    before = text[start:index]
    if before.strip(" \t") == "":
        line = _rest(text, index).strip(" \t")
        return (f"expected spaces, found a tab in the indentation of '{_short(line)}': "
                "YAML indents with spaces, never tabs")
    return (f"expected a space, found a tab after '{_short(before.strip(), end=True)}': "
            "YAML separates with spaces, never tabs")


def _continued(text: str, at: Any, flow: bool) -> tuple[Any, str] | None:
    """A value that begins as a list, a mapping or a quoted text, and goes on after it
    closes (``when: [iVaso] AND iLleno``, ``when: "iVaso" AND iLleno``)."""
    start = _line_start(text, at.index)
    opener = None
    for m in re.finditer(r"(?:^|:[ \t]|-[ \t]|[{,][ \t]*)[ \t]*([\[{\"'])",
                         text[start:at.index]):
        opener = start + m.start(1)
    if opener is None:
        return None
    closed = text[opener:at.index].rstrip()
    after = _rest(text, at.index)
    if flow:  # inside a flow collection the value ends at its separator
        after = re.split(r",\s|[{}\[\]]", after)[0]
    after = after.strip()
    kind = text[opener]
    if kind in "[{":
        what, fixed = ("a list" if kind == "[" else "a mapping"), f"{closed} {after}"
    else:  # the quotes were meant for the whole value
        what, fixed = "a quoted text", f"{closed[1:-1]} {after}"
    return at, (f"expected the end of the value after '{_short(closed)}', found "
                f"'{_short(after)}': a value that begins with '{kind}' is {what} and ends "
                f"where it closes: quote the whole value: {_quoted(fixed)}")


def _colon_in_value(text: str, at: Any, flow: bool) -> tuple[Any, str] | None:
    """A plain value holding ': ' (``description: Pump P1: stopped``), which YAML reads as
    a key and its value where the value goes on."""
    start = _line_start(text, at.index)
    keys = list(re.finditer(r"([^\s:#{},\[\]'\"-][^:#{},\[\]]*?):[ \t]+", text[start:at.index]))
    if not keys:
        return None
    key, value = keys[-1].group(1), text[start + keys[-1].end():at.index].rstrip()
    after = _rest(text, at.index)
    if flow:  # inside a flow collection the value ends at its separator
        after = re.split(r",\s|[{}\[\]]", after)[0]
    after = after.strip()
    if not value or not after.startswith(":"):
        return None
    return at, (f"expected the end of the value of '{key}' after '{_short(value)}', found "
                f"'{_short(after)}': a text holding ': ' reads as a key and its value: quote "
                f"the whole value: {key}: {_quoted(f'{value}{after}')}")


def anchor_alone(anchor: str) -> str:
    """The message for an anchor followed by no value (``when: &iVaso``)."""
    word = "&" + anchor
    return (f"YAML syntax: expected a value after '{word}', found nothing: YAML reads "
            f"'{word}' as an anchor (a name for the value after it): quote a text that "
            f"begins with '&': {_quoted(word)}")


def _key_above(text: str, start: int) -> tuple[int, str] | None:
    """(column from 0, name) of the key on the last line with content before the line
    that begins at ``start``, if it holds one (``key: ...`` or ``- key: ...``)."""
    lines = _BREAK.split(text[:start])[:-1]
    above = next((x for x in reversed(lines) if x.strip() and not x.lstrip().startswith("#")),
                 None)
    m = re.match(r"( *)(- +)?([^\s:#'\"][^:#]*?):(?:\s|$)", above or "")
    return None if m is None else (len(m.group(1)) + len(m.group(2) or ""), m.group(3))


def _deeper_key(text: str, at: Any) -> tuple[tuple[int, int], str] | None:
    """A key indented further than the key of the line above, which YAML reads as more of
    that key's value (``- from: A`` then ``     to: B``)."""
    start = _line_start(text, at.index)
    written = text[start:at.index]
    key, indent = written.strip(), len(written) - len(written.lstrip(" "))
    above = _key_above(text, start)
    if not _NAME.fullmatch(key) or above is None or above[0] >= indent:
        return None
    column, name = above
    return (at.line, indent), (f"expected the key '{key}' at column {column + 1}, aligned "
                               f"with '{name}' above it, found it at column {indent + 1}, "
                               f"where YAML reads it as more of the value of '{name}': "
                               "align it")


def _out_of_line(text: str, at: Any, context_mark: Any, ctx: str) -> str:
    line = _rest(text, at.index)
    what = "an item ('- ') of the list" if "collection" in ctx else "a key of the mapping"
    above = _key_above(text, _line_start(text, at.index))
    aligned = (f" or a key aligned with '{above[1]}' above it (column {above[0] + 1})"
               if above is not None and above[0] > at.column else "")
    return (f"expected {what} that begins at line {context_mark.line + 1} (column "
            f"{context_mark.column + 1}){aligned}, found '{_short(line)}' at column "
            f"{at.column + 1}: align it")


def _line_start(text: str, index: int) -> int:
    start = 0
    for m in _BREAK.finditer(text, 0, index):
        start = m.end()
    return start


def _rest(text: str, index: int) -> str:
    """The file's text from ``index`` to the end of its line, without a comment."""
    m = _BREAK.search(text, index)
    line = text[index:m.start() if m else len(text)]
    cut = re.search(r"\s#", line)
    return (line[:cut.start()] if cut else line).rstrip()


def _word(text: str, index: int) -> str:
    """The run of the file's text at ``index`` up to a space, a flow separator or the end
    of the line."""
    m = re.match(r"[^\s,\[\]{}]+", _rest(text, index))
    return m.group(0) if m else text[index:index + 1]


def _short(words: str, end: bool = False) -> str:
    if len(words) <= SHOWN:
        return words
    return "..." + words[-(SHOWN - 3):] if end else words[:SHOWN - 3] + "..."


def _quoted(words: str) -> str:
    """``words`` as a YAML quoted text."""
    words = _short(words)
    if '"' not in words and "\\" not in words:
        return f'"{words}"'
    return "'" + words.replace("'", "''") + "'"
