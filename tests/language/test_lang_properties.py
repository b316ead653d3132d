"""Property tests: random well-typed expressions, written in both notations with the fewest
parentheses the precedence table allows, parse to the intended tree, round-trip through the
unparser, and compute in the compiled chart what a small reference evaluator computes."""

from __future__ import annotations

import os
from typing import Any

from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from runtime.compiler.codegen import compile_grafcet
from runtime.engine.instance import Instance
from runtime.language.yamlsrc import load_yaml
from tests.language.langkit import assert_round_trip_expr, expr, tree

BOOLS = ("iA", "iB", "iC")
INTS = ("iN", "iM")
#: LANG_PROP_EXAMPLES=5000 for a longer search
PROFILE = settings(max_examples=int(os.environ.get("LANG_PROP_EXAMPLES", "200")), deadline=None,
                   suppress_health_check=[HealthCheck.too_slow])

# surface spellings: (spelling, parse-tree operator, precedence level)
AND = [("·", "MUL", 2), ("*", "MUL", 2), ("AND", "AND", 5), ("&", "AND", 5), ("and", "AND", 5)]
OR = [("+", "ADD", 3), ("OR", "OR", 7), ("or", "OR", 7)]
XOR = [("XOR", "XOR", 6), ("xor", "XOR", 6)]
NOT = ["'", "NOT ", "!", "not "]
EDGE = [("↑", "RE"), ("RE ", "RE"), ("↓", "FE"), ("FE ", "FE")]
CMP = [(">", "GT"), (">=", "GE"), ("≥", "GE"), ("<", "LT"), ("<=", "LE"), ("≤", "LE"),
       ("=", "EQ"), ("==", "EQ"), ("≠", "NE"), ("!=", "NE"), ("<>", "NE")]
ARITH = [("+", "ADD", 3), ("-", "SUB", 3), ("*", "MUL", 2), ("·", "MUL", 2),
         ("/", "DIV", 2), ("MOD", "MOD", 2)]
SEED_OPS = ("+", "·", "*")  # logical between two bools, arithmetic otherwise


# -- generated trees: tuples whose first item is the kind ----------------------------------
@st.composite
def bool_node(draw: Any, depth: int = 4) -> tuple:  # type: ignore[type-arg]
    if depth <= 0 or draw(st.integers(0, 4)) == 0:
        if draw(st.integers(0, 4)) == 0:
            return ("blit", draw(st.booleans()), draw(st.booleans()))  # (value, as 0/1?)
        return ("bvar", draw(st.sampled_from(BOOLS)))
    kind = draw(st.sampled_from(["not", "and", "or", "xor", "cmp", "cmp", "beq", "edge"]))
    sub = bool_node(depth - 1)
    if kind == "not":
        return ("not", draw(st.sampled_from(NOT)), draw(sub))
    if kind in ("and", "or", "xor"):
        table = {"and": AND, "or": OR, "xor": XOR}[kind]
        return (kind, draw(st.sampled_from(table)), draw(sub), draw(sub))
    if kind == "cmp":
        op = draw(st.sampled_from(CMP))
        return ("cmp", op, draw(int_node(depth - 1)), draw(int_node(depth - 1)))
    if kind == "beq":
        op = draw(st.sampled_from([c for c in CMP if c[1] in ("EQ", "NE")]))
        return ("cmp", op, ("b2i", draw(sub)), ("b2i", draw(sub)))
    return ("edge", draw(st.sampled_from(EDGE)), draw(sub))


@st.composite
def int_node(draw: Any, depth: int = 4) -> tuple:  # type: ignore[type-arg]
    if depth <= 0 or draw(st.integers(0, 3)) == 0:
        pick = draw(st.integers(0, 5))
        if pick <= 1:
            return ("ilit", draw(st.integers(0, 12)))
        if pick <= 4:
            return ("ivar", draw(st.sampled_from(INTS)))
        return ("b2i", draw(bool_node(depth - 1)))
    kind = draw(st.sampled_from(["arith", "arith", "arith", "neg", "b2i"]))
    if kind == "neg":
        return ("neg", draw(int_node(depth - 1)))
    if kind == "b2i":
        return ("b2i", draw(bool_node(depth - 1)))
    op = draw(st.sampled_from(ARITH))
    left = draw(int_node(depth - 1))
    if op[1] in ("DIV", "MOD"):  # mostly non-zero divisors, so that few examples are rejected
        right = draw(st.one_of(st.builds(lambda n: ("ilit", n), st.integers(1, 9)),
                               st.just(("ivar", "iM")), int_node(depth - 1)))
    else:
        right = draw(int_node(depth - 1))
    return ("arith", op, left, right)


