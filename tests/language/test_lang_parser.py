"""Parser: every operator and notation of language.md, the precedence table, statements,
actions, and round trips through a fully parenthesising unparser."""

from __future__ import annotations

import pytest

from drivers.durations import format_ns as format_time
from drivers.durations import parse_literal as parse_time
from runtime.errors import SourceError
from runtime.language import ast as A
from tests.language.langkit import (
    MS,
    S,
    action,
    assert_round_trip_expr,
    assert_round_trip_stmts,
    expr,
    stmts,
    tree,
    unparse,
)


def lit(v, t="int"):  # type: ignore[no-untyped-def]
    return ("lit", v, t)


# -- operators of the notation table ----------------------------------------------------
@pytest.mark.parametrize("text, want", [
    # or
    ("a + b", ("ADD", "a", "b")),  # seed +: OR or ADD, decided by the types
    ("a OR b", ("OR", "a", "b")),
    ("a or b", ("OR", "a", "b")),  # keywords are case-insensitive
    # and
    ("a·b", ("MUL", "a", "b")),
    ("a∙b", ("MUL", "a", "b")),  # U+2219 and U+22C5 are read as the seed's dot too
    ("a⋅b", ("MUL", "a", "b")),
    ("a*b", ("MUL", "a", "b")),
    ("a AND b", ("AND", "a", "b")),
    ("a & b", ("AND", "a", "b")),
    # not
    ("a'", ("NOT", "a")),
    ("(a+b)'", ("NOT", ("ADD", "a", "b"))),
    ("a''", ("NOT", ("NOT", "a"))),
    ("NOT a", ("NOT", "a")),
    ("Not a", ("NOT", "a")),
    ("!a", ("NOT", "a")),
    # xor
    ("a XOR b", ("XOR", "a", "b")),
    # edges
    ("↑a", ("RE", "a")),
    ("↓a", ("FE", "a")),
    ("RE a", ("RE", "a")),
    ("FE a", ("FE", "a")),
    ("↑(a + b)", ("RE", ("ADD", "a", "b"))),
    # arithmetic
    ("a - b", ("SUB", "a", "b")),
    ("a / b", ("DIV", "a", "b")),
    ("a MOD b", ("MOD", "a", "b")),
    ("a mod b", ("MOD", "a", "b")),
    ("-a", ("NEG", "a")),
    ("a - -b", ("SUB", "a", ("NEG", "b"))),
    # parentheses
    ("((a))", "a"),
    ("(a + b)·c", ("MUL", ("ADD", "a", "b"), "c")),
])
def test_operators(text: str, want: object) -> None:
    assert tree(expr(text)) == want


@pytest.mark.parametrize("op, name", [
    (">", "GT"), (">=", "GE"), ("≥", "GE"), ("<", "LT"), ("<=", "LE"), ("≤", "LE"),
    ("=", "EQ"), ("==", "EQ"), ("≠", "NE"), ("!=", "NE"), ("<>", "NE"),
])
def test_comparisons_every_spelling(op: str, name: str) -> None:
    assert tree(expr(f"a {op} b")) == (name, "a", "b")
    assert tree(expr(f"a{op}b")) == (name, "a", "b")  # no spaces needed


@pytest.mark.parametrize("text, want", [
    ("0", lit(0)), ("1", lit(1)), ("42", lit(42)), ("1_000", lit(1000)),
    ("16#FF", lit(255)), ("2#1010", lit(10)),
    ("3.5", lit(3.5, "real")), ("2.5e3", lit(2500.0, "real")), ("1e-3", lit(0.001, "real")),
    ("TRUE", lit(True, "bool")), ("FALSE", lit(False, "bool")), ("true", lit(True, "bool")),
])
def test_constants(text: str, want: object) -> None:
    assert tree(expr(text)) == want


