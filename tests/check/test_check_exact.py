"""G201 and G208 are decided exactly, not by sampling: for random conditions over a few
bools, edges and a counter, ``check`` reports G201 exactly when a brute-force truth table
finds values making both transitions of an OR divergence true, and its witness forces
both conditions true whatever the values it leaves out. G104's firing sequence is exact."""

from __future__ import annotations

import itertools
import re
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.checker.check import check_files

VARS = ("iA", "iB", "iC")
COUNTS = range(-1, 6)  # sN is compared with constants 0..3: -1..5 covers every case


# -- a tiny expression language with its own evaluator (independent of runtime/) ---------
@dataclass(frozen=True)
class E:
    text: str  # seed notation, fully parenthesised where it matters
    fn: Callable[[dict[str, tuple[bool, bool]], int], bool]


def var(name: str) -> E:
    return E(name, lambda env, n: env[name][0])


def rise(name: str) -> E:
    return E(f"↑{name}", lambda env, n: env[name][0] and not env[name][1])


def fall(name: str) -> E:
    return E(f"↓{name}", lambda env, n: env[name][1] and not env[name][0])


def cmp(op: str, c: int) -> E:
    f = {">=": lambda n: n >= c, "<": lambda n: n < c, "=": lambda n: n == c}[op]
    return E(f"(sN {op} {c})", lambda env, n: f(n))


def neg(a: E) -> E:
    return E(f"({a.text})'", lambda env, n: not a.fn(env, n))


def conj(a: E, b: E) -> E:
    return E(f"({a.text}·{b.text})", lambda env, n: a.fn(env, n) and b.fn(env, n))


def disj(a: E, b: E) -> E:
    return E(f"({a.text} + {b.text})", lambda env, n: a.fn(env, n) or b.fn(env, n))


leaves = st.one_of(
    st.sampled_from(VARS).map(var),
    st.sampled_from(VARS).map(rise),
    st.sampled_from(VARS).map(fall),
    st.builds(cmp, st.sampled_from([">=", "<", "="]), st.integers(0, 3)),
)
exprs = st.recursive(leaves, lambda sub: st.one_of(
    sub.map(neg), st.builds(conj, sub, sub), st.builds(disj, sub, sub)), max_leaves=5)


def envs() -> list[tuple[dict[str, tuple[bool, bool]], int]]:
    out = []
    for bits in itertools.product((False, True), repeat=2 * len(VARS)):
        env = {v: (bits[2 * i], bits[2 * i + 1]) for i, v in enumerate(VARS)}
        out += [(env, n) for n in COUNTS]
    return out


ALL = envs()

CHART = """\
grafcet: T
inputs: [iA, iB, iC, iD]
memory: {{sN: 0}}
steps:
  gsA: {{initial: true, actions: ["P1 sN := sN + 1"]}}
  gsB: {{}}
  gsC: {{}}
transitions:
  - {{from: gsA, to: gsB, when: "{a}"}}
  - {{from: gsA, to: gsC, when: "{b}"}}
  - {{from: gsB, to: gsA, when: iD}}
  - {{from: gsC, to: gsA, when: iD}}
"""


def parse_witness(text: str) -> dict[tuple[str, int], int]:
    """``iA=1 (previous scan 0), sN=2, iB: previous scan 1`` -> {(key, age): value}."""
    out: dict[tuple[str, int], int] = {}
    if text == "any values":
        return out
    for part in re.split(r", (?![^()]*\))", text):
        m = re.fullmatch(r"(\w+)=(-?\d+)(?: \(previous scan (\d)\))?", part)
        if m:
            out[(m.group(1), 0)] = int(m.group(2))
            if m.group(3) is not None:
                out[(m.group(1), 1)] = int(m.group(3))
            continue
        m = re.fullmatch(r"(\w+): previous scan (\d)", part)
        assert m, f"unexpected witness part {part!r} in {text!r}"
        out[(m.group(1), 1)] = int(m.group(2))
    return out


def consistent(env: dict[str, tuple[bool, bool]], n: int,
               w: dict[tuple[str, int], int]) -> bool:
    for (key, age), v in w.items():
        if key == "sN":
            assert age == 0
            if n != v:
                return False
        elif env[key][age] != bool(v):
            return False
    return True


@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(a=exprs, b=exprs)
def test_g201_matches_a_truth_table(a: E, b: E) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "chart.yaml"
        path.write_text(CHART.format(a=a.text, b=b.text), encoding="utf-8")
        (res,) = check_files([str(path)])
    assert res.failure is None, res.failure
    sat_a = any(a.fn(e, n) for e, n in ALL)
    sat_b = any(b.fn(e, n) for e, n in ALL)
    both = any(a.fn(e, n) and b.fn(e, n) for e, n in ALL)
    g208 = sorted(d.line for d in res.diags if d.code == "G208")
    assert g208 == [line for line, sat in ((9, sat_a), (10, sat_b)) if not sat], (
        a.text, b.text, [str(d) for d in res.diags])
    g201 = [d for d in res.diags if d.code == "G201"]
    assert [d.severity for d in g201] == (["warning"] if both else []), (
        a.text, b.text, [str(d) for d in res.diags])
    if g201:
        m = re.search(r"both true with (.*) \('", g201[0].message)
        assert m, g201[0].message
        w = parse_witness(m.group(1))
        completions = [(e, n) for e, n in ALL if consistent(e, n, w)]
        assert completions, (w, g201[0].message)
        assert all(a.fn(e, n) and b.fn(e, n) for e, n in completions), (
            a.text, b.text, g201[0].message)


def test_g201_exact_witness_of_the_seed_drawer_tester(drawer: str) -> None:
    (res,) = check_files([drawer])
    msgs = sorted(d.message for d in res.diags if d.code == "G201")
    assert any("both true with iAbierto=1, gsAbrir.T=10s ('iAbierto' and 'tAveriaAbrir')"
               in m for m in msgs), msgs
    # tParo := iCerrado·sParo + (sCierres >= 1000) and iCerrado: the counter alone is
    # enough, sParo is left out (it does not matter)
    assert any("both true with iCerrado=1, sCierres=1000 ('tParo' and 'iCerrado')" in m
               for m in msgs), msgs


def test_g104_exact_firing_sequence(write: Callable[[str, str], str]) -> None:
    path = write("c.yaml", """\
        grafcet: T
        inputs: [iA, iB, iC, iD]
        steps:
          gsA: {initial: true}
          gsB: {}
          gsC: {}
          gsD: {}
          gsE: {}
        transitions:
          - {from: gsA, to: gsE, when: iA}
          - {from: gsE, to: [gsB, gsC], when: iB}
          - {from: gsB, to: gsD, when: iC}
          - {from: gsC, to: gsD, when: iD}
          - {from: gsD, to: gsA, when: iA}
        """)
    (res,) = check_files([path])
    (d,) = [d for d in res.diags if d.code == "G104"]
    # the shortest sequence: both branches end in the same scan
    assert d.line == 12
    assert d.message == (
        "unsafe chart: step 'gsD' is activated by two transitions at once (an OR convergence "
        "fed by parallel branches?), by {gsA} -[gsA→gsE (line 10)]-> {gsE} "
        "-[gsE→gsB,gsC (line 11)]-> {gsB, gsC} -[gsB→gsD (line 12) + gsC→gsD (line 13)]-> "
        "{gsD} (seed-000 rule I.3; conditions taken as free)")