# -- rendering with the fewest parentheses -------------------------------------------------
def render(n: tuple, seed_parent: bool = False, extra: frozenset[int] = frozenset(),
           path: int = 1) -> tuple[str, float]:  # type: ignore[type-arg]
    """(text, level): level 0 for atoms, 0.5 postfix, 1 prefix, 2..7 binary operators.
    ``extra`` lists the node paths that get a redundant pair of parentheses."""
    text, level = _render(n, seed_parent, extra, path)
    if path in extra:
        return f"({text})", 0
    return text, level


def _render(n: tuple, seed_parent: bool, extra: frozenset[int],  # type: ignore[type-arg]
            path: int) -> tuple[str, float]:
    kind = n[0]
    if kind == "bvar" or kind == "ivar":
        return n[1], 0
    if kind == "blit":
        if n[2] and not seed_parent:  # 0/1 are bools where a bool is wanted
            return ("1" if n[1] else "0"), 0
        return ("TRUE" if n[1] else "FALSE"), 0
    if kind == "ilit":
        return str(n[1]), 0
    if kind == "b2i":
        return render(n[1], seed_parent, extra, path * 2)
    if kind == "not" and n[1] == "'":
        t, lv = render(n[2], False, extra, path * 2)
        return (f"({t})'" if lv > 0.5 else f"{t}'"), 0.5
    if kind in ("not", "edge", "neg"):
        spelling = {"not": lambda: n[1], "edge": lambda: n[1][0], "neg": lambda: "-"}[kind]()
        operand = n[2] if kind != "neg" else n[1]
        t, lv = render(operand, False, extra, path * 2)
        return (f"{spelling}({t})" if lv > 1 else f"{spelling}{t}"), 1
    if kind in ("and", "or", "xor", "arith"):
        spelling, _, level = n[1]
        left, right = n[2], n[3]
    else:  # cmp
        spelling, level = n[1][0], 4
        left, right = n[2], n[3]
    seed = spelling in SEED_OPS
    lt, llv = render(left, seed, extra, path * 2)
    rt, rlv = render(right, seed, extra, path * 2 + 1)
    if llv > level:
        lt = f"({lt})"
    if rlv >= level:
        rt = f"({rt})"
    return f"{lt} {spelling} {rt}", level


def expected_tree(n: tuple, seed_parent: bool = False) -> Any:  # type: ignore[type-arg]
    """The parse tree the rendered text must give (langkit.tree's form)."""
    kind = n[0]
    if kind in ("bvar", "ivar"):
        return n[1]
    if kind == "blit":
        if n[2] and not seed_parent:
            return ("lit", int(n[1]), "int")
        return ("lit", n[1], "bool")
    if kind == "ilit":
        return ("lit", n[1], "int")
    if kind == "b2i":
        return expected_tree(n[1], seed_parent)
    if kind == "not":
        return ("NOT", expected_tree(n[2]))
    if kind == "edge":
        return (n[1][1], expected_tree(n[2]))
    if kind == "neg":
        return ("NEG", expected_tree(n[1]))
    seed = kind != "cmp" and n[1][0] in SEED_OPS
    return (n[1][1], expected_tree(n[2], seed), expected_tree(n[3], seed))


# -- the reference evaluator (IEC semantics, written from the spec) ------------------------
class DivByZero(Exception):
    pass


def static_bool(n: tuple) -> bool:  # type: ignore[type-arg]
    """A bool by its written type (a bool used as a number keeps it)."""
    if n[0] == "arith" and n[1][1] in ("ADD", "MUL"):
        # `+`/`·` between two bools is OR/AND, a bool again (`iA + iA + iA` is an OR of three)
        return static_bool(n[2]) and static_bool(n[3])
    return n[0] in ("bvar", "blit", "not", "and", "or", "xor", "cmp", "edge") or (
        n[0] == "b2i")


def idiv(a: int, b: int) -> int:
    if b == 0:
        raise DivByZero
    q = abs(a) // abs(b)
    return q if (a < 0) == (b < 0) else -q


def imod(a: int, b: int) -> int:
    if b == 0:
        raise DivByZero
    r = abs(a) % abs(b)
    return r if a >= 0 else -r