def test_zero_and_one_are_marked_usable_as_bools() -> None:
    for text, like in (("0", True), ("1", True), ("2", False), ("1.0", False)):
        n = expr(text)
        assert isinstance(n, A.Lit)
        assert n.bool_like is like


@pytest.mark.parametrize("text, ns", [
    ("10s", 10 * S),
    ("250ms", 250 * MS),
    ("1d23h30m20s700ms", ((((1 * 24 + 23) * 60 + 30) * 60 + 20) * 1000 + 700) * MS),
    ("12h30m", (12 * 60 + 30) * 60 * S),
    ("T#10s", 10 * S),
    ("t#10s", 10 * S),
    ("TIME#1h30m", 90 * 60 * S),
    ("T#1h_30m", 90 * 60 * S),
    ("1.5s", 1500 * MS),
    ("T#250ms", 250 * MS),
    ("5us", 5000),
])
def test_time_literals(text: str, ns: int) -> None:
    n = expr(text)
    assert isinstance(n, A.Lit) and n.lit_type is A.Type.TIME
    assert n.value == ns


def test_time_format_and_parse_agree() -> None:
    for ns in (0, 1, 250 * MS, 10 * S, 90 * 60 * S, 86_400 * S + 5 * MS, 93_020_700 * MS):
        assert parse_time(format_time(ns)) == ns
    assert format_time(93_020_700 * MS) == "1d1h50m20s700ms"
    assert parse_time("1s10m") is None  # units must come in order
    assert parse_time("10x") is None


@pytest.mark.parametrize("text, want", [
    ("gsAbrir.X", ("flag", "gsAbrir", "X")),
    ("gsAbrir.T", ("flag", "gsAbrir", "T")),
    ("gsAvería.X", ("flag", "gsAvería", "X")),
    ("gsA.T >= 10s", ("GE", ("flag", "gsA", "T"), lit(10 * S, "time"))),
    ("gsA.T > 1d23h30m20s700ms", ("GT", ("flag", "gsA", "T"),
                                  lit(171_020_700 * MS, "time"))),
    ("tonDoor.Q", ("member", "tonDoor", "Q")),
    ("ctr.CV >= 3", ("GE", ("member", "ctr", "CV"), lit(3))),
    ("timeTest.End()", ("call", "timeTest", "End", [])),
    ("timeTest.Val() > 5s", ("GT", ("call", "timeTest", "Val", []), lit(5 * S, "time"))),
    ("iParo + iCerrado·timeTest.End()",
     ("ADD", "iParo", ("MUL", "iCerrado", ("call", "timeTest", "End", [])))),
])
def test_step_flags_members_and_methods(text: str, want: object) -> None:
    assert tree(expr(text)) == want


def test_unicode_identifiers() -> None:
    assert tree(expr("gsAvería.X + tAveríaAbrir·iPaño")) == (
        "ADD", ("flag", "gsAvería", "X"), ("MUL", "tAveríaAbrir", "iPaño"))


def test_comments_are_skipped() -> None:
    assert tree(expr("a (* comment *) + b // to the end of the line")) == ("ADD", "a", "b")


# -- the precedence table, one test per level ----------------------------------------------
def test_level1_postfix_binds_tighter_than_prefix() -> None:
    assert tree(expr("↑a'")) == ("RE", ("NOT", "a"))
    assert tree(expr("↓a'")) == ("FE", ("NOT", "a"))
    assert tree(expr("NOT a'")) == ("NOT", ("NOT", "a"))
    assert tree(expr("-a'")) == ("NEG", ("NOT", "a"))
    assert tree(expr("RE a'")) == ("RE", ("NOT", "a"))


def test_level1_members_and_calls_bind_tightest() -> None:
    assert tree(expr("gsA.X'")) == ("NOT", ("flag", "gsA", "X"))
    assert tree(expr("↑gsA.X")) == ("RE", ("flag", "gsA", "X"))
    assert tree(expr("NOT timeT.End()")) == ("NOT", ("call", "timeT", "End", []))
    assert tree(expr("tonD.Q'")) == ("NOT", ("member", "tonD", "Q"))


