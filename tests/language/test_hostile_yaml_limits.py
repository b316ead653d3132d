"""The limits of runtime.language.yamlsrc at their edges: what is just inside loads as
before, what is just beyond is refused at its place (test_hostile_yaml.py runs the attacks
themselves through the command line)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from runtime.errors import Loc, SourceError
from runtime.language import safefile, yamlsrc
from runtime.language.lexer import MAX_TOKENS
from runtime.language.parser import MAX_DEPTH as MAX_CHAIN
from runtime.language.parser import Parser, parse_expression, parse_statements
from runtime.language.plantfile import load_plant
from runtime.language.shape import time_value
from runtime.language.yamlsrc import (
    EXPANSION_ALLOWANCE,
    INT_MAX,
    INT_MIN,
    MAX_ALIASES,
    MAX_DEPTH,
    NODE_ALLOWANCE,
    TIME_MAX_NS,
    YList,
    YMap,
    load_yaml,
    node_budget,
    read_source,
)


def load(tmp_path: Path, text: str) -> object:
    p = tmp_path / "f.yaml"
    p.write_text(text, encoding="utf-8")
    return load_yaml(str(p))


def refusal(tmp_path: Path, text: str) -> SourceError:
    with pytest.raises(SourceError) as info:
        load(tmp_path, text)
    return info.value


def nested(depth: int) -> str:
    """A document whose innermost scalar is ``depth`` nodes deep (the root mapping is 1)."""
    return "k: " + "[" * (depth - 2) + "x" + "]" * (depth - 2) + "\n"


def test_nesting_up_to_the_limit_loads_and_one_more_is_refused(tmp_path: Path) -> None:
    doc = load(tmp_path, nested(MAX_DEPTH))
    assert isinstance(doc, YMap)
    err = refusal(tmp_path, nested(MAX_DEPTH + 1))
    assert "nested deeper than 64" in err.message
    assert (err.loc.line, err.loc.col) == (1, 4 + MAX_DEPTH - 1)  # the innermost 'x'


def test_aliases_that_share_values_load_as_copies(tmp_path: Path) -> None:
    text = "io: &io {iA: sim.I0, iB: sim.I1}\n" + "".join(
        f"u{i}: *io\n" for i in range(MAX_ALIASES))
    doc = load(tmp_path, text)
    assert isinstance(doc, YMap)
    assert doc["u7"] == {"iA": "sim.I0", "iB": "sim.I1"}
    assert doc.val_locs["u7"].line == 1  # an aliased value is placed at its anchor's text
    err = refusal(tmp_path, text + "extra: *io\n")
    assert "too many aliases" in err.message
    assert (err.loc.line, err.loc.col) == (MAX_ALIASES + 2, 8)


def test_text_expansion_just_within_the_budget_loads_and_beyond_is_refused(
        tmp_path: Path) -> None:
    # one anchored text of n characters, aliased 9 times: 10 copies of it, plus keys a and b
    def doc(n: int) -> str:
        return f"a: &a {'x' * n}\nb: [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n"

    def chars(n: int) -> int:
        return 2 + 10 * n

    n = next(k for k in range(1000, 2000) if chars(k) > len(doc(k)) + EXPANSION_ALLOWANCE)
    assert isinstance(load(tmp_path, doc(n - 1)), YMap)
    err = refusal(tmp_path, doc(n))
    assert "alias '*a' expands the file to more than" in err.message
    assert "characters of values" in err.message
    assert (err.loc.line, err.loc.col) == (2, 5 + 4 * 8)  # the ninth alias


def test_nodes_up_to_the_limit_load_and_one_more_is_refused(tmp_path: Path) -> None:
    def text(items: int) -> str:
        return "a: [" + ",".join(["1"] * items) + "]\n"
    # the root, key 'a', the list: 3 nodes, then one per item; the budget grows with the
    # size (a quarter of it), so find the largest list that fits
    items = NODE_ALLOWANCE
    while 3 + items + 1 <= node_budget(len(text(items + 1))):
        items += 1
    doc = load(tmp_path, text(items))
    assert isinstance(doc, YMap) and len(doc["a"]) == items
    err = refusal(tmp_path, text(items + 1))
    budget = node_budget(len(text(items + 1)))
    assert err.message.startswith(f"the file has more than {budget} nodes")
    assert (err.loc.line, err.loc.col) == (1, 5 + 2 * items)  # the last item


def test_a_file_written_at_four_bytes_a_node_always_loads(tmp_path: Path) -> None:
    """A 1000-instance plant or a 100-tester story is large but plain: the budget never
    refuses a file without aliases whose nodes take 4 bytes or more each."""
    doc = load(tmp_path, "a:\n" + "- 1\n" * 100_000)
    assert isinstance(doc, YMap) and len(doc["a"]) == 100_000


def test_nodes_added_by_an_alias_count(tmp_path: Path) -> None:
    big = "a: &a [" + ",".join(["1"] * NODE_ALLOWANCE) + "]\n"
    budget = node_budget(len(big + "b: *a\n"))
    assert 2 * NODE_ALLOWANCE > budget  # the alias doubles the list past the budget
    err = refusal(tmp_path, big + "b: *a\n")
    assert err.message.startswith(f"alias '*a' expands the file to more than {budget} nodes")
    assert (err.loc.line, err.loc.col) == (2, 4)


def test_an_undefined_alias_is_still_a_yaml_error(tmp_path: Path) -> None:
    err = refusal(tmp_path, "a: *nowhere\n")
    assert "undefined alias" in err.message
    assert (err.loc.line, err.loc.col) == (1, 4)


@pytest.mark.parametrize("value", [INT_MIN, INT_MAX, 0, -1, 2**63, 1000_000])
def test_64_bit_integers_load(tmp_path: Path, value: int) -> None:
    doc = load(tmp_path, f"n: {value}\nh: 0x{INT_MAX:x}\n")
    assert isinstance(doc, YMap)
    assert doc["n"] == value and doc["h"] == INT_MAX


@pytest.mark.parametrize("text", [str(INT_MAX + 1), str(INT_MIN - 1), f"0x{INT_MAX + 1:x}",
                                  "1" + "_0" * 4400, "0b" + "1" * 65, "1:" * 40 + "1"])
def test_integers_beyond_64_bits_are_refused_at_their_place(tmp_path: Path, text: str) -> None:
    err = refusal(tmp_path, f"a: 1\nn: {text}\n")
    assert err.message.startswith("integer out of range: expected a 64-bit integer")
    assert (err.loc.line, err.loc.col) == (2, 4)


def test_times_up_to_64_bit_nanoseconds_load() -> None:
    loc = Loc("f.yaml", 3, 5)
    assert time_value("106751d23h47m16s854ms775us807ns", loc, "max") == TIME_MAX_NS
    with pytest.raises(SourceError, match="time out of range for max"):
        time_value("106751d23h47m16s854ms775us808ns", loc, "max")
    with pytest.raises(SourceError, match="time out of range"):
        time_value("9" * 5000 + "s", loc, "max")


def test_a_file_below_the_size_limit_loads_and_one_at_it_is_refused(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(yamlsrc, "MAX_FILE_BYTES", 1000)
    p = tmp_path / "f.yaml"
    p.write_text("a: " + "x" * 995 + "\n")  # 999 bytes
    assert read_source(str(p)).startswith("a: x")
    p.write_text("a: " + "x" * 996 + "\n")  # 1000 bytes
    with pytest.raises(SourceError, match=r"found a file of 1000 bytes"):
        read_source(str(p))


def test_a_file_that_grows_after_its_size_was_read_is_cut_and_refused(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # the size seen by fstat is small; the file is longer when read (a log being appended to)
    p = tmp_path / "f.yaml"
    p.write_text("a: " + "x" * 2000 + "\n")
    real_stat, real_fstat = os.stat, os.fstat

    def small(st: os.stat_result) -> os.stat_result:
        return os.stat_result((*st[:6], 10, *st[7:]))  # st_size is field 6

    monkeypatch.setattr(yamlsrc, "MAX_FILE_BYTES", 1000)
    monkeypatch.setattr(safefile.os, "stat", lambda path: small(real_stat(path)))
    monkeypatch.setattr(safefile.os, "fstat", lambda fd: small(real_fstat(fd)))
    with pytest.raises(SourceError, match=r"found a file of at least 1000 bytes"):
        read_source(str(p))


def test_a_plant_naming_a_fifo_says_so_at_its_grafcet_line(tmp_path: Path) -> None:
    fifo = tmp_path / "chart.yaml"
    os.mkfifo(fifo)
    plant = tmp_path / "plant.yaml"
    plant.write_text("drivers: {sim: {type: sim}}\ninstances:\n  a: {grafcet: chart.yaml}\n")
    with pytest.raises(SourceError) as info:
        load_plant(str(plant))
    assert str(info.value) == (f"{plant}:3:16: error: grafcet file {fifo}: must be a regular "
                               "file below 1024 KiB (1048576 bytes), found a FIFO (named pipe)")


def test_a_forbidden_character_after_a_crlf_line_is_placed_on_its_line(tmp_path: Path) -> None:
    err = refusal(tmp_path, "a: 1\r\nb: [x, \x01]\r\n")
    assert (err.loc.line, err.loc.col) == (2, 8)
    assert "U+0001 is not allowed" in err.message


def test_a_list_keeps_working_with_the_composer_limits(tmp_path: Path) -> None:
    doc = load(tmp_path, "l: [a, &b [1, 2], *b]\n")
    assert isinstance(doc, YMap) and isinstance(doc["l"], YList)
    assert doc["l"] == ["a", [1, 2], [1, 2]]


def test_leading_zeros_do_not_count_toward_the_integer_limit(tmp_path: Path) -> None:
    doc = load(tmp_path, f"a: 0x{'0' * 100}ff\nb: -{'0' * 100}7\n")  # YAML 1.1: 0... octal
    assert isinstance(doc, YMap) and (doc["a"], doc["b"]) == (255, -7)


def test_expression_literals_up_to_64_bits_parse_and_one_more_is_refused() -> None:
    from runtime.language.ast import Lit
    from tests.language.langkit import expr

    for text, value in [("0" * 100 + "1", 1), ("16#" + "0" * 100 + "FF", 255),
                        (str(INT_MAX), INT_MAX), ("2#" + "1" * 64, INT_MAX)]:
        lit = expr(text)
        assert isinstance(lit, Lit) and lit.value == value
    for text in [str(INT_MAX + 1), "2#1" + "0" * 64, "16#1" + "0" * 16]:
        with pytest.raises(SourceError, match="integer out of range") as info:
            expr(f"x + {text}")
        assert info.value.loc.col == 5


def _place(offset: int) -> Loc:
    return Loc("t", 1, offset + 1)


def test_a_long_chain_is_refused_at_its_first_operator_past_the_limit_unread_beyond() -> None:
    # 100000 terms: before, every token was made and the tree built before the refusal
    # (2-3 s); now the parser stops at the 101st operator, with a few tokens read ahead
    text = " + ".join(["iA"] * 100_000)
    p = Parser(text, _place)
    with pytest.raises(SourceError, match="at most 100 operators in a chain") as info:
        p.expression()
    assert info.value.loc.col == len("iA + ") * MAX_CHAIN + len("iA ") + 1  # the 101st '+'
    assert len(p.toks) < 2 * MAX_CHAIN + 50  # tokens read: the rest was never looked at
    # a fault further on is not reached either: the first fault of the text is the one said
    with pytest.raises(SourceError, match="at most 100 operators"):
        parse_expression(text + " $", _place)
    chain = " + ".join(["iA"] * (MAX_CHAIN + 1))  # 100 operators: a chain at the limit
    assert parse_expression(chain, _place) is not None


def test_a_text_of_max_tokens_parses_and_one_more_token_is_refused_there() -> None:
    body = "sN := 1\n" * (MAX_TOKENS // 4)  # NAME ':=' INT NL: 4 tokens a statement
    assert len(parse_statements(body, _place)) == MAX_TOKENS // 4
    with pytest.raises(SourceError, match=f"at most {MAX_TOKENS} tokens") as info:
        parse_statements(body + "sN := 2\n", _place)
    assert info.value.loc.col == len(body) + 1  # the 10001st token: the last 'sN'