def evaluate(n: tuple, env: dict[str, Any], edges: dict[int, Any], first: bool,
             path: int = 1) -> Any:  # type: ignore[type-arg]
    """Value of ``n`` in one scan; ``edges`` keeps each edge's previous operand value."""
    kind = n[0]
    ev = evaluate
    if kind in ("bvar", "ivar"):
        return env[n[1]]
    if kind in ("blit", "ilit"):
        return n[1]
    if kind == "b2i":
        return ev(n[1], env, edges, first, path * 2)
    if kind == "not":
        return not ev(n[2], env, edges, first, path * 2)
    if kind == "neg":
        return -int(ev(n[1], env, edges, first, path * 2))
    if kind == "edge":
        cur = bool(ev(n[2], env, edges, first, path * 2))
        prev = edges.get(path)
        edges[path] = cur
        if first:  # on the first scan no edge is true
            return False
        return (cur and not prev) if n[1][1] == "RE" else (prev and not cur)
    a = ev(n[2], env, edges, first, path * 2)  # every operand is evaluated (no short cut)
    b = ev(n[3], env, edges, first, path * 2 + 1)
    if kind == "and":
        return bool(a) and bool(b)
    if kind == "or":
        return bool(a) or bool(b)
    if kind == "xor":
        return bool(a) != bool(b)
    if kind == "cmp":
        return {"GT": a > b, "GE": a >= b, "LT": a < b, "LE": a <= b, "EQ": a == b,
                "NE": a != b}[n[1][1]]
    op = n[1][1]
    if op in ("ADD", "MUL") and static_bool(n[2]) and static_bool(n[3]):
        # `+`/`·` between two bools are OR/AND; the result counts as 0/1 here
        return int(bool(a) or bool(b)) if op == "ADD" else int(bool(a) and bool(b))
    a, b = int(a), int(b)
    if op == "ADD":
        return a + b
    if op == "SUB":
        return a - b
    if op == "MUL":
        return a * b
    if op == "DIV":
        return idiv(a, b)
    return imod(a, b)


# -- running a generated expression in a compiled chart --------------------------------------
CHART = """\
grafcet: Prop
inputs: [iA, iB, iC, {{iN: int}}, {{iM: int}}]
outputs: []
memory: {{sOut: 0}}
steps: {{gsA: {{initial: true}}}}
post:
  - |
    {target} := {text}
"""


def compiled_values(text: str, target: str, scans: list[dict[str, Any]]) -> list[Any]:
    from runtime.language.grafcetfile import GrafcetLoader

    source = CHART.format(target=target, text=text)
    g = GrafcetLoader("prop.yaml", load_yaml("prop.yaml", source)).load()
    inst = Instance("p", compile_grafcet(g))
    out = []
    for k, env in enumerate(scans):
        for name, v in env.items():
            inst.set(name, v)
        inst.scan(10**12 + k * 10**7, k * 10**7)
        out.append(inst.get(target))
    return out


def reference_values(n: tuple, scans: list[dict[str, Any]]) -> list[Any]:  # type: ignore
    edges: dict[int, Any] = {}
    try:
        return [evaluate(n, env, edges, k == 0) for k, env in enumerate(scans)]
    except DivByZero:
        assume(False)
        raise AssertionError from None  # not reached


ENV = st.fixed_dictionaries({
    "iA": st.booleans(), "iB": st.booleans(), "iC": st.booleans(),
    "iN": st.integers(-20, 20), "iM": st.integers(-20, 20).filter(lambda v: v != 0),
})
SCANS = st.lists(ENV, min_size=3, max_size=4)
EXTRA = st.frozensets(st.integers(1, 64), max_size=3)


def check_parse(n: tuple, text: str) -> None:  # type: ignore[type-arg]
    got = tree(expr(text))
    assert got == expected_tree(n), (text, got, expected_tree(n))
    assert_round_trip_expr(text)


@PROFILE
@given(bool_node(), SCANS, EXTRA)
def test_bool_expressions(n: tuple, scans: list[dict[str, Any]],  # type: ignore[type-arg]
                          extra: frozenset[int]) -> None:
    if n[0] == "blit":  # `tOut := 1` would make an int temporary: write TRUE
        n = ("blit", n[1], False)
    text, _ = render(n, extra=extra)
    check_parse(n, text)
    want = reference_values(n, scans)
    got = compiled_values(text, "tOut", scans)
    assert [bool(v) for v in got] == [bool(v) for v in want], text
    assert all(isinstance(v, bool) for v in got), (text, got)


@PROFILE
@given(int_node(), SCANS, EXTRA)
def test_int_expressions(n: tuple, scans: list[dict[str, Any]],  # type: ignore[type-arg]
                         extra: frozenset[int]) -> None:
    text, _ = render(n, extra=extra)
    check_parse(n, text)
    want = reference_values(n, scans)
    got = compiled_values(text, "sOut", scans)
    assert got == [int(v) for v in want], text


def test_renderer_uses_the_precedence_table() -> None:
    n: tuple[object, ...]
    n = ("and", ("AND", "AND", 5), ("cmp", (">", "GT"), ("arith", ("+", "ADD", 3),
                                                          ("ivar", "iN"), ("ilit", 1)),
                                    ("ivar", "iM")), ("bvar", "iC"))
    assert render(n)[0] == "iN + 1 > iM AND iC"
    n = ("or", ("+", "ADD", 3), ("and", ("·", "MUL", 2), ("bvar", "iA"), ("bvar", "iB")),
         ("cmp", (">=", "GE"), ("ivar", "iN"), ("ilit", 10)))
    assert render(n)[0] == "iA · iB + (iN >= 10)"
    n = ("edge", ("↑", "RE"), ("not", "'", ("bvar", "iA")))
    assert render(n)[0] == "↑iA'"
    n = ("not", "'", ("edge", ("↑", "RE"), ("bvar", "iA")))
    assert render(n)[0] == "(↑iA)'"