def test_level1_prefix_binds_tighter_than_binary() -> None:
    assert tree(expr("↑a·b")) == ("MUL", ("RE", "a"), "b")
    assert tree(expr("NOT a AND b")) == ("AND", ("NOT", "a"), "b")
    assert tree(expr("!a + b")) == ("ADD", ("NOT", "a"), "b")
    assert tree(expr("-a * b")) == ("MUL", ("NEG", "a"), "b")
    assert tree(expr("↑iMarcha·iParo'")) == ("MUL", ("RE", "iMarcha"), ("NOT", "iParo"))


def test_level2_multiplicative() -> None:
    assert tree(expr("a + b·c")) == ("ADD", "a", ("MUL", "b", "c"))
    assert tree(expr("a·b + c")) == ("ADD", ("MUL", "a", "b"), "c")
    assert tree(expr("a * b / c MOD d")) == ("MOD", ("DIV", ("MUL", "a", "b"), "c"), "d")
    assert tree(expr("a - b MOD c")) == ("SUB", "a", ("MOD", "b", "c"))


def test_level3_additive_left_associative() -> None:
    assert tree(expr("a - b + c")) == ("ADD", ("SUB", "a", "b"), "c")
    assert tree(expr("a - b - c")) == ("SUB", ("SUB", "a", "b"), "c")
    assert tree(expr("a + b > c")) == ("GT", ("ADD", "a", "b"), "c")


def test_level4_comparisons() -> None:
    assert tree(expr("iCerrado·sParo+(sCierres>=1000)")) == (
        "ADD", ("MUL", "iCerrado", "sParo"), ("GE", "sCierres", lit(1000)))
    # the seed's + sits above comparisons: without parentheses the sum is compared
    assert tree(expr("iParo + sCierres >= 1000")) == (
        "GE", ("ADD", "iParo", "sCierres"), lit(1000))
    assert tree(expr("a < b = c")) == ("EQ", ("LT", "a", "b"), "c")


def test_level5_and_below_comparisons() -> None:
    assert tree(expr("a + 1 > b AND c")) == ("AND", ("GT", ("ADD", "a", lit(1)), "b"), "c")
    assert tree(expr("a = 1 & b <> 2")) == ("AND", ("EQ", "a", lit(1)), ("NE", "b", lit(2)))
    assert tree(expr("a AND b·c")) == ("AND", "a", ("MUL", "b", "c"))


def test_level6_xor_between_and_and_or() -> None:
    assert tree(expr("a XOR b AND c")) == ("XOR", "a", ("AND", "b", "c"))
    assert tree(expr("a AND b XOR c")) == ("XOR", ("AND", "a", "b"), "c")
    assert tree(expr("a OR b XOR c")) == ("OR", "a", ("XOR", "b", "c"))


def test_level7_or_loosest() -> None:
    assert tree(expr("a OR b AND c")) == ("OR", "a", ("AND", "b", "c"))
    assert tree(expr("a AND b OR c")) == ("OR", ("AND", "a", "b"), "c")
    assert tree(expr("a OR b OR c")) == ("OR", ("OR", "a", "b"), "c")
    assert tree(expr("a > 1 OR b + c")) == ("OR", ("GT", "a", lit(1)), ("ADD", "b", "c"))


def test_seed_and_st_operators_mix() -> None:
    assert tree(expr("a + b OR c·d AND NOT e'")) == (
        "OR", ("ADD", "a", "b"), ("AND", ("MUL", "c", "d"), ("NOT", ("NOT", "e"))))


def test_newlines_inside_parentheses_and_after_operators() -> None:
    assert tree(expr("(a +\n b)")) == ("ADD", "a", "b")
    assert tree(expr("(a\n + b)")) == ("ADD", "a", "b")
    assert tree(expr("a AND\n b")) == ("AND", "a", "b")
    assert tree(expr("NOT\n a")) == ("NOT", "a")


