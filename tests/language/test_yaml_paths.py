"""The two ways runtime.language.yamlsrc parses a file give the same result: libyaml
(PyYAML's C parser, where the wheel has it) and the pure-Python parser (where it is
missing, and always to word a syntax error). Every value, every place kept (mappings,
lists, keys, values, each character of a text) and every refusal's line must be the same,
on the example files, on texts written to reach each scalar style and line break, on the
error corpus and on random texts."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.errors import Loc, SourceError
from runtime.language import yamlsrc
from runtime.language.yamlsrc import MAX_ALIASES, MAX_DEPTH, YList, YMap, YStr, load_yaml

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted(ROOT.glob("configs/*/*.yaml"))


def outcome(text: str, libyaml: bool, path: str = "f.yaml") -> Any:
    """What loading ``text`` gives on one path: a canonical tree with every place, or the
    refusal's line."""
    old = yamlsrc.USE_LIBYAML
    yamlsrc.USE_LIBYAML = libyaml
    try:
        return canonical(load_yaml(path, text))
    except SourceError as exc:
        return ("refused", str(exc))
    finally:
        yamlsrc.USE_LIBYAML = old


def canonical(v: Any) -> Any:
    """The value with every place the loader keeps, as plain tuples."""
    if isinstance(v, YMap):
        return ("map", v.loc, [(k, v.key_locs[k], v.val_locs[k], canonical(x))
                               for k, x in v.items()])
    if isinstance(v, YList):
        return ("list", v.loc, v.locs, [canonical(x) for x in v])
    if isinstance(v, YStr):
        places = v.places()
        if v:  # the place found without working out the others is the first character's
            assert v.loc == Loc(v.loc.file, *places[0]), (str(v), v.loc, places[0])
        return ("str", str(v), v.loc, places, v.pos(len(v)))
    return (type(v).__name__, v)


def same(text: str) -> Any:
    """Both paths' outcome, asserted equal."""
    fast, slow = outcome(text, True), outcome(text, False)
    assert fast == slow
    return fast


def test_this_pyyaml_has_libyaml() -> None:
    # PyYAML's wheels for x86_64 and aarch64 carry it: where CI runs, the fast path is used
    assert yamlsrc.USE_LIBYAML


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_example_file_loads_the_same(path: Path) -> None:
    got = same(path.read_text(encoding="utf-8"))
    assert got[0] == "map"


TEXTS = {
    "plain and flow": "a: b c\nd: [e, {f: g h, i: 1}]\nj: 2.5\nk: true\nl: ~\n",
    "plain on two lines": "a: b\n  c   d\n\n  e\n",
    "single quoted": "a: 'it''s  ok'\nb: 'x\n\n  y  z'\n",
    "double quoted escapes": 'a: "x\\u2191y\\ttab\\x41\\U0001F600"\nb: "p\\\n   q"\n',
    "literal block": "a: |\n  line1\n    line2\n\n  line3\nb: x\n",
    "folded block": "a: >-\n  one\n  two\n\n  three\nb: |+\n  keep\n\n",
    "block indentation indicator": "a: |2\n   x\n  y\n",
    "crlf": "a: b\r\nc: 'd\r\n  e'\r\nf: |\r\n  g\r\n  h\r\n",
    "lone cr": "a: b\rc: d\r",
    "nel and separators": "a: b\x85c: d\u2028e: f\u2029g: 'h\x85 i'\n",
    "wide characters": "a: 😀b ↑ é\nc: ['ñ', \"😀😀\"]\n",
    "tabs inside values": "a: b\tc\nd: 'e\tf'\n",
    "empty values": "a:\nb: ''\nc: \"\"\nd: []\ne: {}\n",
    "anchors and aliases": "io: &io {x: [1, 2], y: &t text}\na: *io\nb: *io\nc: *t\n",
    "keys of every kind": "1: a\ntrue: b\n'q': c\n? complex\n: d\n",
    "tags": "a: !!str 12\nb: !!int '7'\nc: !!float 1\n",
    "document markers": "%YAML 1.1\n---\na: b\n...\n",
    "comments": "# c\na: b # d\n# e\nc: [x, # f\n  y]\n",
    "bom": "\ufeffa: b\nc: 'd'\n",
    "bom inside": "a: b\ufeffc\nd: 'e'\n",
    "deep list": "a:\n" + "".join("  " * i + "- \n" for i in range(1, 10)) + "  x\n",
}


@pytest.mark.parametrize("name", sorted(TEXTS))
def test_every_style_and_break_keeps_its_places(name: str) -> None:
    same(TEXTS[name])