def test_reference_evaluator_chains_seed_or() -> None:
    """Found by hypothesis: `iA + iA + iA` is (iA OR iA) OR iA, 1 when iA is true, not 2."""
    a = ("b2i", ("bvar", "iA"))
    n = ("arith", ("+", "ADD", 3), ("arith", ("+", "ADD", 3), a, a), a)
    assert render(n)[0] == "iA + iA + iA"
    scans = [{"iA": False, "iB": False, "iC": False, "iN": 0, "iM": 0},
             {"iA": True, "iB": False, "iC": False, "iN": 0, "iM": 0}]
    assert reference_values(n, scans) == [0, 1]
    assert compiled_values("iA + iA + iA", "sOut", scans) == [0, 1]


def test_reference_evaluator_follows_iec_division() -> None:
    assert [idiv(7, 2), idiv(-7, 2), idiv(7, -2), idiv(-7, -2)] == [3, -3, -3, 3]
    assert [imod(7, 3), imod(-7, 3), imod(7, -3), imod(-7, -3)] == [1, -1, 1, -1]


# -- time literals and time arithmetic ------------------------------------------------------------
_UNITS = [("d", 86_400_000_000_000, 3), ("h", 3_600_000_000_000, 23), ("m", 60_000_000_000, 59),
          ("s", 1_000_000_000, 59), ("ms", 1_000_000, 999)]


@st.composite
def time_literal(draw: Any) -> tuple[str, int]:
    used = draw(st.lists(st.sampled_from(range(len(_UNITS))), min_size=1, max_size=5,
                         unique=True).map(sorted))
    text, ns = "", 0
    for i in used:
        unit, scale, top = _UNITS[i]
        v = draw(st.integers(0, top))
        text += f"{v}{unit}"
        ns += v * scale
    prefix = draw(st.sampled_from(["", "", "T#", "t#", "TIME#"]))
    return prefix + text, ns


@st.composite
def time_node(draw: Any, depth: int = 3) -> tuple[str, Any]:  # type: ignore[type-arg]
    """(text, reference function of the input iD), fully parenthesised."""
    if depth <= 0 or draw(st.integers(0, 2)) == 0:
        if draw(st.booleans()):
            text, ns = draw(time_literal())
            return text, lambda d, ns=ns: ns
        return "iD", lambda d: d
    op = draw(st.sampled_from(["+", "-", "*", "k*", "/", "neg"]))
    a_text, a = draw(time_node(depth - 1))
    if op in ("+", "-"):
        b_text, b = draw(time_node(depth - 1))
        if op == "+":
            return f"({a_text} + {b_text})", lambda d: a(d) + b(d)
        return f"({a_text} - {b_text})", lambda d: a(d) - b(d)
    k = draw(st.integers(1, 9))
    if op == "*":
        return f"({a_text} * {k})", lambda d: a(d) * k
    if op == "k*":
        return f"({k} · {a_text})", lambda d: k * a(d)
    if op == "/":
        return f"({a_text} / {k})", lambda d: idiv(a(d), k)
    return f"-{a_text}", lambda d: -a(d)


TIME_CHART = """\
grafcet: Times
inputs: [{{iD: time}}]
outputs: []
memory: {{sT: 0s}}
steps: {{gsA: {{initial: true}}}}
post: ["sT := {text}"]
"""


@settings(max_examples=int(os.environ.get("LANG_PROP_EXAMPLES", "100")), deadline=None)
@given(time_literal())
def test_time_literals_parse_to_their_value(lit: tuple[str, int]) -> None:
    text, ns = lit
    n = expr(text)
    assert tree(n) == ("lit", ns, "time"), text


@settings(max_examples=int(os.environ.get("LANG_PROP_EXAMPLES", "100")), deadline=None)
@given(time_node(), st.integers(-10**13, 10**13))
def test_time_arithmetic(node: tuple[str, Any], d: int) -> None:
    from runtime.language.grafcetfile import GrafcetLoader

    text, ref = node
    source = TIME_CHART.format(text=text)
    g = GrafcetLoader("t.yaml", load_yaml("t.yaml", source)).load()
    inst = Instance("t", compile_grafcet(g))
    inst.set("iD", d)
    inst.scan(10**12, 0)
    assert inst.get("sT") == ref(d), text