def test_spans_cover_the_source_text() -> None:
    text = "iA + (iB·iC)'"
    n = expr(text)
    assert isinstance(n, A.Binary)
    assert text[n.start:n.end] == text
    assert text[n.right.start:n.right.end] == "(iB·iC)'"


# -- statements ---------------------------------------------------------------------------
def test_assignments_separated_by_semicolons_and_new_lines() -> None:
    want = [(":=", "x", lit(1)), (":=", "y", ("ADD", "x", lit(2))), (":=", "z", "y")]
    assert tree(stmts("x := 1; y := x + 2; z := y")) == want
    assert tree(stmts("x := 1\ny := x + 2\nz := y\n")) == want
    assert tree(stmts("x := 1;\n\n y := x +\n 2 ;;z := y;")) == want


def test_method_statements() -> None:
    assert tree(stmts("sParo.Set(1, iParo); timeT.Ini(12h30m); timeT.Reset()")) == [
        ("stmt", ("call", "sParo", "Set", [lit(1), "iParo"])),
        ("stmt", ("call", "timeT", "Ini", [lit((12 * 60 + 30) * 60 * S, "time")])),
        ("stmt", ("call", "timeT", "Reset", [])),
    ]


def test_function_block_call_with_named_arguments() -> None:
    assert tree(stmts("tonDoor(IN := iA AND iB, PT := T#5s)")) == [
        ("fb", "tonDoor", [("IN", ("AND", "iA", "iB")), ("PT", lit(5 * S, "time"))])]
    assert tree(stmts("ctr(CU := ↑iPieza, R := FALSE, PV := 10)")) == [
        ("fb", "ctr", [("CU", ("RE", "iPieza")), ("R", lit(False, "bool")),
                       ("PV", lit(10))])]
    assert tree(stmts("tonDoor(\n IN := a,\n PT := 1s\n)")) == [
        ("fb", "tonDoor", [("IN", "a"), ("PT", lit(S, "time"))])]


def test_if_elsif_else() -> None:
    text = """IF a THEN x := 1; ELSIF b AND c THEN x := 2; y := 3; ELSE x := 4; END_IF"""
    assert tree(stmts(text)) == [("IF", [
        ("a", [(":=", "x", lit(1))]),
        (("AND", "b", "c"), [(":=", "x", lit(2)), (":=", "y", lit(3))]),
    ], [(":=", "x", lit(4))])]
    block = "if a\n   and b then\n  x := 1\nelse\n  x := 2\nend_if\n"
    assert tree(stmts(block)) == [("IF", [(("AND", "a", "b"), [(":=", "x", lit(1))])],
                                   [(":=", "x", lit(2))])]
    assert tree(stmts("IF a THEN END_IF")) == [("IF", [("a", [])], [])]


def test_nested_if() -> None:
    assert tree(stmts("IF a THEN IF b THEN x := 1; ELSE x := 2; END_IF; END_IF")) == [
        ("IF", [("a", [("IF", [("b", [(":=", "x", lit(1))])], [(":=", "x", lit(2))])])], [])]


def test_case_with_lists_ranges_and_else() -> None:
    text = "CASE n OF 1: x := 1; 2, 3: x := 2; 4..6: x := 3; -2..-1, 9: x := 4; " \
           "ELSE x := 0; END_CASE"
    assert tree(stmts(text)) == [("CASE", "n", [
        ([(1, 1)], [(":=", "x", lit(1))]),
        ([(2, 2), (3, 3)], [(":=", "x", lit(2))]),
        ([(4, 6)], [(":=", "x", lit(3))]),
        ([(-2, -1), (9, 9)], [(":=", "x", lit(4))]),
    ], [(":=", "x", lit(0))])]
    block = "CASE n OF\n  1:\n    x := 1\n    y := 2\n  2: x := 3\nEND_CASE"
    assert tree(stmts(block)) == [("CASE", "n", [
        ([(1, 1)], [(":=", "x", lit(1)), (":=", "y", lit(2))]),
        ([(2, 2)], [(":=", "x", lit(3))])], [])]