#: texts every YAML loader refuses, and the limits of this one: the words and the place
#: must not depend on the parser
ERRORS = {
    "unclosed flow mapping": "a: {b: c\nd: []\n",
    "mapping value not allowed": "a: b: c\n",
    "tab indentation": "a:\n\tb: c\n",
    "tag then a brace": "t: {when: !iVaso}\n",
    "undefined alias": "t: {when: *iVaso}\n",
    "mapping where a list item is expected": "t:\n  - a\n  b: c\n",
    "list item after a mapping": "t:\n  a: b\n  - c\n",
    "duplicate anchor": "a: &x 1\nb: &x 2\n",
    "two documents": "a: 1\n---\nb: 2\n",
    "bad escape": 'a: "\\q"\n',
    "unclosed quote": "a: 'b\n",
    "control character": "a: b\x01\n",
    "control character after crlf": "a: b\r\nc: \x07\n",
    "U+FFFE": "a: \ufffe\n",
    "empty file": "",
    "only a comment": "# nothing\n",
    "too deep": "k: " + "[" * MAX_DEPTH + "x" + "]" * MAX_DEPTH + "\n",
    "too many aliases": "a: &a x\nb: [" + ", ".join(["*a"] * (MAX_ALIASES + 1)) + "]\n",
    "recursive alias": "a: &a [1, *a]\n",
    "billion laughs": "a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join([f'*{chr(97 + i)}'] * 10)}]\n"
        for i in range(8)),
    "integer beyond 64 bits": "a: 99999999999999999999\n",
    "bad timestamp": "a: 2001-99-99\n",
    "bad tagged int": "a: !!int abc\n",
    "duplicate key": "a: 1\na: 2\n",
    "mapping key": "? [a]\n: b\n",
    "anchor alone": "t: {when: &iVaso}\n",
    "reserved indicator": "t: {when: @iVaso}\n",
    "block scalar misused": "t:\n  when: |iVaso|\n",
    "list then more": "t:\n  when: [iVaso] AND iLleno\n",
    "quoted then more": "t: {when: \"iVaso\" AND iLleno}\n",
    "key further in": "t:\n  - from: a\n     to: b\n",
    "key further out": "t:\n  - from: a\n   to: b\n",
    "tab after a value": "t: {when: iVaso}\t\n",
    "a tag only libyaml takes, then too deep": "a: !...!!str x\nb: " + "[" * 70 + "]" * 70 + "\n",
}


@pytest.mark.parametrize("name", sorted(ERRORS))
def test_a_refusal_is_worded_the_same_on_both_paths(name: str) -> None:
    got = same(ERRORS[name])
    assert got[0] == "refused", got


def test_a_file_that_loads_is_not_parsed_in_python(monkeypatch: pytest.MonkeyPatch) -> None:
    made: list[str] = []
    real = yamlsrc._Loader

    def spy(text: str, path: str = "<yaml>") -> yamlsrc._Loader:
        made.append(path)
        return real(text, path)

    monkeypatch.setattr(yamlsrc, "_Loader", spy)
    load_yaml("good.yaml", TEXTS["anchors and aliases"])
    assert made == []
    with pytest.raises(SourceError, match="undefined alias"):
        load_yaml("bad.yaml", ERRORS["undefined alias"])
    assert made == ["bad.yaml"]  # worded by the pure-Python parser


def test_a_limit_is_refused_by_the_fast_path_itself(monkeypatch: pytest.MonkeyPatch) -> None:
    """A hostile file is refused while libyaml parses it: it is not parsed twice."""
    def no_python(text: str, path: str = "<yaml>") -> yamlsrc._Loader:
        raise AssertionError("parsed again in Python")

    monkeypatch.setattr(yamlsrc, "_Loader", no_python)
    for name in ("too deep", "too many aliases", "recursive alias", "billion laughs"):
        with pytest.raises(SourceError):
            load_yaml("f.yaml", ERRORS[name])


#: pieces random texts are made of: YAML's indicators, indentation, line breaks of every
#: kind, quotes and escapes, words, numbers, and characters YAML refuses
PIECES = ["a", "b", "iVaso", "12", "0x1F", "1.5", "true", "~", " ", "  ", "\n", "\r\n", "\r",
          "\x85", "\u2028", "\t", ":", ": ", "- ", "-", "[", "]", "{", "}", ",", "?", "'",
          '"', "\\", "\\u2191", "#", "&a", "*a", "!", "!!str ", "|", ">", "%", "@", "`",
          "...", "---", "é", "😀", "\ufeff", "\x00"]


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.sampled_from(PIECES), max_size=40))
def test_random_texts_load_or_are_refused_the_same(pieces: list[str]) -> None:
    same("".join(pieces))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.sampled_from(PIECES), max_size=12), st.sampled_from(EXAMPLES),
       st.integers(min_value=0, max_value=10**6))
def test_an_example_with_a_slip_loads_or_is_refused_the_same(
        pieces: list[str], path: Path, at: int) -> None:
    text = path.read_text(encoding="utf-8")
    at %= len(text) + 1
    same(text[:at] + "".join(pieces) + text[at:])


def test_texts_on_one_line_work_out_their_places_only_when_asked() -> None:
    doc = load_yaml("f.yaml", "a: 'it''s  ok'\nb: {c: plain text}\nd: \"x\\ty\"\n")
    texts = [doc["a"], doc["b"]["c"], doc["d"]]
    assert [s._pos for s in texts] == [None, None, None]
    assert [s.loc for s in texts] == [Loc("f.yaml", 1, 5), Loc("f.yaml", 2, 8),
                                      Loc("f.yaml", 3, 5)]
    assert doc["a"].pos(3) == Loc("f.yaml", 1, 9)  # the s, after the doubled quote
    assert doc["d"].pos(2) == Loc("f.yaml", 3, 8)  # the y, after the escape