def test_bounded_for_with_and_without_by() -> None:
    assert tree(stmts("FOR i := 1 TO n BY 2 DO s := s + i; END_FOR")) == [
        ("FOR", "i", lit(1), "n", lit(2), [(":=", "s", ("ADD", "s", "i"))])]
    assert tree(stmts("FOR i := 10 TO 1 BY -1 DO END_FOR")) == [
        ("FOR", "i", lit(10), lit(1), ("NEG", lit(1)), [])]
    assert tree(stmts("for i := 0 to 3 do\n  s := i\nend_for")) == [
        ("FOR", "i", lit(0), lit(3), None, [(":=", "s", "i")])]


@pytest.mark.parametrize("text", [
    "WHILE a DO x := 1; END_WHILE",
    "REPEAT x := 1; UNTIL a END_REPEAT",
    "x := 1; while a do x := 2; end_while",
])
def test_no_while_or_repeat(text: str) -> None:
    with pytest.raises(SourceError) as info:
        stmts(text)
    msg = info.value.message
    assert "not allowed" in msg and "FOR" in msg and "found" in msg


# -- actions ------------------------------------------------------------------------------
@pytest.mark.parametrize("text, qual, time_ns, target, cond", [
    ("oAbrir", "N", None, "oAbrir", None),
    ("N oAbrir", "N", None, "oAbrir", None),
    ("N oParado if Clock_1Hz", "N", None, "oParado", "Clock_1Hz"),
    ("oParado if iA AND iB", "N", None, "oParado", ("AND", "iA", "iB")),
    ("S oLamp", "S", None, "oLamp", None),
    ("R oLamp", "R", None, "oLamp", None),
    ("L 2s oX", "L", 2 * S, "oX", None),
    ("D 500ms oX", "D", 500 * MS, "oX", None),
    ("D T#500ms oX", "D", 500 * MS, "oX", None),
    ("P oPulse", "P", None, "oPulse", None),
    ("DS 1s oX", "DS", S, "oX", None),
    ("SD 1s oX", "SD", S, "oX", None),
    ("SL 1s oX", "SL", S, "oX", None),
])
def test_bool_actions(text: str, qual: str, time_ns: int | None, target: str,
                      cond: object) -> None:
    pa = action(text)
    assert (pa.qualifier, pa.time_ns) == (qual, time_ns)
    assert pa.target is not None and pa.target.name == target
    assert (None if pa.cond is None else tree(pa.cond)) == cond
    assert pa.body is None


@pytest.mark.parametrize("text, qual, body", [
    ("P1 sCierres := sCierres + 1", "P1", [(":=", "sCierres", ("ADD", "sCierres", lit(1)))]),
    ("P0 x := 0; y := 1", "P0", [(":=", "x", lit(0)), (":=", "y", lit(1))]),
    ("N x := x + 1", "N", [(":=", "x", ("ADD", "x", lit(1)))]),
    ("x := 1", "N", [(":=", "x", lit(1))]),
    ("P timeT.Ini(5s)", "P", [("stmt", ("call", "timeT", "Ini", [lit(5 * S, "time")]))]),
    ("P1\n  x := 1\n  y := 2\n", "P1", [(":=", "x", lit(1)), (":=", "y", lit(2))]),
    ("N IF a THEN x := 1; END_IF", "N", [("IF", [("a", [(":=", "x", lit(1))])], [])]),
])
def test_statement_actions(text: str, qual: str, body: object) -> None:
    pa = action(text)
    assert pa.qualifier == qual and pa.target is None
    assert tree(pa.body) == body


def test_event_action() -> None:
    pa = action("on ↑iPieza do sN := sN + 1")
    assert pa.qualifier == "EVENT"
    assert tree(pa.event) == ("RE", "iPieza")
    assert tree(pa.body) == [(":=", "sN", ("ADD", "sN", ("lit", 1, "int")))]
    pa = action("on RE iA AND iB do x := 1; y := 2")
    assert tree(pa.event) == ("AND", ("RE", "iA"), "iB")
    assert len(pa.body or []) == 2


@pytest.mark.parametrize("text, kind", [
    ("on (↑iA + ↓iB) do n := 1", "EVENT"),  # parentheses, then do: an event
    ("ON ↑iA do n := 1", "EVENT"),  # the word is case-insensitive
    ("On", "target"),  # a bare output named On: an N action
    ("oN if iA", "target"),  # conditional N action on an output named oN
    ("ON := iA", "body"),  # an assignment to an output named ON
    ("oN.Set(1, iA)", "body"),  # a method call on it
    ("oN(IN := iA)", "body"),  # a block named oN called: no 'do' after the parentheses
])
def test_on_starts_an_event_action_only_before_an_event(text: str, kind: str) -> None:
    pa = action(text)
    if kind == "EVENT":
        assert pa.qualifier == "EVENT" and pa.event is not None
    elif kind == "target":
        assert pa.qualifier == "N" and pa.target is not None and pa.target.name == text[:2]
    else:
        assert pa.qualifier == "N" and pa.body is not None and pa.event is None


# -- round trips --------------------------------------------------------------------------
ROUND_TRIP_EXPRESSIONS = [
    "↑iMarcha·iParo'",
    "iCerrado·sParo+(sCierres>=1000)",
    "gsParado.X + sParo·Clock_1Hz",
    "gsAbrir.T >= 10s",
    "iParo + iCerrado·timeTest.End()",
    "a + 1 > b AND c",
    "NOT (a OR b) XOR c & d",
    "↓(a + b)' · -c",
    "a - -b * c / d MOD e",
    "x ≥ 1 + y ≤ 2 ≠ z",
    "gsA.T > 1d23h30m20s700ms",
    "T#1h30m + 250ms * 2",
    "2.5 * 1e-3 + 16#FF",
    "tonDoor.Q AND ctr.CV <> 3 OR TRUE AND FALSE",
    "RE a' OR FE b",
    "(((a)))",
    "gsAvería.X + tAveríaAbrir",
]


@pytest.mark.parametrize("text", ROUND_TRIP_EXPRESSIONS)
def test_round_trip_expressions(text: str) -> None:
    assert_round_trip_expr(text)


def test_unparser_is_fully_parenthesised() -> None:
    assert unparse(expr("a + b·c'")) == "(a + (b * (NOT c)))"
    assert unparse(expr("↑a'")) == "(RE (NOT a))"
    assert unparse(expr("a + 1 > b AND c")) == "(((a + 1) > b) AND c)"


ROUND_TRIP_STATEMENTS = [
    "sParo.Set(1, iParo); tAveriaAbrir := gsAbrir.T >= 10s; "
    "tParo := iCerrado·sParo+(sCierres>=1000)",
    "IF a THEN x := 1; ELSIF b THEN x := 2; ELSE x := 3; END_IF",
    "CASE n OF 1: x := 1; 2, 3: x := 2; 4..6: x := 3; ELSE x := 4; END_CASE",
    "FOR i := 1 TO 10 BY 2 DO s := s + i; IF s > 10 THEN t := 1; END_IF; END_FOR",
    "tonDoor(IN := a AND b, PT := 5s); x := tonDoor.Q; timeT.Ini(1m); timeT.Reset()",
    "CASE n OF -3..-1: FOR i := 0 TO 2 DO x := x + 1; END_FOR; ELSE END_CASE",
]


@pytest.mark.parametrize("text", ROUND_TRIP_STATEMENTS)
def test_round_trip_statements(text: str) -> None:
    assert_round_trip_stmts(text)
